"""Posterior Cramer-Rao bound on the position error of a drive with truth (issue 18, item 1).

The bound is built from graph-batch's own factor graph, so it holds exactly
the information graph-batch uses: the same keyframes, the same factors
(IMU preintegration, wheel odometry with its non-holonomic constraint,
compass, tag ranges, GNSS fixes, the planar priors, the start prior) from
the same :class:`~graphpos.graph.builder.GraphBuilder`, with

- the noise levels of the drive's sensors (:func:`bound_config`: for a
  simulated drive the simulator's own sigmas from ``drive.params``, else
  graph-batch's defaults), no self-calibration and no robust losses (the
  bound is that of the Gaussian model);
- the graph linearised at the truth (:func:`truth_values`): poses, yaw and
  velocities interpolated from ``drive.truth`` at the keyframe times, the
  IMU biases at the drive's realised turn-on biases (0 when none is
  recorded), landmarks at the surveyed tag positions, range and wheel
  scales at their realised values.

Two bounds per keyframe (the output epochs):

- the smoother bound: the marginal east/north covariance of the
  whole-drive problem (``gtsam.Marginals``), what graph-batch at best
  achieves;
- the filtering bound: the marginal of the newest keyframe given only
  the factors up to it, what a causal estimator (graph-isam2, the filters)
  at best achieves: the factors are fed in keyframe order to an iSAM2
  that never relinearises (everything is linearised at the truth, so its
  recursion is the exact information-filter recursion of the linearised
  problem). Before the estimators' start (the keyframe where graph-batch's
  builder releases its held start-up track, ignition's) no causal
  estimator gives an output and the filtering bound is NaN; the first
  iSAM2 update holds the whole held track.

The bound reads the truth: it scores estimators, it is not one.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Any

import gtsam
import numpy as np

from graphpos.drive import Drive, Window
from graphpos.errors import EstimationError, MissingChannelError
from graphpos.graph.config import GraphConfig
from graphpos.graph.models import KeyframeState
from graphpos.profile import SensorProfile

#: Floor of a noise density or sigma the drive's sensors do not have at all
#: (a zero would make GTSAM's information infinite).
TINY = 1e-6


@dataclass
class Bound:
    """The position bound of one drive at each keyframe (output epoch).

    Attributes
    ----------
    t_s : (N,) keyframe times
    smoother_cov_en_m2, filtering_cov_en_m2 : (N, 2, 2)
        East/north covariance bounds; the filtering bound is NaN before the
        causal estimators' start.
    windows : labelled windows of the drive (for :meth:`rms_sqrt_trace`)
    diagnostics : dict (timings, keyframes, start keyframe, config used)
    """

    t_s: np.ndarray
    smoother_cov_en_m2: np.ndarray
    filtering_cov_en_m2: np.ndarray
    windows: tuple[Window, ...] = ()
    diagnostics: dict[str, Any] = field(default_factory=dict)

    def sqrt_trace(self, kind: str = "smoother") -> np.ndarray:
        """sqrt(trace) of the bound at each epoch (m): the RMS position error bound."""
        cov = self._cov(kind)
        return np.sqrt(cov[:, 0, 0] + cov[:, 1, 1])

    def _cov(self, kind: str) -> np.ndarray:
        if kind == "smoother":
            return self.smoother_cov_en_m2
        if kind == "filtering":
            return self.filtering_cov_en_m2
        raise ValueError(f"kind must be 'smoother' or 'filtering', got {kind!r}")

    def mask(self, window: str | Window | list[Window] | None = None) -> np.ndarray:
        """Epochs inside a window: a label of the drive's windows, Window(s), or None (all)."""
        if window is None:
            return np.ones(len(self.t_s), dtype=bool)
        if isinstance(window, str):
            wins = [w for w in self.windows if w.label == window]
            if not wins:
                raise KeyError(f"no window labelled {window!r} (have: {sorted({w.label for w in self.windows})})")
        elif isinstance(window, Window):
            wins = [window]
        else:
            wins = list(window)
        m = np.zeros(len(self.t_s), dtype=bool)
        for w in wins:
            m |= w.contains(self.t_s)
        return m

    def rms_sqrt_trace(self, window: str | Window | list[Window] | None = None, kind: str = "smoother") -> float:
        """RMS over the window's epochs of sqrt(trace) of the bound, i.e. sqrt(mean trace) (m).

        It is the bound on an estimator's position RMS over the same epochs.
        Epochs without a bound (the filtering bound before the start) are left out.
        """
        tr = self._cov(kind)
        tr = tr[:, 0, 0] + tr[:, 1, 1]
        tr = tr[self.mask(window) & np.isfinite(tr)]
        return float(math.sqrt(tr.mean())) if len(tr) else float("nan")

    def at(self, t_s: np.ndarray, kind: str = "smoother") -> np.ndarray:
        """sqrt(trace) of the bound interpolated at other times (an estimator's epochs)."""
        return np.interp(np.asarray(t_s, dtype=float), self.t_s, self.sqrt_trace(kind), left=np.nan, right=np.nan)


def knows_noise_levels(drive: Drive) -> bool:
    """Whether the drive carries its sensors' noise levels (a simulated drive's ``params``), which make the bound a
    lower limit; on other drives :func:`bound_config` keeps graph-batch's defaults, a reference an estimator may beat."""
    p = drive.params or {}
    return all(isinstance(p.get(k), dict) for k in ("imu", "wheel", "compass"))


def bound_config(drive: Drive, base: GraphConfig | None = None) -> GraphConfig:
    """graph-batch's config with the drive's sensor noise levels and neither self-calibration nor robust losses.

    For a simulated drive (``drive.params`` with ``imu``/``wheel``/``compass``
    sections) the sensor sigmas are the simulator's: accelerometer and gyro
    white noise, wheel-speed noise, compass noise, the IMU biases' stationary
    sigmas (priors and, over their time constants, random walks), and no
    wheel scale drift or extra heading noise where the drive has none. Model
    terms that are not sensor noise (the lateral-slip sigma of the
    non-holonomic constraint, the inertial graph's integration noise and
    planar priors) stay graph-batch's. Other drives keep graph-batch's
    defaults (or ``base``).
    """
    c = base or GraphConfig()
    c = dataclasses.replace(c, self_calibrate=False, range_scale="off", wheel_scale="off", robust_loss="none", compass_loss="none",
                            range_sigma_scale=1.0, learn_online=False, output_covariance=False)
    if not knows_noise_levels(drive):
        return c
    p = drive.params
    imu, wheel, compass = p["imu"], p["wheel"], p["compass"]
    values: dict[str, float] = {}
    if "accel_sigma_mps2" in imu:
        values["accel_sigma_mps2"] = max(float(imu["accel_sigma_mps2"]), TINY)
    if "gyro_sigma_dps" in imu:
        values["gyro_sigma_radps"] = max(math.radians(float(imu["gyro_sigma_dps"])), TINY)
    for kind, unit in (("accel", 1.0), ("gyro", math.radians(1.0))):
        sigma = float(imu.get(f"{kind}_bias_sigma_{'mps2' if kind == 'accel' else 'dps'}", 0.0)) * unit
        tau = float(imu.get(f"{kind}_bias_tau_s", 600.0))
        turn_on = float(imu.get(f"{kind}_turn_on_bias_max_{'mps2' if kind == 'accel' else 'dps'}", 0.0)) * unit
        unit_name = "mps2" if kind == "accel" else "radps"
        # stationary Gauss-Markov sigma plus a uniform turn-on bias (its sigma: max / sqrt(3))
        values[f"{kind}_bias_sigma_{unit_name}"] = max(math.hypot(sigma, turn_on / math.sqrt(3.0)), TINY)
        # a Gauss-Markov process's increments: variance 2 sigma^2 / tau per second
        values[f"{kind}_bias_walk_{unit_name}_per_sqrt_s"] = max(sigma * math.sqrt(2.0 / tau), TINY)
    if "sigma_mps" in wheel:
        values["wheel_speed_sigma_mps"] = max(float(wheel["sigma_mps"]), TINY)
    values["wheel_scale_density_per_sqrt_s"] = TINY  # the wheel factors take the realised scale (white noise only)
    if "sigma_deg" in compass:
        values["compass_sigma_rad"] = max(math.radians(float(compass["sigma_deg"])), TINY)
    yaw_scale = float(imu.get("yaw_rate_scale_error_max", 0.0))
    values["turn_scale_density_per_sqrt_s"] = max(yaw_scale / math.sqrt(3.0), TINY) if yaw_scale > 0 else TINY
    values["heading_noise_radps_per_sqrt_s"] = TINY
    values["heading_drift_sigma_radps"] = TINY
    if "rate_hz" in imu:
        values["imu_rate_hz"] = float(imu["rate_hz"])
    if "rate_hz" in wheel:
        values["wheel_rate_hz"] = float(wheel["rate_hz"])
    return dataclasses.replace(c, **values)


def default_bound_range_model(drive: Drive) -> Any:
    """A simulated drive whose radio reports ranges: its white range noise (the simulator's
    ``rfid.range_sigma_m``); otherwise None (graph-batch's default range model)."""
    rfid = (drive.params or {}).get("rfid")
    if isinstance(rfid, dict) and rfid.get("reports_range") and drive.reports_ranges:
        from graphpos.ranging.model import LinearCalibration

        return LinearCalibration(sigma0_m=float(rfid.get("range_sigma_m", 0.15)), sigma_slope=0.0)
    return None


def _realised(drive: Drive) -> dict[str, float]:
    r = (drive.params or {}).get("realised")
    return r if isinstance(r, dict) else {}


def position_bound(drive: Drive, layout: str | None = None, range_model: Any = None, config: GraphConfig | None = None,
                   filtering: bool = True) -> Bound:
    """The smoother and filtering position bounds of a drive with truth (see the module docstring).

    Parameters
    ----------
    drive : Drive with a ``truth`` channel
    layout : str, optional
        Restrict the tag map to a named layout (as the estimators' ``layout``).
    range_model : RangeModel, optional
        Range model (sigma per distance) of the tag ranges; default:
        :func:`default_bound_range_model`, else graph-batch's default.
    config : GraphConfig, optional
        The bound's graph config; default :func:`bound_config` of the drive.
    filtering : bool
        Compute the filtering bound too (else it is NaN).
    """
    from graphpos.graph.estimators import GraphBatch

    if not drive.has("truth") or len(drive.truth) < 2:
        raise MissingChannelError(f"position bound: drive '{drive.name}' has no truth")
    t0 = time.perf_counter()
    config = config or bound_config(drive)
    range_model = range_model if range_model is not None else default_bound_range_model(drive)
    est = GraphBatch(config, layout=layout, range_model=range_model, profile=SensorProfile())
    sensors = est.prepare(drive.without_truth())
    est.start(sensors)
    builder, model = est.builder, est.model
    release_keyframe = None
    for m in sensors.measurements(est.channels_used(sensors), by="t"):
        builder.add(m._replace(arrival_s=m.t_s))
        if release_keyframe is None and builder.anchored:
            release_keyframe = builder.last_keyframe
    builder.flush()
    if release_keyframe is None and builder.anchored:
        release_keyframe = builder.last_keyframe
    if not builder.anchored or builder.last_keyframe < 1:
        raise EstimationError(f"position bound: graph-batch never starts on drive '{drive.name}' (no ignition)")
    realised = _realised(drive)
    builder.range_scale = float(realised.get("range_scale", 1.0))
    builder.wheel_scale = 1.0 + float(realised.get("wheel_scale_error", 0.0))
    n = builder.last_keyframe + 1
    t_k = np.array([builder.keyframe_time(k) for k in range(n)])
    states = truth_states(drive, t_k, realised)
    values = truth_values(model, builder, states)
    builder.reweight_ranges(values)  # range sigmas at the true distances
    graph = builder.graph()
    t_build = time.perf_counter() - t0

    t1 = time.perf_counter()
    try:
        marginals = gtsam.Marginals(graph, values)
        smoother = np.array([model.position_cov(marginals.marginalCovariance(model.pose_key(k)), states[k]) for k in range(n)])
    except RuntimeError as exc:
        raise EstimationError(f"position bound on '{drive.name}': smoother marginals failed: {' '.join(str(exc).split())[:200]}") from None
    t_smoother = time.perf_counter() - t1

    t2 = time.perf_counter()
    filt = np.full((n, 2, 2), np.nan)
    if filtering:
        filt = _filtering_bound(graph, values, model, states, release_keyframe, drive.name)
    t_filtering = time.perf_counter() - t2
    diagnostics = {"keyframes": n, "factors": graph.size(), "start_keyframe": release_keyframe, "parameterisation": model.name,
                   "build_s": t_build, "smoother_s": t_smoother, "filtering_s": t_filtering,
                   "total_s": time.perf_counter() - t0, "config": dataclasses.asdict(config),
                   "noise_levels_known": knows_noise_levels(drive)}
    return Bound(t_k, smoother, filt, tuple(drive.windows), diagnostics)


def truth_states(drive: Drive, t_s: np.ndarray, realised: dict[str, float] | None = None) -> list[KeyframeState]:
    """The true state at each time (linear interpolation of ``drive.truth``, yaw unwrapped),
    with the IMU biases at the drive's realised turn-on biases (0 where none is recorded)."""
    tr = drive.truth
    t = tr.t_s
    yaw = np.unwrap(tr.yaw_rad)
    cols = tr.columns
    e, nn = np.interp(t_s, t, tr.east_m), np.interp(t_s, t, tr.north_m)
    y = np.interp(t_s, t, yaw)
    if "v_east_mps" in cols and "v_north_mps" in cols:
        ve, vn = np.interp(t_s, t, tr.v_east_mps), np.interp(t_s, t, tr.v_north_mps)
    else:
        ve, vn = np.interp(t_s, t, np.gradient(tr.east_m, t)), np.interp(t_s, t, np.gradient(tr.north_m, t))
    r = realised or {}
    bias = np.array([r.get("accel_turn_on_bias_x_mps2", 0.0), r.get("accel_turn_on_bias_y_mps2", 0.0), 0.0,
                     0.0, 0.0, math.radians(r.get("gyro_turn_on_bias_dps", 0.0))], dtype=float)
    return [KeyframeState(float(e[i]), float(nn[i]), float(y[i]), float(ve[i]), float(vn[i]), bias) for i in range(len(t_s))]


def truth_values(model, builder, states: list[KeyframeState]) -> gtsam.Values:
    """Values at the truth for every key of the builder's graph: keyframes, bias nodes, landmarks."""
    values = gtsam.Values()
    for k, s in enumerate(states):
        if k in builder.states:  # keyframes of the graph (all of them with keep_history)
            model.insert_values(values, k, s)
    graph_keys = set(builder.graph().keys())
    for key in graph_keys:
        if values.exists(key):
            continue
        sym = gtsam.Symbol(key)
        if chr(sym.chr()) in "lr":
            e, n = builder.landmark_positions[key]
            values.insert(key, np.array([e, n]) if model.name == "planar" else np.array([e, n, 0.0]))
        elif chr(sym.chr()) == "b":
            values.insert(key, gtsam.imuBias.ConstantBias(states[0].bias[:3], states[0].bias[3:]))
        else:
            raise EstimationError(f"position bound: no truth value for key {sym.string()}")
    return values


def _key_index(key: int) -> int | None:
    """The keyframe a key belongs to (keyframe poses, velocities, bias nodes); None for landmarks."""
    sym = gtsam.Symbol(key)
    return None if chr(sym.chr()) in "lr" else int(sym.index())


def _filtering_bound(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, model, states: list[KeyframeState],
                     start: int, name: str) -> np.ndarray:
    """Marginal of each keyframe from the factors up to it: iSAM2 in keyframe order, never relinearised."""
    n = len(states)
    by_index: dict[int, list] = {}
    landmark_first: dict[int, int] = {}
    pending: list = []
    for i in range(graph.size()):
        f = graph.at(i)
        if f is None:
            continue
        idx = [_key_index(k) for k in f.keys()]
        known = [j for j in idx if j is not None]
        if not known:
            pending.append(f)  # landmark priors: with the landmark's first sighting
            continue
        j = max(known)
        by_index.setdefault(j, []).append(f)
        for key in f.keys():
            if _key_index(key) is None:
                landmark_first[key] = min(landmark_first.get(key, j), j)
    for f in pending:
        j = min((landmark_first.get(key, n - 1) for key in f.keys()), default=n - 1)
        by_index.setdefault(j, []).append(f)
    params = gtsam.ISAM2Params()
    params.setRelinearizeThreshold(1e12)
    params.relinearizeSkip = 1 << 30
    isam = gtsam.ISAM2(params)
    inserted: set[int] = set()
    out = np.full((n, 2, 2), np.nan)
    start = max(int(start), 0)
    j = 0
    while j < n:
        upto = start if j == 0 else j
        factors, new = gtsam.NonlinearFactorGraph(), gtsam.Values()
        for i in range(j, upto + 1):
            for f in by_index.get(i, []):
                factors.add(f)
                for key in f.keys():
                    if key not in inserted:
                        inserted.add(key)
                        new.insert(key, _value(values, key, model))
        try:
            isam.update(factors, new)
            out[upto] = model.position_cov(isam.marginalCovariance(model.pose_key(upto)), states[upto])
        except RuntimeError as exc:
            raise EstimationError(f"position bound on '{name}': filtering bound at keyframe {upto} failed: {' '.join(str(exc).split())[:200]}") from None
        j = upto + 1
    return out


def _value(values: gtsam.Values, key: int, model):
    """One key's value (typed) from the truth Values."""
    c = chr(gtsam.Symbol(key).chr())
    if c == "x":
        return values.atPose2(key) if model.name == "planar" else values.atPose3(key)
    if c == "b":
        return values.atConstantBias(key)
    if c in "lr":
        return values.atPoint2(key) if model.name == "planar" else values.atPoint3(key)
    return values.atVector(key)
