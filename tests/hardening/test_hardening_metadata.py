"""Issue 14, item 1: every field of a drive's metadata is validated on reading.

The ``graphpos.drive`` metadata record (origin, params, windows, tag map,
RSU map, time base, format) is checked against one table
(:data:`graphpos.io.json_rules.DRIVE_METADATA_RULES` for the JSON types,
the specs of :mod:`graphpos.drive` for the values). A bad value must give
``info``, ``run`` and ``evaluate`` one line naming the file, the field and
the value, status 2, no traceback and nothing written; nothing is coerced
(a ``wall_side`` of 0.5 is not truncated to 0).
"""

from __future__ import annotations

import json
import math

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_hardening_bad_input import DRIVE_COMMANDS, _check, rewrite, run_cli

from graphpos.drive import ORIGIN_SPECS
from graphpos.errors import FileFormatError
from graphpos.io import read_drive

#: A numpy warning would be a second line on the user's stderr.
pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")
COMMANDS = ("info", "run", "evaluate")



def with_metadata(key: str, change):
    """A metadata edit of ``rewrite``: the value of ``key`` becomes ``change(parsed value)`` written as
    JSON, or the text ``t`` when ``change`` returns ``("raw", t)`` (``change`` gets the raw text of a key
    that is not JSON: format, name)."""

    def edit(record, values):
        if record != "graphpos.drive":
            return values
        new = change(json.loads(values[key]) if key not in ("format", "name") else values[key])
        values = dict(values)
        values[key] = new[1] if isinstance(new, tuple) else json.dumps(new)
        return values

    return edit


def _set(path: tuple, value):
    """A change setting a nested entry (keys and list indexes) of a parsed value."""

    def change(parsed):
        target = parsed
        for key in path[:-1]:
            target = target[key]
        target[path[-1]] = value
        return parsed

    return change


#: case -> (metadata key, change, what the error line must contain: field and value)
CASES = {
    # origin: JSON types, then values
    "origin-lat-null": ("origin", _set(("lat_deg",), None), "metadata 'origin.lat_deg' is null, not a number"),
    "origin-lat-string": ("origin", _set(("lat_deg",), "40.4"), "metadata 'origin.lat_deg' is a string \"40.4\""),
    "origin-lat-bool": ("origin", _set(("lat_deg",), True), "metadata 'origin.lat_deg' is true, not a number"),
    "origin-lat-array": ("origin", _set(("lat_deg",), [40.4]), "metadata 'origin.lat_deg' is an array [40.4]"),
    "origin-lat-1e308": ("origin", _set(("lat_deg",), 1e308), "lat_deg = 1e+308 is outside the plausible range [-90, 90]"),
    "origin-lat-nan": ("origin", _set(("lat_deg",), math.nan), "metadata 'origin': lat_deg is nan"),
    "origin-lon-720": ("origin", _set(("lon_deg",), 720), "lon_deg = 720 is outside the plausible range [-180, 180]"),
    "origin-lon-huge-int": ("origin", _set(("lon_deg",), 10**400), "metadata 'origin.lon_deg' is a number 1000"),
    "origin-alt-absurd": ("origin", _set(("alt_m",), 1e9), "alt_m = 1e+09 is outside the plausible range"),
    "origin-unknown-field": ("origin", _set(("height",), 3.0), "metadata 'origin.height' is not a known field"),
    "origin-not-object": ("origin", lambda o: [1, 2], "metadata 'origin' is an array [1, 2], not an object"),
    "origin-not-json": ("origin", lambda o: ("raw", "{lat"), "metadata 'origin' is not valid JSON"),
    # tag map
    "wall-side-half": ("tags", _set(("wall_side", 1), 0.5), "metadata 'tags', row 1: wall_side = 0.5 is not a whole number"),
    "wall-side-two": ("tags", _set(("wall_side", 0), 2), "row 0: wall_side = 2 is outside the plausible range [-1, 1]"),
    "wall-side-string": ("tags", _set(("wall_side", 2), "1"), "metadata 'tags.wall_side[2]' is a string \"1\""),
    "group-fraction": ("tags", _set(("group", 2), 1.7), "metadata 'tags', row 2: group = 1.7 is not a whole number"),
    "group-below-none": ("tags", _set(("group", 0), -2), "row 0: group = -2 is outside the plausible range"),
    "tag-id-string": ("tags", _set(("tag_id", 3), "7"), "metadata 'tags.tag_id[3]' is a string \"7\""),
    "tag-id-fraction": ("tags", _set(("tag_id", 3), 7.5), "row 3: tag_id = 7.5 is not a whole number"),
    "tag-id-negative": ("tags", _set(("tag_id", 0), -1), "row 0: tag_id = -1 is outside the plausible range"),
    "tag-id-duplicate": ("tags", _set(("tag_id", 1), 0), "tag id 0 is listed 2 times"),
    "tag-east-null": ("tags", _set(("east_m", 0), None), "metadata 'tags.east_m[0]' is null, not a number"),
    "tag-north-absurd": ("tags", _set(("north_m", 1), 1e300), "row 1: north_m = 1e+300 is outside the plausible range"),
    "tag-column-missing": ("tags", lambda t: {k: v for k, v in t.items() if k != "north_m"}, "metadata 'tags.north_m' is missing"),
    "tag-column-short": ("tags", _set(("east_m",), [0.0]), "metadata 'tags': east_m has 1 entries for 4 ids"),
    "layout-unknown-id": ("tags", _set(("layouts", "sparse"), [99]), "layout 'sparse' names unknown tag id 99"),
    "layout-not-array": ("tags", _set(("layouts", "sparse"), "7"), "metadata 'tags.layouts.sparse' is a string \"7\""),
    "tags-unknown-field": ("tags", _set(("colour",), [1, 2, 3, 4]), "metadata 'tags.colour' is not a known field"),
    # RSU map
    "rsu-id-bool": ("rsus", _set(("rsu_id", 0), True), "metadata 'rsus.rsu_id[0]' is true, not a number"),
    "rsu-east-nan": ("rsus", _set(("east_m", 1), math.nan), "metadata 'rsus', row 1: east_m is nan"),
    # windows
    "window-start-string": ("windows", _set((0, "start_s"), "1.0"), "metadata 'windows[0].start_s' is a string \"1.0\""),
    "window-reversed": ("windows", _set((0, "end_s"), -5.0), "metadata 'windows': window 'in_tunnel' has bad bounds [1.0, -5.0]"),
    "window-absurd": ("windows", _set((1, "end_s"), 1e300), "window 'zone:open' has bad bounds"),
    "window-label-number": ("windows", _set((0, "label"), 5), "metadata 'windows[0].label' is a number 5, not a string"),
    "window-end-missing": ("windows", lambda w: [{"label": "x", "start_s": 0.0}], "metadata 'windows[0].end_s' is missing"),
    "windows-not-array": ("windows", lambda w: {"label": "x"}, "metadata 'windows' is an object"),
    # params: keys graphpos reads
    "rss-environment-unknown": ("params", _set(("rss_environment",), "cave"),
                                "metadata 'params.rss_environment' is a string \"cave\", not a known RSS environment"),
    "rss-environment-number": ("params", _set(("rss_environment",), 3), "metadata 'params.rss_environment' is a number 3"),
    "initial-pose-string": ("params", _set(("initial_pose",), {"east_m": "0", "north_m": 0, "yaw_rad": 0}),
                            "metadata 'params.initial_pose.east_m' is a string \"0\""),
    "initial-pose-incomplete": ("params", _set(("initial_pose",), {"east_m": 0.0}),
                                "metadata 'params.initial_pose' is not a usable start pose"),
    "initial-pose-nan": ("params", _set(("initial_pose",), {"east_m": math.nan, "north_m": 0, "yaw_rad": 0}),
                         "metadata 'params.initial_pose' is not a usable start pose"),
    "params-not-object": ("params", lambda p: [1, 2], "metadata 'params' is an array [1, 2], not an object"),
    # the time base and the format
    "time-base-string": ("time_base_s", lambda b: "0", "metadata 'time_base_s' is a string \"0\""),
    "time-base-positive": ("time_base_s", lambda b: 5.0, "metadata 'time_base_s' is a number 5.0, outside"),
    "format-newer": ("format", lambda f: ("raw", "graphpos.drive/9"), "unsupported drive format 'graphpos.drive/9'"),
    "format-foreign": ("format", lambda f: ("raw", "other"), "unsupported drive format 'other'"),
}


def _bad_file(small, tmp_path, case):
    key, change, _ = CASES[case]
    return rewrite(small, tmp_path / f"{case}.mcap", lambda t, i, m: m, metadata=with_metadata(key, change))


@pytest.mark.parametrize("command", COMMANDS)
@pytest.mark.parametrize("case", list(CASES))
def test_bad_metadata_is_one_line_naming_file_field_value(capsys, tmp_path, small, case, command):
    path = _bad_file(small, tmp_path, case)
    _check(capsys, tmp_path, command, DRIVE_COMMANDS[command], path, CASES[case][2], valid=False)


def test_valid_metadata_still_reads(tmp_path, small):
    """The unchanged record, and ids written as whole floats (JSON Schema integers), read."""
    path = rewrite(small, tmp_path / "floats.mcap", lambda t, i, m: m,
                   metadata=with_metadata("tags", lambda t: {**t, "tag_id": [float(v) for v in t["tag_id"]]}))
    assert read_drive(path).tags.tag_id.tolist() == [0, 1, 2, 7]


# -- property-based: any value of a wrong JSON type, anywhere a number belongs ----------------------------------
not_numbers = st.one_of(
    st.none(), st.booleans(), st.text(max_size=6), st.lists(st.floats(allow_nan=False), max_size=2),
    st.dictionaries(st.text(max_size=3), st.integers(), max_size=2),
)
#: (metadata key, path to a number in it) of every number field of the record
NUMBER_PLACES = [("origin", (spec.name,)) for spec in ORIGIN_SPECS] + [
    ("tags", (column, i)) for column in ("tag_id", "east_m", "north_m", "wall_side", "group") for i in (0, 3)
] + [("rsus", (column, 1)) for column in ("rsu_id", "east_m", "north_m")] + [
    ("windows", (0, "start_s")), ("windows", (1, "end_s")), ("tags", ("layouts", "sparse", 0)),
]


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(place=st.sampled_from(NUMBER_PLACES), value=not_numbers)
def test_any_wrong_type_in_a_number_field_is_refused(tmp_path, small, place, value):
    key, path = place
    bad = rewrite(small, tmp_path / "bad.mcap", lambda t, i, m: m, metadata=with_metadata(key, _set(path, value)))
    field = key + "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in path)
    with pytest.raises(FileFormatError) as info:
        read_drive(bad)
    message = str(info.value)
    assert message.startswith(f"{bad}: metadata '{field}' is ") and "not a number" in message
    assert json.dumps(value)[:20] in message


finite_out_of_range = st.floats(allow_nan=False, allow_infinity=False).filter(lambda v: not -90 <= v <= 90)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(lat_deg=finite_out_of_range, wall_side=st.floats(-1, 1).filter(lambda v: v not in (-1.0, 0.0, 1.0)))
def test_values_out_of_range_or_not_whole_are_refused_not_truncated(tmp_path, small, lat_deg, wall_side):
    for key, path, value, field in (("origin", ("lat_deg",), lat_deg, "lat_deg"), ("tags", ("wall_side", 0), wall_side, "wall_side")):
        bad = rewrite(small, tmp_path / "bad.mcap", lambda t, i, m: m, metadata=with_metadata(key, _set(path, value)))
        with pytest.raises(FileFormatError, match=rf"metadata '{key}'.*: {field} = "):
            read_drive(bad)


@pytest.mark.parametrize("origin, names", [("40,-79,20000", "alt_m = 20000 is outside"), ("91,0", "lat_deg = 91 is outside"),
                                           ("40,nan", "lon_deg is nan"), ("40,-200", "lon_deg = -200 is outside")])
def test_origin_option_is_checked_by_the_same_specs(capsys, tmp_path, samples, origin, names):
    """``import --origin`` goes through the origin's specs too: one line, nothing written."""
    argv = ["import", "plaza", "{file}", "-o", "{out}/plaza.mcap", "--origin", origin]
    status, _, err = run_cli(capsys, [a.format(file=samples["mat"], out=tmp_path) for a in argv])
    assert status == 2 and len(err.strip().splitlines()) == 1 and names in err and "Traceback" not in err
    assert not (tmp_path / "plaza.mcap").exists()
