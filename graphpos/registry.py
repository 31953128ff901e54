"""Estimators by name.

Each estimator family exports ``ESTIMATORS`` (name -> class) from its
package: ``filters`` (the papers' Kalman filters) and ``graphpos.graph``
(factor graphs). The core does not import them at module load, so the
dependency arrow stays ``estimators -> core``.
"""

from __future__ import annotations

import importlib

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


def make_estimator(name: str, settings: dict[str, str] | None = None, **kwargs) -> Estimator:
    """Build an estimator by name; a clear error for an unknown one.

    ``settings``: ``{key: value text}`` applied to its default config
    (:func:`graphpos.settings.apply_settings`).
    """
    cls = require_known([name])[name]
    if settings:
        from graphpos.settings import apply_settings

        kwargs["config"] = apply_settings(cls.default_config(), settings, name)
    return cls(**kwargs)
