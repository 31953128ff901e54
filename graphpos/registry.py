"""Estimators by name.

Each estimator family exports ``ESTIMATORS`` (name -> class) from its
package: ``filters`` (the papers' Kalman filters) and ``graphpos.graph``
(factor graphs). The core does not import them at module load, so the
dependency arrow stays ``estimators -> core``.
"""

from __future__ import annotations

import importlib
import math
from typing import Any

from graphpos.errors import ConfigError
from graphpos.estimator import Estimator

_FAMILIES = ("filters", "graphpos.graph")


def estimator_classes() -> dict[str, type[Estimator]]:
    """Every registered estimator class, by name, in registration order."""
    classes: dict[str, type[Estimator]] = {}
    for module_name in _FAMILIES:
        module = importlib.import_module(module_name)
        classes.update(getattr(module, "ESTIMATORS", {}))
    return classes


def require_known(names: list[str]) -> dict[str, type[Estimator]]:
    """The classes of ``names``; a ConfigError naming the unknown ones and the known."""
    classes = estimator_classes()
    unknown = [n for n in names if n not in classes]
    if unknown:
        raise ConfigError("unknown estimator " + ", ".join(f"'{n}'" for n in unknown) + f" (known: {', '.join(classes)})")
    return {n: classes[n] for n in names}


def make_estimator(name: str, settings: dict[str, Any] | None = None, **kwargs) -> Estimator:
    """Build an estimator by name; a clear error for an unknown one.

    Parameters
    ----------
    name : str
        Registry name.
    settings : dict, optional
        ``{key: value text}`` (or the value itself: ``False``, ``7``)
        applied to its default config (:func:`graphpos.settings.apply_settings`).
    **kwargs
        Passed to the estimator class: ``layout``, ``range_model``,
        ``initial_pose`` (a :class:`graphpos.ignition.StartPose`), ``config``
        (see :class:`graphpos.estimator.Estimator`).
    """
    cls = require_known([name])[name]
    if settings:
        from graphpos.settings import apply_settings

        kwargs["config"] = apply_settings(cls.default_config(), settings, name)
    return cls(**kwargs)


def start_pose_record(pose: Any) -> dict[str, float] | None:
    """A user's start pose as run.json and results.json record it.

    Parameters
    ----------
    pose : graphpos.ignition.StartPose or None

    Returns
    -------
    dict or None
        :meth:`StartPose.to_dict` (metres, radians) plus ``yaw_deg`` and
        ``yaw_sigma_deg``; None when no pose was given.
    """
    if pose is None:
        return None
    return {**pose.to_dict(), "yaw_deg": math.degrees(pose.yaw_rad), "yaw_sigma_deg": math.degrees(pose.yaw_sigma_rad)}
