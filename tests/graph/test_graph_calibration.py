"""Range-scale self-calibration (no truth used by the estimators) and Plaza1 accuracy."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from graph_drives import SYNTHETIC_MODEL, mrclam_drive, position_errors, synthetic_drive

from graphpos.graph import ESTIMATORS
from graphpos.graph.calibration import calibrate_range_scale, fit_bearing_term
from graphpos.graph.config import GraphConfig
from graphpos.ranging.model import LinearCalibration


def rms(errors: np.ndarray) -> float:
    return float(np.sqrt(np.mean(errors**2)))


def test_scale_recovered_on_a_long_reading_radio():
    drive = synthetic_drive(40, seed=13, turn_radps=0.05, range_scale=1.07)
    config = GraphConfig(parameterisation="planar", **SYNTHETIC_MODEL)
    model = calibrate_range_scale(drive, config)
    assert model.scale == pytest.approx(1.07, abs=0.01)
    assert 0.15 < model.sigma0_m < 0.5  # the simulated 0.3 m
    plain = ESTIMATORS["graph-isam2"](config, range_model=LinearCalibration(sigma0_m=0.3)).run(drive)
    calibrated = ESTIMATORS["graph-isam2"](config, range_model=model).run(drive)
    assert rms(position_errors(drive, calibrated)) < 0.85 * rms(position_errors(drive, plain))


@pytest.mark.parametrize("parameterisation", ["planar", "inertial"])
def test_graph_fixed_lag_scales_its_ranges_by_the_start_s_scale(parameterisation):
    """graph-fixed-lag learns no profile: with no range model or profile given, the ranges' common scale that
    ignition solved with the start (ranges 7 % long here) corrects every range from then on, as in the filters;
    range_scale="off", or a range model given (the test above), leaves them."""
    beacons = [(-30.0, 40.0, 1), (60.0, 40.0, 1), (-30.0, -40.0, -1), (60.0, -40.0, -1)]  # Plaza-like: ranges of 30-70 m
    drive = synthetic_drive(40, seed=13, turn_radps=0.05, range_scale=1.07, beacons=beacons, max_range_m=100.0, speed_mps=2.0)
    runs = {}
    for mode in ("auto", "off"):
        config = GraphConfig(parameterisation=parameterisation, range_scale=mode, **SYNTHETIC_MODEL)
        runs[mode] = ESTIMATORS["graph-fixed-lag"](config).run(drive.without_truth())
    assert runs["auto"].diagnostics["start"]["range_scale"] == pytest.approx(1.07, abs=0.01)
    assert rms(position_errors(drive, runs["auto"])) < 0.75 * rms(position_errors(drive, runs["off"]))


@pytest.mark.parametrize("minimum", [0.93, 1.0, 1.07, 1.2])
def test_profile_minimum_finds_the_vertex_in_few_solves(minimum):
    """The successive-parabola search (issue 19: it replaced a 14-solve Brent search) on a quartic-tailed bowl."""
    from graphpos.graph.calibration import _profile_minimum

    solves = []

    def at(x, warm):
        solves.append(x)
        d = x - minimum
        return 100 * d**2 + 300 * d**4 + 5.0, None

    vertex, curvature, _ = _profile_minimum(at, 1.0, 0.01, (0.8, 1.25), 6, None)
    assert vertex == pytest.approx(minimum, abs=2e-4)
    assert curvature == pytest.approx(200, rel=0.1)
    assert len(solves) <= 3 * 4 + 1
    assert _profile_minimum(lambda x, w: (-((x - 1.0) ** 2), None), 1.0, 0.01, (0.8, 1.25), 6, None) is None  # not convex


def test_range_scale_search_agrees_with_a_fine_bracketing_search():
    from scipy.optimize import minimize_scalar

    from graphpos.graph.calibration import estimate_range_scale
    from graphpos.graph.estimators import optimise

    drive = synthetic_drive(40, seed=13, turn_radps=0.05, range_scale=1.07)
    est = ESTIMATORS["graph-batch"](GraphConfig(parameterisation="planar", self_calibrate=False, range_scale="off", **SYNTHETIC_MODEL),
                                    range_model=LinearCalibration(sigma0_m=0.3))
    est.run(drive.without_truth())
    b, config = est.builder, est.config
    scale, values = estimate_range_scale(b, est.values, config, "test")
    assert b.diagnostics["range_scale_solves"] <= 10
    fine = minimize_scalar(lambda x: b.graph(x).error(optimise(b.graph(x), values, config, "test")), bounds=(1.0, 1.15), method="bounded",
                           options={"xatol": 1e-5})
    assert scale == pytest.approx(fine.x, abs=1e-3)
    assert scale == pytest.approx(1.07, abs=0.01)


def test_wheel_scale_recovered_on_simulated_drives():
    """graph-batch self-calibrates the sim's wheel scale error (1 % 1-sigma) and gains by it.

    The scale is seen only through the tags' along-track information (the
    drives are 152 m long), so one drive's estimate can be off by a percent
    (seed 4: -2.6 % estimated as -1.6 %); over six drives the estimate's RMS
    error must be under half the uncorrected one, and the position better.
    """
    from graphpos.sim import simulate

    scale_err, left_err, rms_cal, rms_plain = [], [], [], []
    for seed in range(6):
        drive = simulate("paper-straight", seed=seed)
        true_scale = 1.0 + drive.params["realised"]["wheel_scale_error"]
        calibrated = ESTIMATORS["graph-batch"](GraphConfig(output_covariance=False), layout="optimized").run(drive.without_truth())
        plain = ESTIMATORS["graph-batch"](GraphConfig(output_covariance=False, wheel_scale="off", self_calibrate=False),
                                          layout="optimized").run(drive.without_truth())
        assert "wheel_scale" not in plain.diagnostics
        scale_err.append(calibrated.diagnostics["wheel_scale"] - true_scale)
        left_err.append(1.0 - true_scale)
        rms_cal.append(rms(position_errors(drive, calibrated)))
        rms_plain.append(rms(position_errors(drive, plain)))
    assert rms(np.array(scale_err)) < 0.5 * rms(np.array(left_err))
    assert np.mean(rms_cal) < np.mean(rms_plain)


def test_wheel_scale_weighs_only_what_the_ranges_see():
    """The wheel scale is the one the ranges support, not an average over keyframes the wheel alone places.

    A realistic drive (wheel reading 5.9 % short) through the tunnel and
    back, turning outside the portals where no tag is in range: there the
    solve follows the wheel whatever its scale. The scale fitted to the
    solved wheel deltas found 0.978 (a third of the error); the solved
    error's minimum is within 0.2 % of the simulated 0.941.
    """
    from graphpos.sim import simulate

    drive = simulate("paper-straight", seed=0, profile="realistic", duration_s=90.0)
    out = ESTIMATORS["graph-batch"](GraphConfig(output_covariance=False)).run(drive.without_truth())
    true_scale = 1.0 + drive.params["realised"]["wheel_scale_error"]
    assert true_scale < 0.95
    assert out.diagnostics["profile"]["wheel_scale"] == pytest.approx(true_scale, abs=0.005)


def _camera_drive(c0_m: float, c2_m_per_rad2: float, duration_s: float = 60.0):
    """A drive whose ranges read off by c0 + c2 b^2, b a bearing within +-0.5 rad (a camera's, as MRCLAM's)."""
    d = synthetic_drive(duration_s, seed=12, turn_radps=0.08)
    bearing = 0.5 * np.sin(0.4 * d.rfid.t_s)  # slowly changing, as a landmark's in a turning camera's image
    rfid = d.rfid.replace(range_m=d.rfid.range_m + c0_m + c2_m_per_rad2 * bearing**2, bearing_rad=bearing)
    return d.replace(channels={k: v for k, v in {**d.channels, "rfid": rfid}.items() if k != "compass"})


def _truth_residuals(drive) -> tuple[np.ndarray, np.ndarray]:
    """Each range reading less its distance from the true track, and its bearing."""
    r, tr = drive.rfid, drive.truth
    marks = drive.tags.positions(r.tag_id)
    dist = np.hypot(np.interp(r.t_s, tr.t_s, tr.east_m) - marks[:, 0], np.interp(r.t_s, tr.t_s, tr.north_m) - marks[:, 1])
    return r.range_m - dist, r.bearing_rad


def test_bearing_range_term_fitted_from_residuals():
    drive, clean = _camera_drive(0.1, -1.5), _camera_drive(0.0, 0.0)
    # residuals about the truth, to test the fit alone; the drive's own range errors give the clean fit
    c0, c2, sigma = fit_bearing_term(*_truth_residuals(drive))
    c0_clean, c2_clean, sigma_clean = fit_bearing_term(*_truth_residuals(clean))
    assert c0 - c0_clean == pytest.approx(0.1, abs=1e-3) and c2 - c2_clean == pytest.approx(-1.5, abs=1e-3)
    assert abs(c2_clean) < 0.5 and sigma == pytest.approx(sigma_clean, rel=0.01)
    residual, bearing = _truth_residuals(drive)
    assert fit_bearing_term(residual, np.full(residual.size, np.nan)) is None  # no bearings: nothing to fit
    assert fit_bearing_term(residual, np.full(residual.size, 0.2)) is None  # one bearing: the term is the offset


def test_graph_batch_calibrates_the_bearing_term_without_truth():
    def batch(drive):
        return ESTIMATORS["graph-batch"](GraphConfig(output_covariance=False)).run(drive.without_truth())

    drive = _camera_drive(0.1, -1.5)
    with_bearing, clean = batch(drive), batch(_camera_drive(0.0, 0.0))
    found = with_bearing.diagnostics["profile"]["range_bearing2_m_per_rad2"] - clean.diagnostics["profile"]["range_bearing2_m_per_rad2"]
    assert found == pytest.approx(-1.5, abs=0.3)
    blind = batch(drive.replace(channels={**drive.channels, "rfid": drive.rfid.replace(bearing_rad=np.full(len(drive.rfid), np.nan))}))
    assert blind.diagnostics["profile"]["range_bearing2_m_per_rad2"] == 0.0
    # here the 0.3 m range noise hides most of the term (0.079 against 0.082 m); the gain is checked on MRCLAM (slow test)
    assert rms(position_errors(drive, with_bearing)) < rms(position_errors(drive, blind))


def test_graph_isam2_learns_the_bearing_term_online():
    """graph-isam2 learns the camera's bearing term from the readings so far and keeps it through later learnings.

    Learnings at 30, 60 and 120 s of a 120-s drive: the term is found at 60 s
    (200 readings with a bearing needed) and corrects the readings to come
    and those recorded, so the learning at 120 s finds little more (the
    total stays, not doubled). Its gain shows on MRCLAM6 (graph-isam2 mean
    0.526 to 0.431 m), not under this drive's 0.3 m range noise.
    """
    def learnt(drive):
        out = ESTIMATORS["graph-isam2"](GraphConfig(output_covariance=False)).run(drive.without_truth())
        return [step["range_bearing2_m_per_rad2"] for step in out.diagnostics["online_calibration"]]

    found, clean = learnt(_camera_drive(0.1, -1.5, 120)), learnt(_camera_drive(0.0, 0.0, 120))
    assert len(found) == 3 and found[0] == 0.0
    assert found[1] - clean[1] == pytest.approx(-1.5, abs=0.3)
    assert found[2] - clean[2] == pytest.approx(-1.5, abs=0.3)
    drive = _camera_drive(0.1, -1.5, 120)
    blind = drive.replace(channels={**drive.channels, "rfid": drive.rfid.replace(bearing_rad=np.full(len(drive.rfid), np.nan))})
    assert learnt(blind) == [0.0, 0.0, 0.0]


@pytest.mark.slow
def test_mrclam_robot3_accuracy_with_the_bearing_term():
    """MRCLAM6 robot 3, truth hidden, default settings: the camera's bearing term is found and used.

    Measured: c2 -1.3 m/rad^2, RMS 0.146 m, ANEES 1.50 (before its held odometry readings were counted once:
    0.153 m, 2.43; 0.242 m without the term; ANEES 7.7 with the range offset taken from the residuals about
    the track rather than searched; RMS 0.130 m, ANEES 3.15 with the heading noise fitted to the residuals
    as if they were the errors, without their redundancy).
    """
    from eval.metrics import evaluate_estimate

    drive = mrclam_drive(3)
    batch = ESTIMATORS["graph-batch"]().run(drive.without_truth())
    assert -2.5 < batch.diagnostics["profile"]["range_bearing2_m_per_rad2"] < -0.5
    whole = evaluate_estimate(drive, batch)["windows"]["whole"]
    assert whole["position"]["rms_m"] <= 0.20
    assert 1.0 <= whole["nees"]["anees"] <= 4.0


@pytest.mark.slow
def test_mrclam_robot1_heading_noise_from_the_redundancy_of_its_turns():
    """MRCLAM6 robot 1, truth hidden: its camera sees landmarks ahead only, the solved track follows the
    odometry, and the turn residuals show a few per cent of the heading error. Weighed by their redundancy,
    they give a heading noise near what the truth shows (about 0.03 rad/sqrt(s) over 10-40 s) and a
    consistent covariance. Measured: heading 0.027 rad/sqrt(s) + turn scale 0.046, RMS 0.246 m, ANEES 1.58
    (0.305 m, 3.68 with its held odometry readings counted once per row; plain fit: 0.0076 + 0.075, RMS
    0.313 m, ANEES 6.12)."""
    from eval.metrics import evaluate_estimate

    drive = mrclam_drive(1)
    batch = ESTIMATORS["graph-batch"]().run(drive.without_truth())
    assert batch.diagnostics["profile"]["heading_noise_radps_per_sqrt_s"] > 0.015
    whole = evaluate_estimate(drive, batch)["windows"]["whole"]
    assert whole["position"]["rms_m"] <= 0.33
    assert 1.0 <= whole["nees"]["anees"] <= 4.0


@pytest.mark.slow
def test_mrclam_robot4_counts_each_held_odometry_reading_once():
    """MRCLAM6 robot 4, truth hidden, default settings: its odometry holds each commanded speed over about nine
    100 Hz rows, and graph-batch counts each reading once (issue 13: ANEES within 1-4). Measured: RMS 0.240 m,
    ANEES 1.91; counted once per row, 0.254 m and ANEES 6.17 (ellipses 1.8 times too small)."""
    from eval.metrics import evaluate_estimate

    drive = mrclam_drive(4)
    est = ESTIMATORS["graph-batch"]()
    batch = est.run(drive.without_truth())
    assert 9.0 < est.config.wheel_rate_hz < 14.0  # the new readings' rate, not the 100 Hz rows'
    whole = evaluate_estimate(drive, batch)["windows"]["whole"]
    assert whole["position"]["rms_m"] <= 0.26
    assert 1.0 <= whole["nees"]["anees"] <= 4.0
    assert "warnings" not in batch.diagnostics  # the whole drive determines its heading noise (dof 5.6)


@pytest.mark.slow
def test_mrclam_robot4_piece_too_short_to_determine_its_heading_noise_says_so():
    """150 s of MRCLAM6 robot 4 from 15 % in, truth hidden: the ranges show almost none of the odometry's heading
    errors (noise fit dof 0.0, the whole drive 5.6), the heading noise fitted is 0.0009 rad/s/sqrt(s) where the truth
    shows about 0.02 over 2-64 s, and the ANEES is 24: graph-batch says the noise is not determined."""
    from graphpos.graph.calibration import MIN_NOISE_FIT_DOF

    drive = mrclam_drive(4)
    start = drive.start_s + 0.15 * drive.duration_s
    piece = drive.replace(channels={k: ch.between(start, start + 150.0) for k, ch in drive.channels.items()})
    batch = ESTIMATORS["graph-batch"]().run(piece.without_truth())
    assert batch.diagnostics["profile"]["source"]["noise_dof"] < MIN_NOISE_FIT_DOF
    assert len(batch.diagnostics["warnings"]) == 1


@pytest.mark.slow
def test_mrclam_profile_of_robot1_serves_robot3_online():
    """A fleet calibrates on one robot and runs online on the next (issue 13): graph-isam2 on robot 3 with
    robot 1's profile within 15 % of its figure with robot 3's own. Measured 0.297 against 0.305 m (0.394
    against 0.274 m with the heading noise fitted without the residuals' redundancy)."""
    from graphpos.profile import SensorProfile

    def profile_of(drive):
        return SensorProfile.from_dict(ESTIMATORS["graph-batch"]().run(drive.without_truth()).diagnostics["profile"])

    r1, r3 = mrclam_drive(1), mrclam_drive(3)
    config = GraphConfig(output_covariance=False)
    own = ESTIMATORS["graph-isam2"](config, profile=profile_of(r3)).run(r3.without_truth())
    other = ESTIMATORS["graph-isam2"](config, profile=profile_of(r1)).run(r3.without_truth())
    assert rms(position_errors(r3, other)) <= 1.15 * rms(position_errors(r3, own))


@pytest.mark.slow
def test_plaza1_accuracy_with_self_calibrated_scale(plaza_path):
    """Plaza1, truth hidden, default settings: graph-batch <= 0.25 m RMS with ANEES in [1, 4] (issue 13).

    graph-batch calibrates the range scale (and the rest of the sensor
    profile) from the drive itself; graph-isam2 learns it online: causal <= 0.40 m
    (issue 13; 0.330 m measured).
    """
    from eval.metrics import evaluate_estimate
    from graphpos.io.plaza import import_plaza

    drive = import_plaza(plaza_path)
    batch = ESTIMATORS["graph-batch"]().run(drive.without_truth())
    assert batch.diagnostics["range_scale"] == pytest.approx(1.069, abs=0.01)
    whole = evaluate_estimate(drive, batch)["windows"]["whole"]
    assert whole["position"]["rms_m"] <= 0.25
    assert 1.0 <= whole["nees"]["anees"] <= 4.0
    causal = ESTIMATORS["graph-isam2"](GraphConfig(output_covariance=False)).run(drive.without_truth())
    assert rms(position_errors(drive, causal)) <= 0.40


@pytest.mark.slow
@pytest.mark.parametrize("scenario", ["paper-straight", "paper-comprehensive"])
def test_accuracy_against_the_best_song2016_filter(scenario):
    """Issue 6 targets on the optimized layout: batch <= 0.6 x best filter, iSAM2 <= best filter.

    Over 12 seeds: one drive's RMS varies by a factor of 3 between seeds
    (a compass disturbance at the curve costs every estimator there), so 5
    seeds decide little: on seeds 0-4 of paper-comprehensive fusion-ekf
    averages 0.47 m, on seeds 0-11 0.64 m.
    """
    from filters import ESTIMATORS as FILTERS
    from graphpos.sim import simulate

    rms_of = {name: [] for name in ("fusion-ekf", "fukf", "graph-isam2", "graph-batch")}
    for seed in range(12):
        drive = simulate(scenario, seed=seed)
        for name in rms_of:
            cls = FILTERS[name] if name in FILTERS else ESTIMATORS[name]
            rms_of[name].append(rms(position_errors(drive, cls(layout="optimized").run(drive))))
    best = min(np.mean(rms_of["fusion-ekf"]), np.mean(rms_of["fukf"]))
    assert np.mean(rms_of["graph-isam2"]) <= best
    assert np.mean(rms_of["graph-batch"]) <= 0.6 * best


def _windowed(rate_error_radps: np.ndarray, dt_s: float, window_s: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """Heading errors summed over consecutive windows, and the windows' lengths."""
    per = int(round(window_s / dt_s))
    n = rate_error_radps.size // per
    return rate_error_radps[: n * per].reshape(n, per).sum(1) * dt_s, np.full(n, window_s)


def test_noise_fit_recovers_a_random_walk_density():
    """White rate noise of density q: the heading error's variance is q^2 T at every horizon, and the fit finds q."""
    from graphpos.graph.calibration import _noise_fit

    rng = np.random.default_rng(3)
    dt, q = 0.1, 0.02
    residual, T = _windowed(rng.normal(0.0, q / np.sqrt(dt), 9000), dt)
    heading_var, turn_var, _ = _noise_fit(residual, T, np.zeros(T.size))
    assert np.sqrt(heading_var) == pytest.approx(q, rel=0.15)
    assert turn_var == 0.0


@pytest.mark.parametrize("share", [0.05, 0.3])
def test_noise_fit_with_redundancy_finds_the_density_a_solve_hid(share):
    """Residuals that show only ``share`` of the heading error (a track that followed the odometry):
    the plain fit finds sqrt(share) of the density, the fit told each span's share finds the density."""
    from graphpos.graph.calibration import _noise_fit

    rng = np.random.default_rng(5)
    dt, q = 0.1, 0.03
    residual, T = _windowed(rng.normal(0.0, np.sqrt(share) * q / np.sqrt(dt), 9000), dt)
    plain, _, _ = _noise_fit(residual, T, np.zeros(T.size))
    told, _, _ = _noise_fit(residual, T, np.zeros(T.size), redundancy=lambda first, last: np.full(first.size, share))
    assert np.sqrt(plain) == pytest.approx(np.sqrt(share) * q, rel=0.15)
    assert np.sqrt(told) == pytest.approx(q, rel=0.15)


def test_noise_fit_degrees_of_freedom_count_what_the_residuals_show():
    """Each window counts its share ``u`` of the error its residual shows; a window at the floor counts nothing.

    4500 windows showing all their error: 95 % of them are kept (the trim),
    so about 4275 degrees of freedom; showing 30 %: 30 % of that; at the
    :data:`MIN_REDUNDANCY` floor (a track that followed the odometry): none,
    under :data:`MIN_NOISE_FIT_DOF`, whatever the residuals.
    """
    from graphpos.graph.calibration import MIN_NOISE_FIT_DOF, MIN_REDUNDANCY, _noise_fit

    rng = np.random.default_rng(6)
    residual, T = _windowed(rng.normal(0.0, 0.02 / np.sqrt(0.1), 9000), 0.1)
    motion = np.zeros(T.size)
    kept = int(np.sum(residual**2 <= np.quantile(residual**2, 0.95)))
    assert _noise_fit(residual, T, motion)[2] == pytest.approx(kept)
    assert _noise_fit(residual, T, motion, redundancy=lambda first, last: np.full(first.size, 0.3))[2] == pytest.approx(0.3 * kept)
    floor = _noise_fit(residual, T, motion, redundancy=lambda first, last: np.full(first.size, MIN_REDUNDANCY))
    assert floor[2] == 0.0 < MIN_NOISE_FIT_DOF


def test_noise_fit_sees_an_error_that_persists():
    """A rate error correlated over 30 s (first-order Gauss-Markov) hardly shows in 2-s windows.

    Its heading error over a horizon grows faster than a random walk's; the
    fit over horizons up to a minute gives a density at least twice the one
    the 2-s windows alone give (what ``fit_profile`` used before).
    """
    from graphpos.graph.calibration import _noise_fit

    rng = np.random.default_rng(4)
    dt, tau, sigma = 0.1, 30.0, 0.01
    phi = np.exp(-dt / tau)
    drive = rng.normal(0.0, sigma * np.sqrt(1 - phi**2), 9000)
    rate = np.zeros(drive.size)
    for i in range(1, rate.size):
        rate[i] = phi * rate[i - 1] + drive[i]
    residual, T = _windowed(rate + rng.normal(0.0, 0.005 / np.sqrt(dt), rate.size), dt)
    multi, _, _ = _noise_fit(residual, T, np.zeros(T.size))
    short = np.mean(residual[residual**2 <= np.quantile(residual**2, 0.95)] ** 2) / 0.73 / 2.0
    assert np.sqrt(multi) > 2.0 * np.sqrt(short)


def test_turn_scale_fit_sees_the_turn_a_solve_followed_the_gyro_through():
    """A solved heading that follows a gyro reading 25 % high through each U-turn and is pulled back after
    (time constant 3 s, as a compass does: 14 degrees off at the turn's end, as graph-batch's first solve
    on a realistic-profile drive): its 2-s windows keep much of the turn the gyro claimed, and a fit to
    them finds a scale under 1.2; the fit over spans up to a minute finds 1.25."""
    from graphpos.graph.calibration import _huber_lstsq, _turn_correction_fit

    dt, scale, bias = 0.1, 1.25, 0.002
    t = np.arange(0.0, 600.0, dt)
    true_rate = np.where((t % 100.0) < 10.0, np.pi / 10.0, 0.0)  # a U-turn every 100 s
    measured_rate = scale * true_rate + bias
    error = np.zeros(t.size)  # the solved heading's error: the gyro's, decaying towards zero
    for i in range(1, t.size):
        error[i] = error[i - 1] * np.exp(-dt / 3.0) + (measured_rate[i] - true_rate[i]) * dt
    solved_heading = np.cumsum(true_rate) * dt + error  # after each step
    per = int(round(2.0 / dt))
    n = t.size // per - 1
    turn_m = measured_rate[1: n * per + 1].reshape(n, per).sum(1) * dt
    turn_s = np.diff(solved_heading[: n * per + 1: per])
    w = {"T": np.full(n, 2.0), "turn_m": turn_m, "turn_s": turn_s}
    (windows_scale, _), _ = _huber_lstsq(np.column_stack([turn_s, w["T"]]), turn_m)
    assert windows_scale < 1.2
    found_scale, found_bias = _turn_correction_fit(w, with_scale=True)
    assert found_scale == pytest.approx(scale, abs=0.02)
    assert found_bias == pytest.approx(bias, abs=0.001)


def _offset_drive(c0_m: float, seed: int):
    """A turning drive whose ranges read ``c0_m`` long and reach only the tags ahead (within +-0.5 rad, a camera's view)."""
    d = synthetic_drive(60, seed=seed, turn_radps=0.08)
    r, tr = d.rfid, d.truth
    marks = d.tags.positions(r.tag_id)
    yaw = np.interp(r.t_s, tr.t_s, np.unwrap(tr.yaw_rad))
    bearing = np.arctan2(marks[:, 1] - np.interp(r.t_s, tr.t_s, tr.north_m), marks[:, 0] - np.interp(r.t_s, tr.t_s, tr.east_m)) - yaw
    ahead = np.abs((bearing + np.pi) % (2 * np.pi) - np.pi) < 0.5
    return d.replace(channels={**d.channels, "rfid": r.replace(range_m=r.range_m + c0_m).select(ahead)})


@pytest.mark.parametrize("seed", [12, 13, 14])
def test_range_offset_found_by_profile_likelihood(seed):
    """A common offset of ranges to the landmarks ahead is found from the solved error (no truth) with an honest sigma.

    Ranges to landmarks ahead alone: an offset reads as a track moved
    forward, which only the turns tell apart. Measured: found offsets
    differ by 0.288-0.295 m for a 0.3 m difference; each within 0.5 sigma
    of its own (sigma 0.23-0.28 m, the 0.3 m range noise on ~60 readings).
    The compass is taken as unbiased here (``compass_bias="off"``), as the
    range scale is taken as 1: with its bias an unknown too, a turned track
    explains part of what the offset does and the offset is found to half
    the precision (seed 12: sigma 0.23 to 0.48 m; seed 13: no longer convex).
    """
    from eval.metrics import evaluate_estimate

    config = GraphConfig(parameterisation="planar", range_offset="estimate", self_calibrate=False, range_scale="off",
                         compass_bias="off", **SYNTHETIC_MODEL)
    found = {}
    for c0 in (0.0, 0.3):
        drive = _offset_drive(c0, seed)
        plain = ESTIMATORS["graph-batch"](dataclasses.replace(config, range_offset="off"), range_model=LinearCalibration(sigma0_m=0.3)).run(drive.without_truth())
        out = ESTIMATORS["graph-batch"](config, range_model=LinearCalibration(sigma0_m=0.3)).run(drive.without_truth())
        offset, sigma = out.diagnostics["range_offset_m"], out.diagnostics["range_offset_sigma_m"]
        assert 0.05 < sigma < 0.6 and abs(offset - c0) < 2.5 * sigma
        found[c0] = offset
        # the offset's uncertainty widens the covariance, never narrows it
        added = np.trace(out.cov_en_m2, axis1=1, axis2=2) - np.trace(plain.cov_en_m2, axis1=1, axis2=2)
        assert np.all(added > -1e-6) and float(np.mean(added)) > 0
        assert evaluate_estimate(drive, out)["windows"]["whole"]["nees"]["anees"] < 2.5
    assert found[0.3] - found[0.0] == pytest.approx(0.3, abs=0.03)


def test_a_given_profile_still_has_its_range_offset_searched():
    """With a sensor profile (one solve, no self-calibration), graph-batch's default ``range_offset="auto"`` searches
    the offset the profile left (another vehicle's camera; MRCLAM6 with robot 1's profile: ANEES 7.6-18.8 to
    3.9-6.3) and widens the covariance by its uncertainty; ``"off"`` leaves the ranges as the profile made them."""
    from graphpos.profile import SensorProfile

    drive = _offset_drive(0.3, 12)
    profile = SensorProfile(wheel_scale=1.0)  # says nothing of the ranges: their 0.3 m is left
    config = GraphConfig(parameterisation="planar", range_scale="off", compass_bias="off", **SYNTHETIC_MODEL)
    assert config.range_offset == "auto"
    out = ESTIMATORS["graph-batch"](config, range_model=LinearCalibration(sigma0_m=0.3), profile=profile).run(drive.without_truth())
    off = ESTIMATORS["graph-batch"](dataclasses.replace(config, range_offset="off"), range_model=LinearCalibration(sigma0_m=0.3),
                                    profile=profile).run(drive.without_truth())
    assert "range_offset_m" not in off.diagnostics
    offset, sigma = out.diagnostics["range_offset_m"], out.diagnostics["range_offset_sigma_m"]
    assert abs(offset - 0.3) < 2.5 * sigma
    added = np.trace(out.cov_en_m2, axis1=1, axis2=2) - np.trace(off.cov_en_m2, axis1=1, axis2=2)
    assert np.all(added > -1e-6) and float(np.mean(added)) > 0
    assert np.sqrt(np.mean(position_errors(drive, out) ** 2)) < np.sqrt(np.mean(position_errors(drive, off) ** 2))


def test_imu_factor_carries_the_turn_noise_of_the_profile():
    """The inertial graph's heading comes from its IMU factors: they take the heading noise and turn-rate scale
    density the planar odometry adds to its turn (``var = (gyro^2 + heading^2 + turn_scale^2 w^2) T``), and
    not from a noise fit that did not determine them (``noise_dof`` under MIN_NOISE_FIT_DOF)."""
    import math

    from graphpos.graph.builder import GraphBuilder
    from graphpos.graph.calibration import MIN_NOISE_FIT_DOF
    from graphpos.graph.models import InertialModel
    from graphpos.sim import simulate

    config = GraphConfig(heading_noise_radps_per_sqrt_s=0.003, turn_scale_density_per_sqrt_s=0.2, imu_rate_hz=100.0, wheel_rate_hz=10.0)
    model = InertialModel(config)
    yaw_rate, dt, n = 0.3, 0.01, 10
    samples = [(np.array([0.0, 0.0, 9.81]), np.array([0.0, 0.0, yaw_rate]), dt, True)] * n
    drive = simulate("paper-straight", seed=0, profile="ideal")
    for noise_dof, determined in ((None, True), (MIN_NOISE_FIT_DOF, True), (0.5 * MIN_NOISE_FIT_DOF, False)):
        builder = GraphBuilder(dataclasses.replace(config, noise_dof=noise_dof), model, drive, {}, config.max_delay_s)
        builder._imu_samples = samples
        extra = builder._imu_turn_noise_var()
        pim = model.preintegrate(samples, None, extra)
        gyro2 = (config.gyro_sigma_radps / math.sqrt(config.imu_rate_hz)) ** 2
        c = config if determined else GraphConfig()
        expected = (gyro2 + c.heading_noise_radps_per_sqrt_s**2 + (c.turn_scale_density_per_sqrt_s * yaw_rate) ** 2) * n * dt
        assert pim.preintMeasCov()[2, 2] == pytest.approx(expected, rel=1e-3)


def test_imu_factor_takes_an_unknown_yaw_rate_scale_until_a_learning_fits_it():
    """graph-isam2 learning online: while the yaw rate's scale is unknown the IMU factors take at least the
    uncalibrated turn-rate scale density; a learning that fitted the density (one that turned
    MIN_TURN_FOR_SCALE_RAD: calibration.fit_profile) ends that and sets it, one that did not leaves it as it was.
    A graph that learns nothing takes it throughout unless given a profile with a fitted scale; graph-batch's
    self-calibration never does."""
    from graphpos.graph.calibration import MIN_TURN_FOR_SCALE_RAD
    from graphpos.profile import SensorProfile
    from graphpos.sim import simulate

    drive = simulate("paper-straight", seed=0, profile="realistic", duration_s=20.0)
    est = ESTIMATORS["graph-isam2"](GraphConfig(output_covariance=False))
    est.start(drive.without_truth())
    b = est.builder
    c = est.config
    yaw_rate = 0.3
    b._imu_samples = [(np.array([0.0, 0.0, 9.81]), np.array([0.0, 0.0, yaw_rate]), 0.01, True)] * 10
    heading2 = c.heading_noise_radps_per_sqrt_s**2
    assert b._imu_turn_noise_var() == pytest.approx(heading2 + (c.uncalibrated_turn_scale_density_per_sqrt_s * yaw_rate) ** 2)
    straight = SensorProfile(turn_scale_density_per_sqrt_s=None, source={"windows": 10, "noise_dof": 10.0, "turned_rad": 0.1})
    b.recalibrate(straight, 1.0, None)
    assert b.unknown_scale_turn_density == c.uncalibrated_turn_scale_density_per_sqrt_s
    assert b._imu_turn_noise_var() == pytest.approx(heading2 + (c.uncalibrated_turn_scale_density_per_sqrt_s * yaw_rate) ** 2)
    turning = SensorProfile(turn_scale_density_per_sqrt_s=0.05, source={"windows": 10, "noise_dof": 10.0, "turned_rad": MIN_TURN_FOR_SCALE_RAD})
    b.recalibrate(turning, 1.0, None)
    assert b.unknown_scale_turn_density is None
    assert b._imu_turn_noise_var() == pytest.approx(heading2 + (0.05 * yaw_rate) ** 2)
    # a given profile with a fitted scale: known from the start; without one, and learning nothing: unknown throughout
    for name, config, profile, unknown in [("graph-isam2", {}, turning, False), ("graph-fixed-lag", {}, turning, False),
                                           ("graph-fixed-lag", {}, None, True), ("graph-fixed-lag", {}, straight, True),
                                           ("graph-isam2", {"learn_online": False}, None, True),
                                           ("graph-batch", {"self_calibrate": False}, None, True)]:
        other = ESTIMATORS[name](GraphConfig(output_covariance=False, **config), profile=profile)
        other.start(drive.without_truth())
        assert (other.builder.unknown_scale_turn_density is not None) == unknown, (name, config, profile)
    # graph-batch's self-calibration: its final solve has the scale it fitted to this drive's turns
    batch = ESTIMATORS["graph-batch"](GraphConfig(output_covariance=False))
    assert "profile" in batch.run(drive.without_truth()).diagnostics
    assert batch.builder.unknown_scale_turn_density is None


def test_wheel_factors_take_an_unknown_wheel_scale_where_nothing_fits_it():
    """A graph given no sensor profile that learns none takes the uncalibrated wheel-scale density; graph-isam2
    learning online (its first learning fits the scale), a given profile and graph-batch's self-calibration keep
    the configured one."""
    from graphpos.profile import SensorProfile
    from graphpos.sim import simulate

    drive = simulate("paper-straight", seed=0, profile="realistic", duration_s=20.0).without_truth()
    c = GraphConfig(output_covariance=False)
    configured, widened = c.wheel_scale_density_per_sqrt_s**2, c.uncalibrated_wheel_scale_density_per_sqrt_s**2
    assert widened > configured
    fitted = SensorProfile(wheel_scale=1.03)
    for name, config, profile, expected in [("graph-fixed-lag", {}, None, widened), ("graph-fixed-lag", {}, fitted, configured),
                                            ("graph-isam2", {}, None, configured), ("graph-isam2", {"learn_online": False}, None, widened),
                                            ("graph-isam2", {"learn_online": False}, fitted, configured),
                                            ("graph-batch", {"self_calibrate": False}, None, widened)]:
        est = ESTIMATORS[name](GraphConfig(output_covariance=False, **config), profile=profile)
        est.start(drive)
        assert est.builder.odometry.scale_var == pytest.approx(expected), (name, config, profile)
    batch = ESTIMATORS["graph-batch"](c)
    assert "profile" in batch.run(drive).diagnostics
    assert batch.builder.odometry.scale_var == pytest.approx(configured)


@pytest.mark.parametrize("name", ["graph-isam2", "graph-fixed-lag"])
def test_online_graph_heading_follows_the_compass_through_a_u_turn_with_the_yaw_rate_off(name):
    """A realistic drive whose yaw rate reads 29 % high turns outside the portal, with no tag in range, before any
    learning has seen a turn. With the IMU factors held to the gyro's white noise, graph-isam2's heading left the
    compass (good to 1 degree) by 58 degrees there and its redescending loss then ignored it (position error up to
    18 m); with the heading noise and turn-rate scale density in them the compass holds the heading. graph-fixed-lag
    learns no scale: at the default turn-rate scale density its heading went 68 degrees off there (21 m)."""
    from graphpos.sim import simulate

    drive = simulate("paper-straight", seed=0, profile="realistic", duration_s=125.0)
    assert drive.params["realised"]["yaw_rate_scale_error"] > 0.25
    out = ESTIMATORS[name](GraphConfig(output_covariance=False)).run(drive.without_truth())
    t, tr = out.t_s, drive.truth
    turn = (t > 78.0) & (t < 120.0)  # the U-turn beyond the east portal and the way back in
    yaw_err = np.angle(np.exp(1j * (out.yaw_rad - np.interp(t, tr.t_s, np.unwrap(tr.yaw_rad)))))
    assert np.degrees(np.abs(yaw_err[turn])).max() < 10.0
    assert position_errors(drive, out)[turn].max() < 2.0


@pytest.mark.slow
def test_graph_isam2_holds_the_heading_in_u_turns_before_it_knows_the_yaw_rate_scale():
    """Realistic seed 11 (yaw rate 21 % high): its first U-turn comes before any learning has turned enough to fit
    the scale. With the IMU factors at the default turn-rate scale density (0.02) the heading followed the gyro 40
    degrees from the compass there and graph-isam2's RMS over 300 s was 2.64 m; at the uncalibrated density 0.28 m."""
    from graphpos.sim import simulate

    drive = simulate("paper-straight", seed=11, profile="realistic", duration_s=300.0)
    assert drive.params["realised"]["yaw_rate_scale_error"] > 0.2
    out = ESTIMATORS["graph-isam2"](GraphConfig(output_covariance=False)).run(drive.without_truth())
    t, tr = out.t_s, drive.truth
    yaw_err = np.angle(np.exp(1j * (out.yaw_rad - np.interp(t, tr.t_s, np.unwrap(tr.yaw_rad)))))
    assert np.degrees(np.abs(yaw_err[(t > 78.0) & (t < 120.0)])).max() < 10.0
    assert rms(position_errors(drive, out)) < 0.6
