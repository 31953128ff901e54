"""Estimator settings given as text (``graphpos run --set``), applied to config dataclasses.

A setting is ``[NAME.]KEY=VALUE``: ``graph-isam2.final=true`` sets one
estimator's field, ``fixed_lag_s=20`` sets the field in every selected
estimator whose config has it; a dotted key reaches into a nested config
(``fading.forgetting_factor``). The value is converted to the field's
declared type: numbers, ``true``/``false``, text, ``none`` for an optional
field, comma-separated numbers for a tuple (``range_scale_bounds=0.9,1.1``) and
semicolon-separated rows for a matrix (``markov=0.95,0.05;0.05,0.95``).
A key no selected estimator has, a value of the wrong type, or a value the
config's own checks refuse is a :class:`~graphpos.errors.ConfigError`.
"""

from __future__ import annotations

import dataclasses
import json
import math
import types
import typing
from typing import Any

from graphpos.errors import ConfigError

_TRUE = ("true", "yes", "on", "1")
_FALSE = ("false", "no", "off", "0")


def parse_settings(items: list[str], names: list[str], configs: dict[str, Any]) -> dict[str, dict[str, str]]:
    """Sort ``[NAME.]KEY=VALUE`` items by the estimator they apply to.

    Parameters
    ----------
    items : list of str
        The settings as typed. ``KEY`` may be a dotted path into a nested
        config (``fading.forgetting_factor``).
    names : list of str
        The selected estimators.
    configs : dict
        Each selected estimator's default config (a dataclass instance).

    Returns
    -------
    dict
        ``{estimator name: {key: value text}}`` for the estimators that get
        at least one setting.
    """
    from graphpos.registry import estimator_classes

    known_names = set(estimator_classes())
    out: dict[str, dict[str, str]] = {}
    for item in items:
        target, sep, value = item.partition("=")
        target = target.strip()
        if not sep or not target:
            raise ConfigError(f"setting {item!r} is not of the form [ESTIMATOR.]KEY=VALUE")
        name, dot, key = target.partition(".")
        if dot and name in known_names:
            if name not in names:
                raise ConfigError(f"setting {item!r} names estimator '{name}', which is not selected (selected: {', '.join(names)})")
            if not _has_setting(configs[name], key):
                raise ConfigError(f"{name} has no setting '{key}' (its settings: {', '.join(setting_names(configs[name]))})")
            takers = [name]
        else:
            key = target
            takers = [n for n in names if _has_setting(configs[n], key)]
            if not takers:
                raise ConfigError(f"no selected estimator ({', '.join(names)}) has a setting '{key}'; `graphpos estimators --json` lists them")
        for n in takers:
            out.setdefault(n, {})[key] = value.strip()
    return out


def as_text(value: Any) -> str:
    """A setting's value as it is typed on the command line (tuples comma-separated, rows by semicolons)."""
    if isinstance(value, tuple):
        rows = any(isinstance(v, tuple) for v in value)
        return (";" if rows else ",").join(as_text(v) for v in value)
    return "none" if value is None else str(value)


def apply_settings(config: Any, settings: dict[str, Any], owner: str) -> Any:
    """A copy of ``config`` with each text setting converted to its field's type.

    From Python a value may be given instead of text (``False``, ``7``,
    ``(0.9, 1.1)``): it is read as its text (:func:`as_text`).
    ``owner`` (the estimator's name) prefixes error messages.
    """
    for key, value in settings.items():
        text = value if isinstance(value, str) else as_text(value)
        if not _has_setting(config, key):
            raise ConfigError(f"{owner} has no setting '{key}' (its settings: {', '.join(setting_names(config))})")
        try:
            config = _replace(config, key.split("."), text)
        except ValueError as exc:
            raise ConfigError(f"{owner}: setting {key}={text!r}: {exc}") from None
        except ConfigError as exc:
            raise ConfigError(f"{owner}: {exc}") from None
    return config


def config_dict(config: Any) -> dict[str, Any]:
    """A config as JSON-ready data (tuples as lists, nested configs as dicts)."""
    if dataclasses.is_dataclass(config):
        return json.loads(json.dumps(dataclasses.asdict(config), default=str))
    return {"repr": repr(config)}


def setting_names(config: Any, prefix: str = "") -> list[str]:
    """Every settable key of a config, nested configs as dotted paths."""
    names = []
    for f in dataclasses.fields(config) if dataclasses.is_dataclass(config) else ():
        value = getattr(config, f.name)
        if dataclasses.is_dataclass(value):
            names.extend(setting_names(value, prefix + f.name + "."))
        else:
            names.append(prefix + f.name)
    return names


def _has_setting(config: Any, key: str) -> bool:
    return key in setting_names(config)


def _replace(config: Any, path: list[str], text: str) -> Any:
    """``config`` with the field at ``path`` set from ``text`` (nested configs rebuilt)."""
    head = path[0]
    if len(path) > 1:
        return dataclasses.replace(config, **{head: _replace(getattr(config, head), path[1:], text)})
    return dataclasses.replace(config, **{head: _convert(text, typing.get_type_hints(type(config))[head])})


def _convert(text: str, hint: Any) -> Any:
    """``text`` as a value of type ``hint``; ValueError saying what was expected."""
    args = typing.get_args(hint)
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        if text.lower() in ("none", "null") and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        if len(inner) == 1:
            return _convert(text, inner[0])
        raise ValueError(f"cannot read a value of type {hint}")
    if typing.get_origin(hint) is tuple:
        # a matrix (tuple of tuples) is typed row by row: "0.9,0.1;0.1,0.9"
        rows = typing.get_origin(args[0]) is tuple
        separator, what = (";", "semicolon-separated rows") if rows else (",", "comma-separated values")
        parts = [p.strip() for p in text.split(separator)]
        element_types = [args[0]] * len(parts) if len(args) == 2 and args[1] is Ellipsis else list(args)
        if len(element_types) != len(parts):
            raise ValueError(f"expected {len(element_types)} {what}, got {len(parts)}")
        return tuple(_convert(p, t) for p, t in zip(parts, element_types))
    if hint is bool:
        if text.lower() in _TRUE:
            return True
        if text.lower() in _FALSE:
            return False
        raise ValueError("expected true or false")
    if hint is int:
        try:
            return int(text)
        except ValueError:
            raise ValueError("expected a whole number") from None
    if hint is float:
        try:
            value = float(text)
        except ValueError:
            raise ValueError("expected a number") from None
        if not math.isfinite(value):
            raise ValueError("expected a finite number")
        return value
    if hint is str:
        return text
    raise ValueError(f"cannot be set from the command line (type {hint})")
