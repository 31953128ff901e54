"""Bad input at the door: every command that reads a file, on a corpus of
broken, foreign and awkward files.

Each broken file must give exactly one line on stderr naming the file (and
the channel and row where known), exit status 2, and leave nothing behind in
the output location. Awkward but valid files (no truth, duplicate
timestamps, an empty channel, a one-second drive) must either work (status
0) or give such a line; never a traceback.

The reader itself is tested on the same kinds of damage in ``tests/io``;
here every command meets them through ``graphpos.cli.main``: ``info``,
``run``, ``evaluate``, ``ranging fit`` (drive files), ``import plaza`` and
``reproduce --plaza`` (.mat files), ``simulate --config`` (TOML files).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer
from plaza_samples import synthetic_plaza

from graphpos.cli import main
from graphpos.registry import estimator_classes

#: A numpy warning would be a second line on the user's stderr.
pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")

# -- commands --------------------------------------------------------------------------------------------------
DRIVE_COMMANDS = {
    "info": ["info", "{file}"],
    "run": ["run", "{file}", "-e", "rfid-ekf", "--out-dir", "{out}/run"],
    "evaluate": ["evaluate", "{file}", "-e", "dr", "-o", "{out}/eval", "--workers", "1", "--no-progress"],
    "ranging-fit": ["ranging", "fit", "{file}", "--truth", "-o", "{out}/model.json"],
}
MAT_COMMANDS = {
    "import-plaza": ["import", "plaza", "{file}", "-o", "{out}/plaza.mcap"],
    "reproduce-plaza": ["reproduce", "--quick", "--plaza", "{file}", "-o", "{out}/repro", "--workers", "1",
                        "--no-progress"],
}
CONFIG_COMMANDS = {"simulate-config": ["simulate", "paper-straight", "--duration", "3", "--config", "{file}",
                                       "-o", "{out}/sim.mcap"]}
#: The first word of the error line of each command.
PREFIX = {"ranging-fit": "ranging fit", "import-plaza": "import plaza", "reproduce-plaza": "reproduce",
          "simulate-config": "simulate"}

CHANNELS = ("imu", "wheel", "compass", "rfid", "rsu", "gnss", "truth")
#: The column spoiled in each channel (a required one where possible; the rfid range is optional but range-checked).
BAD_COLUMN = {"imu": "yaw_rate_radps", "wheel": "speed_mps", "compass": "yaw_rad", "rfid": "tag_id",
              "rsu": "sigma_m", "gnss": "east_m", "truth": "east_m"}
ABSURD_COLUMN = {**BAD_COLUMN, "rfid": "rss"}


# -- making bad files -------------------------------------------------------------------------------------------
def rewrite(src: Path, dst: Path, edit, metadata=None) -> Path:
    """Copy an MCAP drive message by message; ``edit(channel, row, payload)`` returns the new payload dict,
    a list of dicts (several messages), or None (drop the message). Maps and windows are kept, or
    ``metadata(record name, values)`` returns the values of each metadata record."""
    with open(src, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        records = [(m.name, dict(m.metadata)) for m in reader.iter_metadata()]
        messages = [(ch.id, msg.log_time, msg.data) for _, ch, msg in reader.iter_messages(log_time_order=True)]
    rows: dict[int, int] = {}
    with open(dst, "wb") as out:
        writer = Writer(out)
        writer.start(profile="", library="graphpos-tests")
        schemas = {sid: writer.register_schema(s.name, s.encoding, s.data) for sid, s in summary.schemas.items()}
        channels = {cid: writer.register_channel(c.topic, c.message_encoding, schemas[c.schema_id], dict(c.metadata))
                    for cid, c in summary.channels.items()}
        for name, meta in records:
            writer.add_metadata(name, metadata(name, meta) if metadata is not None else meta)
        for cid, log_time, data in messages:
            topic = summary.channels[cid].topic.strip("/")
            row = rows.get(cid, 0)
            rows[cid] = row + 1
            payload = json.loads(data)
            new = edit(topic, row, payload) if "/" not in topic else payload
            for one in new if isinstance(new, list) else [] if new is None else [new]:
                writer.add_message(channels[cid], log_time, json.dumps(one).encode(), log_time)
        writer.finish()
    return dst


def set_value(channel: str, column: str, value, row: int = 1):
    def edit(topic, i, payload):
        if topic == channel and i == row:
            payload[column] = value
        return payload

    return edit


def time_backwards(channel: str):
    first = {}

    def edit(topic, i, payload):
        if topic == channel:
            first.setdefault(topic, payload["t_s"])
            if i == 2:
                payload["t_s"] = first[topic] - 0.001
        return payload

    return edit


def _write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


# -- the drive corpus -------------------------------------------------------------------------------------------
def _drive_cases():
    """name -> (builder(samples, path) -> path, what the error line names, or None for a valid file)."""
    cases = {
        "missing": (lambda s, p: p, "no such file"),
        "empty": (lambda s, p: _write(p, b""), "empty file"),
        "random-bytes": (lambda s, p: _write(p, np.random.default_rng(8).bytes(4096)), "not an MCAP file"),
        "truncated-no-footer": (lambda s, p: _write(p, s["sim"].read_bytes()[:-40]), "truncated"),
        "truncated-half": (lambda s, p: _write(p, s["sim"].read_bytes()[: s["sim"].stat().st_size // 2]), ""),
        "folder": (lambda s, p: p.mkdir() or p, "folder"),
        "foreign-schemas": (lambda s, p: _foreign(p), "not a graphpos drive"),
        "unknown-tag-id": (lambda s, p: rewrite(s["every"], p, set_value("rfid", "tag_id", 99999)),
                           "channel 'rfid', row 1: tag id 99999 is not in the tag map"),
        "unknown-rsu-id": (lambda s, p: rewrite(s["every"], p, set_value("rsu", "rsu_id", 999)),
                           "channel 'rsu', row 1"),
    }
    for ch in CHANNELS:
        col = BAD_COLUMN[ch]
        cases[f"nan-{ch}"] = (lambda s, p, ch=ch, col=col: rewrite(s["every"], p, set_value(ch, col, math.nan)),
                              f"channel '{ch}', row 1")
        cases[f"inf-{ch}"] = (lambda s, p, ch=ch, col=col: rewrite(s["every"], p, set_value(ch, col, math.inf)),
                              f"channel '{ch}', row 1")
        cases[f"absurd-{ch}"] = (lambda s, p, ch=ch: rewrite(s["every"], p, set_value(ch, ABSURD_COLUMN[ch], 1e12)),
                                 f"channel '{ch}', row 1")
        cases[f"time-backwards-{ch}"] = (lambda s, p, ch=ch: rewrite(s["every"], p, time_backwards(ch)),
                                         f"channel '{ch}', row 2: time goes backwards")
    cases["nan-time"] = (lambda s, p: rewrite(s["every"], p, set_value("wheel", "t_s", math.nan)), "channel 'wheel', row 1")
    # Awkward but valid: must work or give one clear line.
    cases["no-truth"] = (lambda s, p: s["no-truth"], None)
    cases["duplicate-timestamps"] = (lambda s, p: rewrite(s["sim"], p, lambda t, i, m: [m, m] if i % 7 == 3 else m), None)
    cases["empty-channel"] = (lambda s, p: rewrite(s["sim"], p, lambda t, i, m: None if t == "compass" else m), None)
    cases["all-channels-empty"] = (lambda s, p: rewrite(s["sim"], p, lambda t, i, m: None), None)
    cases["one-second"] = (lambda s, p: s["one-second"], None)
    return cases


def _foreign(path: Path) -> Path:
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start(profile="ros2", library="someone-else")
        sid = writer.register_schema("sensor_msgs/msg/NavSatFix", "ros2msg", b"float64 latitude")
        cid = writer.register_channel("/fix", "cdr", sid)
        for i in range(3):
            writer.add_message(cid, i * 10**9, b"\x00\x01\x00\x00" + bytes(8), i * 10**9)
        writer.finish()
    return path


DRIVE_CASES = _drive_cases()
#: Valid-but-awkward files that some commands must refuse, and the reason they give.
#: (ranging fit works without the truth channel: a simulated drive's rfid rows carry their true range.)
REFUSALS = {("no-truth", "evaluate"): "needs truth",
            ("all-channels-empty", "evaluate"): "truth", ("all-channels-empty", "ranging-fit"): "",
            ("all-channels-empty", "run"): ""}


def _tree(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


def run_cli(capsys, argv: list[str]) -> tuple[int, str, str]:
    try:
        status = main(argv)
    except SystemExit as exc:  # argparse
        status = exc.code
    out, err = capsys.readouterr()
    return status, out, err


def assert_one_clear_line(status, err, command, path: Path | None, names: str) -> None:
    lines = err.strip().splitlines()
    assert status == 2, f"status {status}, stderr: {err}"
    assert len(lines) == 1, f"expected one line, got: {err}"
    assert lines[0].startswith(f"graphpos {PREFIX.get(command, command)}: error:"), lines[0]
    assert "Traceback" not in err and "np.float64" not in err, "the line shows internals"
    if path is not None:
        assert path.name in lines[0], f"the line does not name the file: {lines[0]}"
    assert names in lines[0], f"{names!r} not in: {lines[0]}"


def _check(capsys, tmp_path, command, argv_template, path, names, valid, name_file=True):
    """Run one command on one file: "ok" (a valid file may work) or "error" (one clear line, nothing left)."""
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    argv = [a.format(file=path, out=out_dir) for a in argv_template]
    before = _tree(tmp_path)
    status, out, err = run_cli(capsys, argv)
    if valid and status == 0:
        assert "Traceback" not in err
        return "ok"
    assert_one_clear_line(status, err, command, path if name_file else None, names or "")
    assert _tree(tmp_path) == before, f"left behind: {_tree(tmp_path) - before}"
    return "error"


@pytest.mark.parametrize("command", list(DRIVE_COMMANDS))
@pytest.mark.parametrize("case", list(DRIVE_CASES))
def test_drive_corpus(capsys, tmp_path, samples, case, command):
    build, names = DRIVE_CASES[case]
    path = build(samples, tmp_path / f"{case}.mcap")
    refusal = REFUSALS.get((case, command))
    valid = names is None and refusal is None
    # Refusing a valid file happens after reading it; test_refusals_name_the_file checks those lines name it.
    outcome = _check(capsys, tmp_path, command, DRIVE_COMMANDS[command], path,
                     refusal if refusal is not None else names, valid=valid, name_file=names is not None)
    if refusal is not None:
        assert outcome == "error"


@pytest.mark.parametrize("command, argv, case", [
    pytest.param("run", ["run", "{file}", "-e", "fusion-ekf", "--out-dir", "{out}/run"], "one-second",
                 id="run-fusion-ekf-one-second"),
    pytest.param("evaluate", DRIVE_COMMANDS["evaluate"], "no-truth", id="evaluate-no-truth"),
    pytest.param("ranging-fit", DRIVE_COMMANDS["ranging-fit"], "all-channels-empty", id="ranging-fit-empty"),
    pytest.param("ranging-fit", DRIVE_COMMANDS["ranging-fit"], "one-second", id="ranging-fit-one-second"),
])
def test_refusals_name_the_file(capsys, tmp_path, samples, command, argv, case):
    """A valid drive a command cannot use: the one line names the file, not only the drive inside."""
    path = DRIVE_CASES[case][0](samples, tmp_path / f"{case}.mcap")
    assert _check(capsys, tmp_path, command, argv, path, "", valid=False) == "error"


@pytest.mark.parametrize("case", ["one-second", "duplicate-timestamps", "empty-channel", "no-truth"])
@pytest.mark.parametrize("estimator", list(estimator_classes()))
def test_every_estimator_on_awkward_drives(capsys, tmp_path, samples, case, estimator):
    """An awkward but valid drive: every estimator either runs or refuses it in one clear line."""
    build, _ = DRIVE_CASES[case]
    path = build(samples, tmp_path / f"{case}.mcap")
    template = ["run", "{file}", "-e", estimator, "--out-dir", "{out}/run"]
    if _check(capsys, tmp_path, "run", template, path, "", valid=True, name_file=False) == "ok":
        rows = (tmp_path / "out" / "run" / f"{estimator}.csv").read_text().splitlines()
        assert len(rows) >= 1


# -- the .mat corpus --------------------------------------------------------------------------------------------
def _mat_with(path: Path, **arrays) -> Path:
    synthetic_plaza(path, **arrays)
    return path


def _mat_cases():
    cases = {
        "missing": (lambda s, p: p, ""),
        "empty": (lambda s, p: _write(p, b""), ""),
        "random-bytes": (lambda s, p: _write(p, np.random.default_rng(9).bytes(4096)), ""),
        "truncated": (lambda s, p: _write(p, s["mat"].read_bytes()[: s["mat"].stat().st_size // 2]), ""),
        "folder": (lambda s, p: p.mkdir() or p, ""),
        "an-mcap-instead": (lambda s, p: _write(p, s["sim"].read_bytes()), ""),
    }
    for array in ("GT", "DR", "TD", "TL"):
        cases[f"missing-{array}"] = (lambda s, p, a=array: _mat_drop(p, a), f"'{array}'")
    cases["nan-range"] = (lambda s, p: _mat_edit(p, "TD", (5, 3), math.nan), "TD")
    cases["inf-truth"] = (lambda s, p: _mat_edit(p, "GT", (5, 1), math.inf), "GT")
    cases["absurd-range"] = (lambda s, p: _mat_edit(p, "TD", (5, 3), 1e12), "TD")
    cases["unknown-beacon"] = (lambda s, p: _mat_edit(p, "TD", (5, 2), 99.0), "99")
    cases["truth-time-backwards"] = (lambda s, p: _mat_edit(p, "GT", (5, 0), 50.0), "GT")
    cases["empty-ranges"] = (lambda s, p: _mat_with(p, TD=np.zeros((0, 4))), "TD")
    return cases


def _mat_drop(path: Path, array: str) -> Path:
    synthetic_plaza(path, drop=array)
    return path


def _mat_edit(path: Path, array: str, index: tuple[int, int], value: float) -> Path:
    arrays = synthetic_plaza(path)
    changed = np.array(arrays[array], dtype=np.float64)
    changed[index] = value
    synthetic_plaza(path, **{array: changed})
    return path


MAT_CASES = _mat_cases()



@pytest.mark.parametrize("command", [pytest.param("import-plaza"),
                                     pytest.param("reproduce-plaza")])
@pytest.mark.parametrize("case", list(MAT_CASES))
def test_mat_corpus(capsys, tmp_path, samples, case, command):
    build, names = MAT_CASES[case]
    path = build(samples, tmp_path / f"{case}.mat")
    _check(capsys, tmp_path, command, MAT_COMMANDS[command], path, names, valid=False)


# -- the config corpus ------------------------------------------------------------------------------------------
CONFIG_CASES = {
    "empty": (b"", None),
    "random-bytes": (np.random.default_rng(10).bytes(512), ""),
    "not-utf8": (b"[imu]\nrate_hz = 100 # \xff\xfe\n", ""),
    "truncated": (b"[imu]\nrate_hz = ", ""),
    "nan": (b"[wheel]\nsigma_mps = nan\n", "sigma_mps"),
    "inf": (b"[imu]\nrate_hz = inf\n", "rate_hz"),
    "absurd": (b"[imu]\nrate_hz = 1e12\n", "rate_hz"),
    "negative-duration": (b"[route]\ntunnel_straight_m = -120.0\n", "tunnel_straight_m"),
    "wrong-type": (b"[imu]\nrate_hz = \"fast\"\n", "rate_hz"),
    "table-expected": (b"imu = 3\n", "imu"),
    "folder": (None, ""),
}


@pytest.mark.parametrize("case", list(CONFIG_CASES))
def test_config_corpus(capsys, tmp_path, samples, case):
    content, names = CONFIG_CASES[case]
    path = tmp_path / f"{case}.toml"
    if content is None:
        path.mkdir()
    else:
        path.write_bytes(content)
    outcome = _check(capsys, tmp_path, "simulate-config", CONFIG_COMMANDS["simulate-config"], path, names,
                     valid=names is None)
    assert outcome == ("ok" if names is None else "error")


# -- sensor profiles (--profile) ------------------------------------------------------------------------------------
_KIND = {"kind": "graphpos-sensor-profile"}
#: A profile a user edited by hand: (content, what the one line must say).
PROFILE_CASES = {
    "not-json": ("{", "not a JSON sensor profile"),
    "no-kind": ({"yaw_rate_scale": 1.1}, "not a graphpos sensor profile"),
    "unknown-field": ({**_KIND, "colour": 1}, "unknown field(s) colour"),
    "implausible": ({**_KIND, "wheel_scale": 0}, "wheel_scale = 0 is outside the plausible range"),
    "text": ({**_KIND, "yaw_rate_scale": "abc"}, "yaw_rate_scale = 'abc' is not a number"),
    "boolean": ({**_KIND, "gyro_bias_radps": True}, "gyro_bias_radps = True is not a number"),
    "negative-noise": ({**_KIND, "heading_noise_radps_per_sqrt_s": -1}, "must be a non-negative number"),
}
PROFILE_COMMANDS = {
    "run": ["run", "{drive}", "-e", "dr", "--profile", "{file}", "--out-dir", "{out}/run"],
    "evaluate": ["evaluate", "{drive}", "-e", "dr", "--profile", "{file}", "-o", "{out}/eval", "--workers", "1",
                 "--no-progress"],
}


@pytest.mark.parametrize("command", list(PROFILE_COMMANDS))
@pytest.mark.parametrize("case", list(PROFILE_CASES))
def test_profile_corpus(capsys, tmp_path, samples, case, command):
    """Every bad profile is one line naming the file and the field (an implausible value was a TypeError's traceback)."""
    content, names = PROFILE_CASES[case]
    path = tmp_path / f"{case}.json"
    path.write_text(content if isinstance(content, str) else json.dumps(content))
    argv = [a.replace("{drive}", str(samples["sim"])) for a in PROFILE_COMMANDS[command]]
    assert _check(capsys, tmp_path, command, argv, path, names, valid=False) == "error"
