"""Issue 14, item 2: a field of the wrong JSON type is an error, never coerced.

A number field holds a JSON number (integer or float; not ``true``, not
``"2.01"``, not ``[2.0]``); an id is a number that is whole. Anything else,
in any channel's rows or an estimate's, gives one line naming the file, the
channel (or topic), the row and the field, with the value.
"""

from __future__ import annotations

import json

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_foreign_and_bad_files import rows, write_foreign
from test_hardening_bad_input import DRIVE_COMMANDS, _check, rewrite, run_cli, set_value

from graphpos.drive import CHANNEL_SPECS
from graphpos.errors import DriveError, FileFormatError
from graphpos.io import read_drive, read_estimates

#: A numpy warning would be a second line on the user's stderr.
pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")
COMMANDS = ("info", "run", "evaluate")



#: case -> (channel, field, value written into row 1, what the line names after "channel 'X', row 1: ")
CASES = {
    "speed-string": ("wheel", "speed_mps", "2.01", "field 'speed_mps' is a string \"2.01\", not a number"),
    "speed-true": ("wheel", "speed_mps", True, "field 'speed_mps' is true, not a number"),
    "speed-false": ("wheel", "speed_mps", False, "field 'speed_mps' is false, not a number"),
    "speed-array": ("wheel", "speed_mps", [2.0], "field 'speed_mps' is an array [2.0], not a number"),
    "speed-object": ("wheel", "speed_mps", {"value": 2.0}, "field 'speed_mps' is an object {\"value\": 2.0}"),
    "tag-id-string": ("rfid", "tag_id", "7", "field 'tag_id' is a string \"7\", not a number"),
    "tag-id-true": ("rfid", "tag_id", True, "field 'tag_id' is true, not a number"),
    "tag-id-array": ("rfid", "tag_id", [7], "field 'tag_id' is an array [7], not a number"),
    "tag-id-fraction": ("rfid", "tag_id", 7.5, "tag_id = 7.5 is not a whole number"),
    "rss-string": ("rfid", "rss", "120", "field 'rss' is a string \"120\", not a number"),
    "arrival-string": ("rfid", "arrival_s", "0.5", "field 'arrival_s' is a string \"0.5\""),
    "time-string": ("imu", "t_s", "0.011", "field 't_s' is a string \"0.011\", not a number"),
    "accel-bool": ("imu", "accel_x_mps2", True, "field 'accel_x_mps2' is true, not a number"),
    "rsu-id-string": ("rsu", "rsu_id", "10", "field 'rsu_id' is a string \"10\", not a number"),
    "gnss-sigma-bool": ("gnss", "sigma_m", True, "field 'sigma_m' is true, not a number"),
    "truth-east-string": ("truth", "east_m", "0", "field 'east_m' is a string \"0\", not a number"),
    "compass-yaw-array": ("compass", "yaw_rad", [0.1], "field 'yaw_rad' is an array [0.1], not a number"),
}


@pytest.mark.parametrize("command", COMMANDS)
@pytest.mark.parametrize("case", list(CASES))
def test_wrong_type_is_one_line_naming_channel_row_field(capsys, tmp_path, small, case, command):
    channel, field, value, names = CASES[case]
    path = rewrite(small, tmp_path / f"{case}.mcap", set_value(channel, field, value))
    _check(capsys, tmp_path, command, DRIVE_COMMANDS[command], path, f"channel '{channel}', row 1: {names}", valid=False)


def test_whole_floats_are_integers(tmp_path, small):
    """An id written as 7.0 is a JSON Schema integer: read as it is."""
    path = rewrite(small, tmp_path / "float-ids.mcap", set_value("rfid", "tag_id", 7.0))
    assert read_drive(path).rfid.tag_id[1] == 7.0


# -- property-based: any wrong type in any field of any channel ---------------------------------------------------
not_numbers = st.one_of(
    st.booleans(), st.text(max_size=6), st.lists(st.integers(-5, 5), max_size=2),
    st.dictionaries(st.text(max_size=3), st.floats(allow_nan=False), max_size=2),
)
FIELDS = [(kind, spec.name) for kind, specs in CHANNEL_SPECS.items() for spec in specs]


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(place=st.sampled_from(FIELDS), value=not_numbers, row=st.integers(0, 3))
def test_any_wrong_type_anywhere_names_channel_row_field(tmp_path, small, place, value, row):
    channel, field = place
    path = rewrite(small, tmp_path / "bad.mcap", set_value(channel, field, value, row=row))
    with pytest.raises(DriveError) as info:
        read_drive(path)
    message = str(info.value)
    assert message.startswith(f"{path}: channel '{channel}', row {row}: field '{field}' is ")
    assert message.endswith("not a number") and json.dumps(value)[:20] in message


# -- estimates: the same rule for their rows ------------------------------------------------------------------------
WHEEL = {"/wheel": ("graphpos.wheel", "json", rows(t_s=[0.0, 1.0], speed_mps=[1.0, 1.0]))}
GOOD_ESTIMATE = {"t_s": 0.0, "east_m": 1.0, "north_m": 2.0, "cov_en_m2": [1.0, 0.0, 0.0, 1.0]}


@pytest.mark.parametrize("field, value, names", [
    ("east_m", "1", "field 'east_m' is a string \"1\", not a number"),
    ("t_s", True, "field 't_s' is true, not a number"),
    ("yaw_rad", [0.0], "field 'yaw_rad' is an array [0.0], not a number"),
    ("cov_en_m2", [1.0, 0.0, 1.0], "field 'cov_en_m2' is an array [1.0, 0.0, 1.0], not null or an array of 4 numbers"),
    ("cov_en_m2", ["1", 0, 0, 1], "field 'cov_en_m2' is an array [\"1\", 0, 0, 1], not null or an array of 4 numbers"),
    ("cov_en_m2", "diag", "field 'cov_en_m2' is a string \"diag\", not null or an array of 4 numbers"),
])
def test_wrong_type_in_an_estimate_row(capsys, tmp_path, field, value, names):
    path = tmp_path / "est.mcap"
    bad = {**GOOD_ESTIMATE, "t_s": 1.0, field: value}
    payloads = [json.dumps(GOOD_ESTIMATE).encode(), json.dumps(bad).encode()]
    write_foreign(path, {**WHEEL, "/estimates/x": ("graphpos.estimate", "json", payloads)})
    with pytest.raises(FileFormatError, match=r"est\.mcap: topic /estimates/x, message 1: "):
        read_estimates(path)
    status, _, err = run_cli(capsys, ["info", str(path)])
    assert status == 2 and len(err.strip().splitlines()) == 1 and names in err and "est.mcap" in err
