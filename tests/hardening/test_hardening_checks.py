"""Issue 14, item 9: awkward drives that read are refused or warned about, by one rule table.

:data:`graphpos.io.checks.DRIVE_RULES` decides: a drive whose every time
stamp is equal, or whose span is years, is refused by ``run`` and
``evaluate`` in one line naming the file and the rule, before any work;
``info`` prints its ``checks`` section and then gives the same line. A
drive with no sensor rows, a long gap, every tag at one point, a channel at
one instant or a window outside the drive is warned about: a line on
stderr once the command is done, and the broken rules in ``run.json`` /
``results.json``; ``info`` lists every rule and its verdict.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_hardening_bad_input import DRIVE_COMMANDS, _check, run_cli
from test_mcap_properties import drives as any_drive

from graphpos.drive import Drive, TagMap, Window
from graphpos.io import write_drive
from graphpos.io.checks import DRIVE_RULES, MAX_DRIVE_SPAN_S, SENSOR_GAP_WARNING_S, drive_checks, require_usable
from graphpos.sim import simulate

#: A numpy warning would be a second line on the user's stderr.
pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")
COMMANDS = ("info", "run", "evaluate")
RUN_DR = ["run", "{file}", "-e", "dr", "--out-dir", "{out}/run"]


@pytest.fixture(scope="module")
def sim() -> Drive:
    return simulate("paper-straight", seed=1, duration_s=12.0)


def retimed(drive: Drive, new_t_s, channels=None) -> Drive:
    """The drive with ``t_s`` (and ``arrival_s``, by the same shift) of the named channels (all by default)
    replaced by ``new_t_s(t_s)``; windows are kept inside the new span."""
    changed = {}
    for name, ch in drive.channels.items():
        if channels is not None and name not in channels:
            changed[name] = ch
            continue
        t_s = np.asarray(new_t_s(ch.t_s), dtype=np.float64)
        changed[name] = ch.replace(t_s=t_s, arrival_s=ch.arrival_s - ch.t_s + t_s) if "arrival_s" in ch.columns else ch.replace(t_s=t_s)
    out = drive.replace(channels=changed, windows=())
    return out.replace(windows=(Window("whole", out.start_s, out.end_s),))


def _frozen_at(t_s: float):
    return lambda d: retimed(d, lambda t: np.full(t.size, t_s))


def _one_row(drive: Drive) -> Drive:
    wheel = drive.wheel.select(np.arange(1))
    return Drive(drive.name, {"wheel": wheel}, tags=drive.tags)


#: case -> (drive from the simulated drive, the rule it breaks)
ERRORS = {
    "all-times-zero": (_frozen_at(0.0), "frozen-time"),
    "all-times-equal": (_frozen_at(2.5), "frozen-time"),
    "all-times-unix": (_frozen_at(1.7e9), "frozen-time"),
    "one-row": (_one_row, "frozen-time"),
    "rfid-on-unix-clock": (lambda d: retimed(d, lambda t: t + 1.7e9, channels={"rfid"}), "time-span"),
    "truth-a-year-late": (lambda d: retimed(d, lambda t: t + 3.2e7, channels={"truth"}), "time-span"),
}


def _gap(drive: Drive) -> Drive:
    return retimed(drive, lambda t: np.where(t > 6.0, t + 10 * SENSOR_GAP_WARNING_S, t))


def _tags_at_one_point(drive: Drive) -> Drive:
    tags = drive.tags
    n = len(tags)
    return drive.replace(tags=TagMap(tags.tag_id, np.full(n, 5.0), np.full(n, 3.0), tags.wall_side, tags.group, tags.layouts))


def _wheel_held(drive: Drive) -> Drive:
    """The wheel speed logged as a logger of commanded speeds does: each reading held over five rows."""
    wheel = drive.wheel
    return drive.replace(channels={**drive.channels, "wheel": wheel.replace(speed_mps=np.repeat(wheel.speed_mps[::5], 5)[: len(wheel)])})


WARNINGS = {
    "sensor-gap": (_gap, "sensor-gap"),
    "wheel-held": (_wheel_held, "held-readings"),
    "tags-at-one-point": (_tags_at_one_point, "tag-spread"),
    "compass-at-one-instant": (lambda d: retimed(d, lambda t: np.full(t.size, 3.0), channels={"compass"}), "channel-span"),
    "window-outside": (lambda d: d.replace(windows=(Window("later", 1e5, 1e5 + 1),)), "window-span"),
    "truth-only": (lambda d: d.replace(channels={"truth": d.truth}), "sensor-rows"),
}


def _file(tmp_path, drive: Drive, case: str):
    path = tmp_path / f"{case}.mcap"
    write_drive(path, drive)
    return path


@pytest.mark.parametrize("command", COMMANDS)
@pytest.mark.parametrize("case", list(ERRORS))
def test_nonsense_drive_is_refused_in_one_line(capsys, tmp_path, sim, case, command):
    build, rule = ERRORS[case]
    path = _file(tmp_path, build(sim), case)
    _check(capsys, tmp_path, command, DRIVE_COMMANDS[command], path, f"(drive check '{rule}')", valid=False)


def test_info_shows_the_checks_of_a_refused_drive(capsys, tmp_path, sim):
    path = _file(tmp_path, _frozen_at(2.5)(sim), "frozen")
    status, out, err = run_cli(capsys, ["info", str(path)])
    assert status == 2 and err.count("\n") == 1 and "no time passes" in err
    line = next(line for line in out.splitlines() if line.split()[:1] == ["frozen-time"])
    assert line.split()[1:3] == ["error", "error"] and "rows are at t_s = 2.5 s" in line


@pytest.mark.parametrize("case", list(WARNINGS))
def test_awkward_drive_is_warned_about_in_info(capsys, tmp_path, sim, case):
    build, rule = WARNINGS[case]
    path = _file(tmp_path, build(sim), case)
    status, out, err = run_cli(capsys, ["info", str(path), "--json"])
    assert status == 0, err
    lines = err.strip().splitlines()
    assert lines and all(line.startswith("graphpos info: warning: ") and path.name in line for line in lines)
    assert any(f"(drive check '{rule}')" in line for line in lines)
    broken = {c["name"] for c in json.loads(out)["checks"] if c["verdict"] != "ok"}
    assert rule in broken and all(c["level"] == "warning" for c in json.loads(out)["checks"] if c["name"] in broken)


@pytest.mark.parametrize("case", ["sensor-gap", "tags-at-one-point"])
def test_run_and_evaluate_report_the_warnings(capsys, tmp_path, sim, case):
    build, rule = WARNINGS[case]
    path = _file(tmp_path, build(sim), case)
    status, _, err = run_cli(capsys, [a.format(file=path, out=tmp_path) for a in RUN_DR])
    assert status == 0, err
    assert err.strip().splitlines()[-1].startswith("graphpos run: warning: ") and f"'{rule}'" in err
    assert any(f"'{rule}'" in w for w in json.loads((tmp_path / "run" / "run.json").read_text())["drive_warnings"])
    argv = [a.format(file=path, out=tmp_path) for a in DRIVE_COMMANDS["evaluate"]]
    status, _, err = run_cli(capsys, argv)
    assert status == 0, err
    assert f"graphpos evaluate: warning: {path}" in err and f"'{rule}'" in err
    results = json.loads((tmp_path / "eval" / "results.json").read_text())
    assert rule in {c["name"] for c in results["drives"][0]["checks"]}


def test_a_refusal_stays_one_line_when_the_drive_also_warns(capsys, tmp_path, sim):
    """A truth-only drive warns (no sensor rows), and run refuses it: only the refusal is said."""
    path = _file(tmp_path, WARNINGS["truth-only"][0](sim), "truth-only")
    _check(capsys, tmp_path, "run", RUN_DR, path, "", valid=False, name_file=False)


def test_the_rule_table_is_in_info(capsys, tmp_path, sim):
    path = _file(tmp_path, sim, "good")
    status, out, err = run_cli(capsys, ["info", str(path), "--json"])
    assert status == 0 and err == ""
    checks = json.loads(out)["checks"]
    assert [(c["name"], c["level"], c["rule"]) for c in checks] == [(r.name, r.level, r.rule) for r in DRIVE_RULES]
    assert all(c["verdict"] == "ok" and c["message"] is None for c in checks)
    status, out, _ = run_cli(capsys, ["info", str(path)])
    table = out[out.index("checks (error"):].splitlines()[1: 1 + len(DRIVE_RULES)]
    assert [line.split()[0] for line in table] == [r.name for r in DRIVE_RULES]
    assert {r.level for r in DRIVE_RULES} == {"error", "warning"}


# -- properties ---------------------------------------------------------------------------------------------------
CHECK_SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


@CHECK_SETTINGS
@given(drive=any_drive())
def test_checks_of_any_drive_are_one_result_per_rule(drive):
    checks = drive_checks(drive)
    json.dumps(checks)
    assert [c["name"] for c in checks] == [r.name for r in DRIVE_RULES]
    assert all(c["verdict"] in ("ok", c["level"]) and (c["verdict"] == "ok") == (c["message"] is None) for c in checks)
    errors = [c for c in checks if c["verdict"] == "error"]
    if errors:
        with pytest.raises(Exception, match=errors[0]["name"]):
            require_usable(checks, "d.mcap")
    else:
        assert len(require_usable(checks, "d.mcap")) == sum(c["verdict"] == "warning" for c in checks)


@CHECK_SETTINGS
@given(drive=any_drive(), t_s=st.floats(-1e9, 1e9))
def test_any_drive_with_every_time_equal_is_refused(drive, t_s):
    rows = sum(len(ch) for ch in drive.channels.values())
    frozen = retimed(drive, lambda t: np.full(t.size, t_s))
    verdict = {c["name"]: c["verdict"] for c in drive_checks(frozen)}["frozen-time"]
    assert verdict == ("error" if rows else "ok")


@CHECK_SETTINGS
@given(span_s=st.floats(MAX_DRIVE_SPAN_S * 1.001, 5e9), first_s=st.floats(-1e9, 1e9))
def test_any_span_over_the_limit_is_refused(sim, span_s, first_s):
    drive = retimed(sim, lambda t: first_s + t / t.max() * span_s if t.size and t.max() > 0 else t + first_s)
    verdict = {c["name"]: c["verdict"] for c in drive_checks(drive)}["time-span"]
    assert verdict == "error"


def test_awkward_but_sane_drives_pass(sim):
    """The corpus' valid drives (one second, duplicate stamps, no truth) break no error rule."""
    one_second = simulate("paper-straight", seed=1, duration_s=1.0)
    doubled = dataclasses.replace(sim, channels={k: ch.select(np.repeat(np.arange(len(ch)), 2)) for k, ch in sim.channels.items()})
    no_truth = sim.replace(channels={k: v for k, v in sim.channels.items() if k != "truth"})
    for drive in (sim, one_second, doubled, no_truth):
        assert require_usable(drive_checks(drive), "d.mcap") == []
