"""What each JSON value of a drive file must be, checked on reading.

A drive file holds JSON in two places: one object per message (a row of a
channel or of an estimate) and the values of the ``graphpos.drive``
metadata record (:data:`DRIVE_METADATA_RULES`). Their JSON *types* are
checked here, before any value reaches the drive's classes, which then
check the values themselves (finite, in range, whole, unique:
:func:`graphpos.drive.check_column` and the specs in :mod:`graphpos.drive`).
Nothing is coerced: a value of the wrong type is an error naming the field
and the value, never converted.

- A *number* is a JSON integer or float (Python ``int`` or ``float`` after
  parsing; never ``true``/``false``, a string or an array). Ids are
  numbers that must be whole, as JSON Schema's ``integer``: ``7`` and
  ``7.0``, not ``7.5`` or ``"7"``.
- A row field may be ``null`` (or absent) where its column is optional.
- The metadata keys ``format`` and ``name`` are plain text (MCAP metadata
  values are strings); every other key holds the text of one JSON value.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from itertools import chain
from typing import Any, Callable

import numpy as np

from graphpos.drive import ORIGIN_SPECS, RSU_SPECS, TAG_SPECS
from graphpos.errors import ConfigError

#: Python types of a parsed JSON number (``bool`` is not one).
_NUMBER_TYPES = frozenset({int, float})
#: ... and of a row field's value (``None``: null, or absent).
_FIELD_TYPES = _NUMBER_TYPES | {type(None)}
_TYPE_TESTS: dict[str, Callable[[Any], bool]] = {
    "number": lambda v: type(v) in _NUMBER_TYPES,
    "string": lambda v: type(v) is str,
    "array": lambda v: type(v) is list,
    "object": lambda v: type(v) is dict,
}
_ARTICLE = {"number": "a number", "string": "a string", "array": "an array", "object": "an object"}


class JsonRuleError(Exception):
    """Internal: a JSON value breaks its rule; the reader adds the file.

    Parameters
    ----------
    field : str
        Where the value is: a field name, dotted and indexed inside
        metadata (``origin.lat_deg``, ``tags.wall_side[3]``).
    reason : str
        What is wrong, naming the value.
    row : int, optional
        The message (row) of a channel or estimate.
    """

    def __init__(self, field: str, reason: str, row: int | None = None):
        self.field = field
        self.reason = reason
        self.row = row
        super().__init__(f"{field} {reason}")


def describe(value: Any) -> str:
    """A JSON value as an error shows it: its type and (shortened) text."""
    try:
        text = json.dumps(value)
    except (ValueError, RecursionError):  # nested too deep to show
        text = "[...]" if type(value) is list else "{...}"
    text = text if len(text) <= 40 else text[:37] + "..."
    if value is None or type(value) is bool:
        return text
    kind = next((k for k, test in _TYPE_TESTS.items() if test(value)), "a value")
    return f"{_ARTICLE.get(kind, kind)} {text}"


def _out_of_range(value: int | float) -> bool:
    """True for an integer too large for a float64 (``1`` and 400 zeros)."""
    try:
        float(value)
    except OverflowError:
        return True
    return False


@dataclass(frozen=True)
class Rule:
    """What one JSON value must be.

    Parameters
    ----------
    type : {"number", "string", "array", "object"}
        Its JSON type (a number: see the module docstring).
    items : Rule, optional
        The rule of every element of an array, or of every value of an
        object that maps names to values (the layouts).
    fields : dict of str to Rule
        The rules of an object's known keys.
    required : tuple of str
        Keys an object must have.
    other_keys : bool
        An object may hold keys not in ``fields`` (checked by ``items``
        where given, else anything).
    check : callable, optional
        A further test of a value of the right type: what is wrong with it
        (a phrase after "is"), or None.
    """

    type: str
    items: "Rule | None" = None
    fields: dict[str, "Rule"] = field(default_factory=dict)
    required: tuple[str, ...] = ()
    other_keys: bool = False
    check: Callable[[Any], str | None] | None = None


def check_value(value: Any, rule: Rule, where: str) -> None:
    """Check a parsed JSON value against its rule, recursively.

    Raises
    ------
    JsonRuleError
        The first value that breaks its rule, with its place ``where``
        (dotted and indexed from the given one).
    """
    if not _TYPE_TESTS[rule.type](value):
        raise JsonRuleError(where, f"is {describe(value)}, not {_ARTICLE[rule.type]}")
    if rule.type == "number" and _out_of_range(value):
        raise JsonRuleError(where, f"is {describe(value)}, out of range")
    if rule.type == "array" and rule.items is not None:
        for i, item in enumerate(value):
            check_value(item, rule.items, f"{where}[{i}]")
    if rule.type == "object":
        for key in rule.required:
            if key not in value:
                raise JsonRuleError(f"{where}.{key}", "is missing")
        for key, item in value.items():
            if key in rule.fields:
                check_value(item, rule.fields[key], f"{where}.{key}")
            elif not rule.other_keys:
                raise JsonRuleError(f"{where}.{key}", f"is not a known field (known: {', '.join(rule.fields)})")
            elif rule.items is not None:
                check_value(item, rule.items, f"{where}.{key}")
    problem = rule.check(value) if rule.check is not None else None
    if problem is not None:
        raise JsonRuleError(where, f"is {problem}")


def number_column(values: list[Any], name: str, first_row: int) -> np.ndarray:
    """One field of consecutive rows as float64 (NaN where null or absent).

    Parameters
    ----------
    values : list
        The field's parsed value in each row (None where null or absent).
    name : str
        The field, for errors.
    first_row : int
        Row (message index) of ``values[0]``, for errors.

    Raises
    ------
    JsonRuleError
        At the first row whose value is not a number or null, or is too
        large for a float64.
    """
    if not _FIELD_TYPES.issuperset(map(type, values)):
        row = next(i for i, v in enumerate(values) if type(v) not in _FIELD_TYPES)
        raise JsonRuleError(name, f"is {describe(values[row])}, not a number", first_row + row)
    try:
        return np.array(values, dtype=np.float64)
    except OverflowError:
        row = next(i for i, v in enumerate(values) if v is not None and _out_of_range(v))
        raise JsonRuleError(name, f"is {describe(values[row])}, out of range", first_row + row) from None


def number_rows(values: list[Any], name: str, first_row: int, width: int) -> np.ndarray:
    """One field of consecutive rows that holds null or an array of
    ``width`` numbers (or nulls) in each, as a (rows, width) float64 array
    (NaN where null).

    Raises
    ------
    JsonRuleError
        As :func:`number_column`.
    """
    given = [v for v in values if v is not None]
    if not ({list}.issuperset(map(type, given)) and {width}.issuperset(map(len, given))
            and _FIELD_TYPES.issuperset(map(type, chain.from_iterable(given)))):
        row = next(i for i, v in enumerate(values)
                   if v is not None and not (type(v) is list and len(v) == width and _FIELD_TYPES.issuperset(map(type, v))))
        raise JsonRuleError(name, f"is {describe(values[row])}, not null or an array of {width} numbers", first_row + row)
    missing = [None] * width
    try:
        return np.array([missing if v is None else v for v in values], dtype=np.float64).reshape(len(values), width)
    except OverflowError:
        row = next(i for i, v in enumerate(values) if v is not None and any(x is not None and _out_of_range(x) for x in v))
        raise JsonRuleError(name, f"is {describe(values[row])}, out of range", first_row + row) from None


# ---------------------------------------------------------------------------
# The metadata record
# ---------------------------------------------------------------------------

NUMBER = Rule("number")
TEXT = Rule("string")


def _known_environment(name: str) -> str | None:
    from graphpos.sim.rss import ENVIRONMENTS

    if name in ENVIRONMENTS:
        return None
    return f"{describe(name)}, not a known RSS environment (known: {', '.join(ENVIRONMENTS)})"


def _start_pose(pose: dict[str, Any]) -> str | None:
    from graphpos.ignition import StartPose

    try:
        StartPose.from_params({"initial_pose": pose})
    except ConfigError as exc:
        return f"not a usable start pose ({exc})"
    return None


#: Keys of a drive's ``params`` that graphpos reads; every other key is
#: provenance (scenario, seed, importer counts ...), kept as it is.
PARAM_RULES: dict[str, Rule] = {
    # the environment an RSS range model is calibrated in (graphpos.ranging.drive_models)
    "rss_environment": Rule("string", check=_known_environment),
    # a start pose stored with the drive (graphpos.ignition.StartPose)
    "initial_pose": Rule("object", items=NUMBER, other_keys=True, check=_start_pose),
}


def _time_base(base_s: float) -> str | None:
    if -1e10 <= base_s <= 0.0:
        return None
    return f"{describe(base_s)}, outside [-1e10, 0]"


def _map_columns(specs) -> dict[str, Rule]:
    """A map stored as columns: one array of numbers per column spec."""
    return {spec.name: Rule("array", items=NUMBER) for spec in specs}


#: The keys of the ``graphpos.drive`` metadata record other than ``format``
#: and ``name``, each the text of one JSON value; any key may be absent
#: (defaults: no maps, no windows, empty params, the default origin).
DRIVE_METADATA_RULES: dict[str, Rule] = {
    # message times are t_s - time_base_s in integer nanoseconds (graphpos.io.mcap_drive)
    "time_base_s": Rule("number", check=_time_base),
    # WGS84 position of the local frame's origin (values: graphpos.drive.ORIGIN_SPECS)
    "origin": Rule("object", fields={spec.name: NUMBER for spec in ORIGIN_SPECS}),
    "params": Rule("object", fields=PARAM_RULES, other_keys=True),
    "windows": Rule("array", items=Rule("object", fields={"label": TEXT, "start_s": NUMBER, "end_s": NUMBER},
                                        required=("label", "start_s", "end_s"))),
    # columns of graphpos.drive.TAG_SPECS, and named subsets of the tag ids
    "tags": Rule("object", fields={**_map_columns(TAG_SPECS), "layouts": Rule("object", items=Rule("array", items=NUMBER),
                                                                             other_keys=True)},
                 required=tuple(spec.name for spec in TAG_SPECS)),
    # columns of graphpos.drive.RSU_SPECS
    "rsus": Rule("object", fields=_map_columns(RSU_SPECS), required=tuple(spec.name for spec in RSU_SPECS)),
}

#: The JSON value among an estimate's channel metadata (the others are plain text).
ESTIMATE_METADATA_RULES: dict[str, Rule] = {"diagnostics": Rule("object", other_keys=True)}
