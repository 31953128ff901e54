"""graphpos plan-layout (issue 18, item 3): layout families, the bound search, the simulation stage, the command."""

from __future__ import annotations

import math
import subprocess
import sys
import tomllib

import numpy as np
import pytest

from eval.plan_layout import _bisect_by_simulation, plan_layout
from graphpos.errors import ConfigError
from graphpos.plan import BASE_SCENARIO, PATTERN, BoundEvaluation, BoundSearch, Candidate, TunnelSpec, family_grid
from graphpos.sim import simulate
from graphpos.sim.infrastructure import FAMILIES, family_offsets

PAPER_TUNNEL = TunnelSpec(length_m=120.0, width_m=6.0, speed_mps=2.0)


@pytest.mark.parametrize("family, expected", [("pairs", 10), ("staggered", 9), ("one-wall", 5), ("groups", 16)])
def test_family_tag_counts_on_the_papers_tunnel(family, expected):
    # every 30 m over 120 m: 5 positions; groups of 2 pairs 6 m apart every 30 m: song2016's 16 tags
    offsets, side = family_offsets(Candidate(family, 30.0).tags(), 120.0)
    assert offsets.size == expected
    assert offsets.min() >= 0 and offsets.max() <= 120.0
    assert set(np.unique(side)) <= {-1, 1}


def test_staggered_alternates_walls_half_a_spacing_apart():
    offsets, side = family_offsets(Candidate("staggered", 20.0).tags(), 100.0)
    np.testing.assert_allclose(np.diff(offsets), 10.0)
    assert np.all(side[:-1] != side[1:])


def test_simulated_drive_holds_exactly_the_planned_tags_on_the_walls():
    spec = TunnelSpec(length_m=100.0, width_m=8.0, speed_mps=3.0, curve_radius_m=60.0, curve_length_m=40.0, curve_start_m=30.0)
    c = Candidate("staggered", 12.0)
    drive = simulate(BASE_SCENARIO, pattern=PATTERN, seed=0, overrides={**spec.overrides(), "tags": c.tags()})
    assert len(drive.tags) == c.n_tags(spec)
    assert set(drive.tags.layouts) == {"dense", "planned"}
    # each tag is half the width from the true path's centreline: farther than the lane offset from the truth
    heard = np.unique(drive.rfid["tag_id"])
    assert heard.size > 0.5 * len(drive.tags)
    tunnel = [w for w in drive.windows if w.label == "in_tunnel"]
    assert len(tunnel) == 1 and tunnel[0].end_s - tunnel[0].start_s == pytest.approx(100.0 / 3.0, rel=0.05)


def test_family_grids_run_from_most_tags_to_fewest():
    for family in FAMILIES:
        counts = [c.n_tags(PAPER_TUNNEL) for c in family_grid(PAPER_TUNNEL, family)]
        assert len(counts) >= 6 and counts == sorted(counts, reverse=True) and len(set(counts)) == len(counts)


@pytest.mark.parametrize("kwargs", [dict(length_m=-5, width_m=6, speed_mps=2), dict(length_m=100, width_m=1, speed_mps=2),
                                    dict(length_m=100, width_m=6, speed_mps=math.nan),
                                    dict(length_m=100, width_m=6, speed_mps=2, curve_radius_m=50, curve_length_m=80, curve_start_m=40)])
def test_bad_tunnels_are_refused(kwargs):
    with pytest.raises(ConfigError):
        TunnelSpec(**kwargs)


@pytest.mark.parametrize("kwargs, needle", [(dict(sensors="imu,wheel,compass"), "must include rfid"),
                                            (dict(sensors="imu,lidar,rfid"), "lidar"), (dict(reader_range_m=12.0), "reader range"),
                                            (dict(reader_range_m=0.0), "reader range"), (dict(pattern="zigzag"), "zigzag")])
def test_bad_sensor_sets_reader_ranges_and_patterns_are_refused(kwargs, needle):
    with pytest.raises(ConfigError, match=needle):
        TunnelSpec(120.0, 6.0, 2.0, **kwargs)


def test_sensor_set_reader_range_and_pattern_reach_the_drives_and_the_bound():
    """Issue 18 item 3's inputs: the drives carry only the chosen sensors, hear tags only within the reader's
    range, move in the chosen pattern; the bound follows (no compass: a weaker heading, a larger bound)."""
    short = TunnelSpec(120.0, 6.0, 2.0, sensors="imu,wheel,rfid,gnss", reader_range_m=5.0, pattern="accel")
    c = Candidate("pairs", 12.0, 2)
    drive = simulate(BASE_SCENARIO, pattern=short.pattern, seed=0, overrides={**short.overrides(), "tags": c.tags()})
    assert sorted(drive.channels) == ["gnss", "imu", "rfid", "truth", "wheel"]
    assert 4.0 < drive.rfid.true_range_m.max() <= 5.0
    assert drive.params["pattern"] == "accel"
    full = BoundSearch(PAPER_TUNNEL, kind="smoother", metric="rms").evaluate(c).value_m
    no_compass = BoundSearch(TunnelSpec(120.0, 6.0, 2.0, sensors="imu,wheel,rfid,gnss"), kind="smoother", metric="rms").evaluate(c).value_m
    assert no_compass > 1.2 * full


class _FakeSearch(BoundSearch):
    """A bound that grows with the spacing (no drive simulated)."""

    def evaluate(self, candidate):
        if candidate not in self.cache:
            self.cache[candidate] = BoundEvaluation(candidate, candidate.n_tags(self.spec), 0.01 * candidate.spacing_m)
        return self.cache[candidate]


@pytest.mark.parametrize("target_m", [0.02, 0.2, 0.5, 5.0])
def test_frontier_bisection_finds_the_fewest_tags_that_meet_the_bound(target_m):
    search = _FakeSearch(PAPER_TUNNEL)
    for family in FAMILIES:
        grid = family_grid(PAPER_TUNNEL, family)
        meeting = [c for c in grid if 0.01 * c.spacing_m <= target_m]
        found = search.frontier(family, target_m)
        assert (found.candidate if found else None) == (meeting[-1] if meeting else None)
        assert len([k for k in search.cache if k.family == family]) <= 2 + math.ceil(math.log2(len(grid)))


def test_simulation_bisection_finds_the_cheapest_that_meets():
    ordered = [Candidate("pairs", float(s)) for s in range(60, 2, -3)]  # cheapest first
    errors = {c: 0.02 * c.spacing_m for c in ordered}
    asked = []

    def meets(c, target_m=0.5):
        asked.append(c)
        return errors[c] <= target_m

    chosen = _bisect_by_simulation(ordered, meets)
    assert chosen == [c for c in ordered if errors[c] <= 0.5][0]
    assert len(asked) <= 2 + math.ceil(math.log2(len(ordered)))
    assert _bisect_by_simulation(ordered, lambda c: meets(c, 0.01)) is None


def test_plan_with_a_budget_writes_a_layout_that_simulate_accepts(tmp_path):
    spec = TunnelSpec(length_m=40.0, width_m=6.0, speed_mps=4.0, sensors="imu,wheel,compass,rfid", reader_range_m=7.0)
    out = plan_layout(spec, tmp_path / "plan", budget=6, seeds=1, fresh_seeds=1, workers=1, progress=False)
    assert out.chosen is not None and out.chosen.n_tags(spec) <= 6
    folder = tmp_path / "plan"
    for name in ("report.md", "report.html", "results.json", "plan.png", "layout.toml"):
        assert (folder / name).stat().st_size > 0
    config = tomllib.loads((folder / "layout.toml").read_text())
    drive = simulate(BASE_SCENARIO, pattern=PATTERN, seed=1, overrides=config)
    assert len(drive.tags) == out.chosen.n_tags(spec)
    assert "gnss" not in drive.channels and drive.rfid.true_range_m.max() <= 7.0  # the plan's sensors and reader, in the file
    report = (folder / "report.md").read_text()
    assert "bound" in report and out.chosen.label in report
    import json

    results = json.loads((folder / "results.json").read_text())
    assert results["chosen"]["bound_m"] > 0 and results["chosen"]["simulated_m"] > results["chosen"]["bound_m"] * 0.5
    assert len(results["rivals"]) == 2
    assert results["chosen"]["fresh_upper_90_m"] is None  # one fresh drive gives no confidence limit


@pytest.mark.parametrize("argv, needle", [
    (["--length-m", "120", "--target-m", "0.5", "--budget", "4"], "not allowed with"),
    (["--length-m", "120"], "give a target (--target-m) or a tag budget (--budget)"),
    (["--length-m", "120", "--target-m", "-1"], "target must be a positive"),
    (["--length-m", "0", "--target-m", "1"], "the tunnel length (--length-m) must be positive, got 0.0"),
    (["--length-m", "120", "--target-m", "1", "--speed-kmh", "0"], "the driving speed (--speed-kmh) must be positive, got 0.0"),
    (["--length-m", "120", "--target-m", "1", "--curve-radius-m", "30"], "a curve needs its arc length (--curve-length-m)"),
    (["--length-m", "120", "--target-m", "1", "--curve-radius-m", "30", "--curve-length-m", "40", "--curve-start-m", "100"],
     "the curve (100 m + 40 m, --curve-start-m + --curve-length-m) must lie inside the 120 m tunnel"),
    (["--length-m", "120", "--target-m", "1", "--fresh-seeds", "1"], "--fresh-seeds must be at least 2, got 1"),
    (["--length-m", "120", "--budget", "5", "-e", "no-such"], "no-such"),
    (["--length-m", "120", "--budget", "5", "--sensors", "imu,sonar,rfid"], "sonar"),
    (["--length-m", "120", "--budget", "5", "--reader-range-m", "20"], "reader range"),
    (["--length-m", "120", "--budget", "5", "--pattern", "zigzag"], "zigzag"),
    (["--length-m", "120", "--budget", "5", "--sensors", "rfid,gnss"], "the bound (graph-batch's graph) needs imu or wheel"),
    (["--length-m", "120", "--budget", "5", "--sensors", "imu,rfid", "-e", "fusion-ekf"], "fusion-ekf needs"),
])
def test_cli_refuses_bad_input_in_one_line(tmp_path, capsys, argv, needle):
    # In this process (graphpos.cli.main, as the console script runs it): a fresh interpreter per case paid
    # plan-layout's 3-4 s of imports ten times over. The command as a user runs it, in its own interpreter
    # (where a stray warning or traceback would also reach stderr), is test_cli_refusal_in_a_fresh_interpreter.
    from graphpos.cli import main

    try:
        status = main(["plan-layout", *argv, "-o", str(tmp_path / "o")])
    except SystemExit as exc:  # argparse's refusals exit, as they do from the console script
        status = exc.code
    stderr = capsys.readouterr().err
    assert status == 2, stderr
    assert needle in stderr and len(stderr.strip().splitlines()) == 1 and "Traceback" not in stderr
    assert not (tmp_path / "o").exists()


def test_cli_refusal_in_a_fresh_interpreter(tmp_path):
    """One refusal of each kind (argparse's, the command's own) through ``python -m graphpos``, as a user runs it."""
    for argv, needle in ((["--length-m", "120", "--target-m", "0.5", "--budget", "4"], "not allowed with"),
                         (["--length-m", "120", "--budget", "5", "-e", "no-such"], "no-such")):
        p = subprocess.run([sys.executable, "-m", "graphpos", "plan-layout", *argv, "-o", str(tmp_path / "o")],
                           capture_output=True, text=True, timeout=120)
        assert p.returncode == 2, p.stderr
        assert needle in p.stderr and len(p.stderr.strip().splitlines()) == 1 and "Traceback" not in p.stderr


@pytest.mark.slow
def test_papers_tunnel_half_a_metre_with_at_most_the_papers_16_tags(tmp_path):
    import json

    out = plan_layout(PAPER_TUNNEL, tmp_path / "plan", target_m=0.5, progress=False)
    assert out.met and out.chosen.n_tags(PAPER_TUNNEL) <= 16
    chosen = json.loads((tmp_path / "plan" / "results.json").read_text())["chosen"]
    assert chosen["simulated_m"] <= 0.5 and chosen["fresh_simulated_m"] <= 0.5


@pytest.mark.slow
def test_three_km_tunnel_at_80_kmh_one_and_a_half_metres(tmp_path):
    spec = TunnelSpec(length_m=3000.0, width_m=9.0, speed_mps=80 / 3.6)
    out = plan_layout(spec, tmp_path / "plan", target_m=1.5, progress=False)
    assert out.met
