"""``graph-ranges``: a factor graph on ranges alone, smoothed over the whole drive.

The graph counterpart of the RFID-only filters (``rfid-ekf``,
``multilateration``): it reads the same RFID ranges (RSS through the drive's
range model, or reported ``range_m``) and RSU ranges where the drive has
them, nothing else (no IMU, wheel, compass or GNSS), so song2016 Table 2 /
song2014 Table 2 compare a smoother with the filters on the same sensors.

Graph
-----
One keyframe per range epoch (an RFID scan, an RSU ranging; readings taken
within ``RangesConfig.epoch_s`` of an epoch's first reading belong to it,
at that reading's time), from the start on: position ``P(k)`` and velocity ``V(k)`` (Point2, east-north), tied by
GTSAM's white-noise-acceleration prior ``WnoaMotionFactorPoint2`` between
consecutive keyframes (the constant-velocity model of
:func:`filters.models.vehicle.constant_velocity_motion` with the noise of
:func:`filters.models.vehicle.white_acceleration_noise`, acceleration PSD
``RangesConfig.accel_psd_m2ps3``). Each range is a ``RangeFactor2`` to the
tag or RSU, a landmark held by a tight prior, with the robust loss and the
range model's sigma (evaluated at the solved distance for the final
solve, as in the other graphs). Levenberg-Marquardt over the whole drive;
marginal covariances of every position.

Start and mirror images
-----------------------
The start comes from the shared :mod:`graphpos.ignition`, given the ranges
only (``has_wheel=False``: no dead reckoning, free heading): it waits until
one epoch's ranges fix the position with no rival, and drops a rival behind
a wall (:func:`~graphpos.ignition.between_walls`), so ranges to tags on one
wall never start the track on the mirror image. Outputs begin at that
epoch (as the RFID-only filters begin at their first measurement). The
prior at the start has ignition's sigmas inflated as in the other graphs
(``START_PRIOR_INFLATION``: its readings are in the graph too) and the
velocity ignition's unknown-speed sigma.

A smoother solved from a poor linearisation point can still settle on a
mirrored stretch where the tags are on one wall only (sparse layouts). The
initial values therefore come from a causal pass, a constant-velocity EKF
from the start with the same models, which gates ranges that disagree with
its prediction (``gate_sigmas``) and keeps its prediction rather than take
an update behind a wall: continuity carries the vehicle past one-wall
stretches on the right side. After the solve, keyframes behind a wall are
counted in ``diagnostics["behind_wall"]``: none on paper-straight seeds 0-4
(dense, optimized and groups-60m layouts) nor paper-imm seeds 0-2; two on
paper-comprehensive seed 0 (dense), its last seconds, where the road
curves past the last tags and the constant-velocity prior runs straight on.
"""

from __future__ import annotations

import math
from typing import Any

import gtsam
import numpy as np

from filters.core import ekf
from filters.models import measurements as meas
from filters.models.vehicle import constant_velocity_motion, white_acceleration_noise
from graphpos.drive import Channel, Drive, Measurement
from graphpos.errors import ConfigError
from graphpos.estimate import Estimate, OutputRow
from graphpos.estimator import Estimator
from graphpos.graph.builder import START_PRIOR_INFLATION
from graphpos.graph.config import RangesConfig
from graphpos.graph.estimators import marginal_covariances, optimise
from graphpos.graph.models import LANDMARK_SIGMA_M, robust
from graphpos.ignition import NOT_STARTED, Ignition, StartState, between_walls
from graphpos.ranging.drive_models import ranges_by_field, reading_models

#: Measurement-update iterations of the causal pass (as ``rfid-ekf``'s default).
UPDATE_ITERATIONS = 3


def _p(k: int) -> int:
    return gtsam.symbol("p", k)


def _v(k: int) -> int:
    return gtsam.symbol("v", k)


def _landmark(kind: str, i: int) -> int:
    return gtsam.symbol("l" if kind == "tag" else "r", i)


class GraphRanges(Estimator):
    """Ranges-only factor graph (RFID and RSU ranges), constant-velocity prior, batch smoothing.

    See the module docstring. ``run`` is the Estimator loop: ``process``
    collects the range readings, ``finish`` solves.
    """

    name = "graph-ranges"
    summary = "GTSAM smoother on RFID/RSU ranges only (constant-velocity prior), output per range epoch, with velocity"
    required_any = (("rfid", "rsu"),)
    optional_channels = ("rfid", "rsu")
    merge_by = "t"
    config: RangesConfig

    @classmethod
    def default_config(cls) -> RangesConfig:
        return RangesConfig()

    def __init__(self, config: Any = None, layout: str | None = None, range_model: Any = None, initial_pose: Any = None, profile: Any = None):
        super().__init__(config, layout, range_model, initial_pose, profile)
        if not isinstance(self.config, RangesConfig):
            raise ConfigError(f"{self.name} takes a RangesConfig, got {type(self.config).__name__}")

    # -- contract -----------------------------------------------------------------
    def start(self, drive: Drive) -> None:
        self._range_models = reading_models(drive, self.resolved_range_model(drive), self.name) if drive.has("rfid") else {}
        self._tags = {int(i): (float(e), float(n)) for i, e, n in zip(drive.tags.tag_id, drive.tags.east_m, drive.tags.north_m)}
        self._rsus = {int(i): (float(e), float(n)) for i, e, n in zip(drive.rsus.rsu_id, drive.rsus.east_m, drive.rsus.north_m)}
        self._tag_en = np.column_stack([drive.tags.east_m, drive.tags.north_m])
        self._walls = np.asarray(drive.tags.wall_side)
        self._user = self.start_pose(drive)
        self._rfid: list[dict[str, float]] = []
        self._rsu: list[dict[str, float]] = []
        self._drive_name = drive.name

    def process(self, measurement: Measurement) -> list[OutputRow]:
        if measurement.channel == "rfid":
            self._rfid.append(measurement.values)
        elif measurement.channel == "rsu":
            self._rsu.append(measurement.values)
        return []

    def finish(self) -> Estimate:
        readings = self._readings()
        self.diagnostics: dict[str, Any] = {"ranges": int(len(readings["t_s"])), "start": None, "behind_wall": 0,
                                            "causal_gated": 0, "causal_kept_prediction": 0,
                                            "rsu_fixes_ignored": int(sum(math.isfinite(r.get("east_m", math.nan)) and not math.isfinite(r.get("range_m", math.nan))
                                                                         for r in self._rsu))}
        epochs = _epochs(readings["t_s"], self.config.epoch_s)
        start = self._ignite(readings, epochs)
        if start is None:
            self.diagnostics["not_started"] = NOT_STARTED
            return Estimate.from_rows(self.name, [], rate_hz=float("nan"), diagnostics=self.diagnostics)
        first, state = start
        epochs = epochs[first:]
        x0 = np.array([state.east_m, state.north_m, 0.0, 0.0])
        P0 = np.diag([state.position_sigma_m**2] * 2 + [state.speed_sigma_mps**2] * 2)
        values, graph = self._solve(readings, epochs, state, self._causal_pass(readings, epochs, x0, P0))
        rows = self._rows(readings, epochs, values, graph)
        return Estimate.from_rows(self.name, rows, rate_hz=float("nan"), diagnostics=self.diagnostics)

    # -- readings -------------------------------------------------------------------
    def _readings(self) -> dict[str, np.ndarray]:
        """Every usable range in time order: time, landmark position and key, distance, sigma, range-model field (-1: RSU)."""
        t, marks, keys, dist, sigma, field = [], [], [], [], [], []
        if self._rfid and self._range_models:
            cols = {k: np.array([r.get(k, math.nan) for r in self._rfid], dtype=np.float64) for k in self._rfid[0]}
            d, s, f = ranges_by_field(self._range_models, Channel("rfid", cols, validate=False))
            ok = np.isfinite(d) & np.isfinite(s) & (s > 0) & np.isin(cols["tag_id"], list(self._tags))
            for i in np.nonzero(ok)[0]:
                tag = int(cols["tag_id"][i])
                t.append(cols["t_s"][i]), marks.append(self._tags[tag]), keys.append(_landmark("tag", tag))
                dist.append(d[i]), sigma.append(s[i] * self.config.range_sigma_scale), field.append(f[i])
        for r in self._rsu:
            rng, s = r.get("range_m", math.nan), r.get("sigma_m", math.nan)
            if math.isfinite(rng) and math.isfinite(s) and s > 0 and int(r["rsu_id"]) in self._rsus:
                t.append(r["t_s"]), marks.append(self._rsus[int(r["rsu_id"])]), keys.append(_landmark("rsu", int(r["rsu_id"])))
                dist.append(rng), sigma.append(s), field.append(-1)
        order = np.argsort(np.asarray(t, dtype=np.float64), kind="stable")
        return {"t_s": np.asarray(t, dtype=np.float64)[order], "marks": np.asarray(marks, dtype=np.float64).reshape(-1, 2)[order],
                "keys": np.asarray(keys, dtype=np.int64)[order], "distance_m": np.asarray(dist, dtype=np.float64)[order],
                "sigma_m": np.asarray(sigma, dtype=np.float64)[order], "field": np.asarray(field, dtype=np.int64)[order]}

    def _ignite(self, readings: dict[str, np.ndarray], epochs: list[slice]) -> tuple[int, StartState] | None:
        """The first epoch at which the shared ignition, given the ranges alone, starts; and its start state."""
        ignition = Ignition(self._tag_en, self._walls, user=self._user, has_wheel=False)
        for i, sl in enumerate(epochs):
            state = ignition.ranges(readings["t_s"][sl.start], readings["marks"][sl], readings["distance_m"][sl], readings["sigma_m"][sl])
            if state is not None:
                self.diagnostics["start"] = state.describe()
                return i, state
        state = ignition.finish()
        if state is not None and epochs:
            self.diagnostics["start"] = state.describe()
            return len(epochs) - 1, state
        return None

    # -- the causal pass (initial values) ----------------------------------------------
    def _causal_pass(self, readings: dict[str, np.ndarray], epochs: list[slice], x: np.ndarray, P: np.ndarray) -> np.ndarray:
        """A constant-velocity EKF through ``epochs`` from the start state ``x``, ``P``: one row
        ``[p_e, p_n, v_e, v_n]`` per epoch, the smoother's initial values (see the module docstring)."""
        c = self.config
        out = np.zeros((len(epochs), 4))
        t_prev = readings["t_s"][epochs[0].start] if epochs else 0.0
        for i, sl in enumerate(epochs):
            t = readings["t_s"][sl.start]
            x, F = constant_velocity_motion(x, t - t_prev)
            P = F @ P @ F.T + white_acceleration_noise(c.accel_psd_m2ps3, t - t_prev)
            t_prev = t
            marks, z, sigma = readings["marks"][sl], readings["distance_m"][sl], readings["sigma_m"][sl]
            h, H = meas.tag_range(x, marks)
            S = np.einsum("ij,jk,ik->i", H, P, H) + sigma**2
            ok = np.abs(z - h) <= c.gate_sigmas * np.sqrt(S)
            self.diagnostics["causal_gated"] += int((~ok).sum())
            if ok.any():
                upd = ekf.iterated_update(x, P, z[ok], lambda xi, m=marks[ok]: meas.tag_range(xi, m), sigma[ok] ** 2, UPDATE_ITERATIONS)
                if between_walls(upd.x[:2], self._tag_en, self._walls):
                    x, P = upd.x, upd.P
                else:
                    self.diagnostics["causal_kept_prediction"] += 1
            out[i] = x
        return out

    # -- the smoother ------------------------------------------------------------------
    def _solve(self, readings: dict[str, np.ndarray], epochs: list[slice], start: StartState,
               initial: np.ndarray) -> tuple[gtsam.Values, gtsam.NonlinearFactorGraph]:
        """Levenberg-Marquardt over ``epochs`` (keyframes 0..; the start prior at 0) from ``initial`` (a row
        per epoch); then again with the tag ranges' sigmas at the solved distances. The solution and its graph."""
        c = self.config
        times = np.array([readings["t_s"][sl.start] for sl in epochs])
        values = gtsam.Values()
        for k, x in enumerate(initial):
            values.insert(_p(k), gtsam.Point2(x[0], x[1]))
            values.insert(_v(k), gtsam.Point2(x[2], x[3]))
        fixed = gtsam.NonlinearFactorGraph()
        fixed.add(gtsam.PriorFactorPoint2(_p(0), gtsam.Point2(start.east_m, start.north_m),
                                          gtsam.noiseModel.Isotropic.Sigma(2, START_PRIOR_INFLATION * start.position_sigma_m)))
        fixed.add(gtsam.PriorFactorPoint2(_v(0), gtsam.Point2(0.0, 0.0), gtsam.noiseModel.Isotropic.Sigma(2, start.speed_sigma_mps)))
        psd = np.full(2, c.accel_psd_m2ps3)
        for k in range(1, len(epochs)):
            fixed.add(gtsam.WnoaMotionFactorPoint2(gtsam.StateData(_p(k - 1), _v(k - 1), float(times[k - 1])),
                                                   gtsam.StateData(_p(k), _v(k), float(times[k])), psd))
        index = np.concatenate([np.full(sl.stop - sl.start, k) for k, sl in enumerate(epochs)])
        rows = np.concatenate([np.arange(sl.start, sl.stop) for sl in epochs])
        keys, marks = readings["keys"][rows], readings["marks"][rows]
        for key in np.unique(keys):
            e, n = marks[np.argmax(keys == key)]
            fixed.add(gtsam.PriorFactorPoint2(int(key), gtsam.Point2(e, n), gtsam.noiseModel.Isotropic.Sigma(2, LANDMARK_SIGMA_M)))
            values.insert(int(key), gtsam.Point2(e, n))
        what = f"{self.name} on '{self._drive_name}'"
        sigma = readings["sigma_m"][rows]
        values = optimise(_with_ranges(fixed, index, keys, readings["distance_m"][rows], sigma, c), values, c, what)
        # the tag ranges' sigmas at the solved distance (see GraphBuilder._range_sigma_m), then the final solve
        sigma = self._sigma_at(values, index, marks, readings["field"][rows], sigma)
        graph = _with_ranges(fixed, index, keys, readings["distance_m"][rows], sigma, c)
        return optimise(graph, values, c, what), graph

    def _rows(self, readings: dict[str, np.ndarray], epochs: list[slice], values: gtsam.Values, graph: gtsam.NonlinearFactorGraph) -> list[OutputRow]:
        """One output per keyframe, with its marginal covariance; keyframes behind a wall counted."""
        what = f"{self.name} on '{self._drive_name}'"  # marginal_covariances says what failed
        covs = marginal_covariances(graph, values, [_p(k) for k in range(len(epochs))], what) if self.config.output_covariance else None
        out = []
        for k, sl in enumerate(epochs):
            p, v = values.atPoint2(_p(k)), values.atPoint2(_v(k))
            if not between_walls(np.asarray(p), self._tag_en, self._walls):
                self.diagnostics["behind_wall"] += 1
            out.append(OutputRow(float(readings["t_s"][sl.start]), float(p[0]), float(p[1]), float(v[0]), float(v[1]), None,
                                 covs[k] if covs is not None else None))
        self.diagnostics["keyframes"] = len(epochs)
        return out

    def _sigma_at(self, values: gtsam.Values, index: np.ndarray, marks: np.ndarray, field: np.ndarray, sigma: np.ndarray) -> np.ndarray:
        """Tag ranges' sigmas from their range models at the solved distances (RSU ranges keep theirs)."""
        pos = np.array([values.atPoint2(_p(int(k))) for k in index]).reshape(-1, 2)
        distance = np.hypot(*(pos - marks).T)
        out = sigma.copy()
        for i, model in enumerate(self._range_models.values()):
            rows = field == i
            if rows.any():
                s = np.asarray(model.predict_sigma_m(distance[rows]), dtype=np.float64) * self.config.range_sigma_scale
                out[rows] = np.where(np.isfinite(s) & (s > 0), s, sigma[rows])
        return out


def _epochs(t_s: np.ndarray, epoch_s: float) -> list[slice]:
    """Slices of time-sorted readings, one per keyframe: each reading within ``epoch_s`` of its slice's first.

    Readings of one scan may be logged a moment apart (MRCLAM: the
    landmarks of one camera frame 1 ms apart). A keyframe for each would
    join two positions by a constant-velocity factor of a millisecond, whose
    position information (about ``3 / (q dt^3)``: 1e11 per m^2) dwarfs the
    ranges' (about 1) and the landmarks' priors (1e4) so far that GTSAM's
    Cholesky declared the marginals' system indeterminate (MRCLAM robot 3).
    """
    if not len(t_s):
        return []
    cuts = [0]
    for i in range(1, len(t_s)):
        if t_s[i] - t_s[cuts[-1]] > epoch_s:
            cuts.append(i)
    cuts.append(len(t_s))
    return [slice(int(a), int(b)) for a, b in zip(cuts[:-1], cuts[1:])]


def _with_ranges(fixed: gtsam.NonlinearFactorGraph, index: np.ndarray, keys: np.ndarray, distance_m: np.ndarray,
                 sigma_m: np.ndarray, config: RangesConfig) -> gtsam.NonlinearFactorGraph:
    """The fixed factors plus one robust range factor per reading."""
    graph = gtsam.NonlinearFactorGraph(fixed)
    for k, key, d, s in zip(index.tolist(), keys.tolist(), distance_m.tolist(), sigma_m.tolist()):
        graph.add(gtsam.RangeFactor2(_p(k), key, d, robust(s, config)))
    return graph

