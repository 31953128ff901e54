"""Plumbing shared by the papers' filters: dispatch, multi-rate timing, outputs, ranges.

A :class:`FilterEstimator` subclass implements a few handlers
(``_predict_to``, ``_on_imu``, ``_on_wheel``, ``_on_compass``, ``_on_scan``,
``_on_fix`` for ``gnss`` / ``rsu`` rows,
``_output``) and gets, from this base:

* asynchronous multi-rate processing: each measurement is applied at its own
  time ``t_s`` after predicting the filter to it; a reading that arrives late
  (``arrival_s > t_s``) is applied when it arrives, at the filter's current
  time, because a filter cannot go back (the factor graph can);
* RFID scans: the readings of one scan (same ``t_s`` and ``arrival_s``) are
  grouped and applied together, as one observation vector (song2016 eq. 10);
  their distances and 1-sigmas come from the estimator's
  :class:`~graphpos.ranging.RangeModel` (``graphpos.ranging.default_range_model``
  of the drive when none is given), a reading without the field that model
  reads from the drive's default model for the field it carries
  (:func:`graphpos.ranging.reading_models`: a drive may mix readings with a
  range and readings with RSS only);
* non-finite samples: a sample whose value a handler needs is not finite is
  a gap in that sensor, skipped and counted per channel and field in
  ``diagnostics["non_finite"]``; non-finite accelerations (on a drive that
  has accelerometers) are counted and handed on as NaN, which the handlers
  take as a sample without accelerometers;
* the yaw-rate bias seen at standstills (:class:`graphpos.standstill.StandstillGyroBias`,
  shared with the graphs): every yaw rate is corrected by what the
  standstills before it showed. The papers' state vectors have no gyro
  bias; a deliberate deviation from them, because a turn-on bias of a few
  tenths of a degree per second turns their dead reckoning by degrees a
  minute, and the vehicle shows it for free while it stands. A drive with
  no standstill (the simulated paper drives) is filtered as the papers do;
* output epochs on a fixed grid (``output_rate_hz``; the filter is predicted to
  each epoch) or, for RFID-only estimators, one output per scan;
* ``run``: the ``start / process / finish`` loop over a drive, done over
  pre-extracted arrays (the same handlers in the same order as
  ``Estimator.run`` would call them; the tests check both agree).

Start-up: a filter whose model needs a start state (``needs_start``) feeds
every measurement to the shared :class:`graphpos.ignition.Ignition` (a start
pose the user gives, else GNSS/RSU fixes, else ranges with the motion of
the first seconds) and starts when it gives a
:class:`~graphpos.ignition.StartState`; until then it outputs nothing. The
papers start every filter from DGPS before the tunnel (song2016 §6): on the
simulated paper drives that is the short ``gnss`` channel of the approach.
The truth is never read. A start from ranges may find them read long or short
by a common scale (:attr:`graphpos.ignition.StartState.range_scale`, kept only
when significant); the filter divides its ranges (and their 1-sigmas) by that
scale from then on: a range calibration found in the drive, as a sensor
profile would give one, which leaves the papers' state vectors as they are.
Uncorrected, Plaza1's 7 %-long UWB ranges cost fusion-ekf 3.2 m RMS against
0.36 m.

Gaps, as in the factor graphs (:mod:`graphpos.graph.builder`): such a
filter's odometry channels (``imu``, ``wheel``) are held for at most
:data:`graphpos.ignition.MAX_ODOMETRY_GAP_S`. When one of them has been silent for longer,
the filter's track ends (no output is extrapolated into the gap); once
every one is back, the filter starts again from a fresh ignition, as at
the drive's start. Each gap and its restart are listed in
``diagnostics["odometry_gaps"]``.

Lock-out: a filter whose state has drifted beyond its own covariance (an
uncalibrated wheel scale the model's noise does not cover, a wrong start)
gates away the ranges that would correct it, and drifts on for the rest of
the drive (a 10 %-fast wheel at 12 m/s: 78 m RMS; the ``realistic``
long-tunnel drives: 70-185 m; two-level-ekf on the ideal long-tunnel
drives, 22 m/s: 12-23 m). When half of its last :data:`LOCKOUT_RANGES`
ranges failed the gate, a fresh ignition is fed beside the filter, which
runs on (its output does not stop), and the filter starts again from that
ignition's state once it has one (same drives: 3.0 m; 6.6 m mean;
1.6-2.1 m). Each one is listed in
``diagnostics["range_lockouts"]``. Not in the papers (they have no gate).
"""

from __future__ import annotations

import math
import time
from typing import Any, ClassVar

import numpy as np

from graphpos.drive import CHANNEL_NAMES, Channel, Drive, Measurement
from graphpos.estimate import Estimate, OutputRow
from graphpos.estimator import Estimator
from graphpos.ignition import MAX_ODOMETRY_GAP_S, Ignition, IgnitionConfig, StartState
from graphpos.ranging.drive_models import ranges_by_field, reading_models
from graphpos.standstill import StandstillGyroBias


#: Columns handed to :meth:`FilterEstimator._on_fix` for each position-fix channel.
_FIX_CHANNELS = {
    "gnss": ("east_m", "north_m", "sigma_m"),
    "rsu": ("rsu_id", "east_m", "north_m", "range_m", "sigma_m"),
}


#: Columns handed to :meth:`FilterEstimator._pre_start` for each non-RFID channel.
_PRE_START_COLUMNS = {"imu": ("accel_x_mps2", "accel_y_mps2", "yaw_rate_radps"), "wheel": ("speed_mps",), "compass": ("yaw_rad",),
                      **_FIX_CHANNELS}

#: Channels every filter that needs a start reads until it has started, to
#: find its start (ranges, fixes, heading), whether or not its model uses them.
_START_CHANNELS = ("rfid", "rsu", "gnss", "compass")

#: Fields of each channel that must be finite for its handler (else the sample is skipped).
_NEEDED_FIELDS = {"imu": ("yaw_rate_radps",), "wheel": ("speed_mps",), "compass": ("yaw_rad",),
                  "gnss": ("east_m", "north_m", "sigma_m"), "rsu": ("sigma_m",)}
#: Fields whose non-finite samples are counted but handed on (the handlers bridge them).
_BRIDGED_FIELDS = {"imu": ("accel_x_mps2", "accel_y_mps2")}

#: Odometry channels of a filter that needs a start: one silent for longer
#: than :data:`graphpos.ignition.MAX_ODOMETRY_GAP_S` ends its track (module docstring).
_ODOMETRY_CHANNELS = ("imu", "wheel")

#: A filter is locked out when at least half of its last this many usable
#: ranges (whole scans) failed the gate (module docstring). A consistent filter
#: gates a range at 0.1 %, and with 5 % gross outliers half of 20 ranges are
#: gated with odds of 1e-8.
LOCKOUT_RANGES = 20


def _start_values(kind: str, columns: tuple, r: int) -> tuple | None:
    """Row ``r`` of a non-RFID channel's pre-extracted columns (:meth:`FilterEstimator.run`) as ignition takes it."""
    if kind == "imu":
        return columns[1][r], columns[2][r], columns[3][r]
    if kind in ("wheel", "compass"):
        return (columns[1][r],)
    if kind in _FIX_CHANNELS:
        return columns[1][r]
    return None


class FilterEstimator(Estimator):
    """Base of the song2016 filters (see the module docstring).

    Subclasses set ``output_on_scan`` (True: one output per RFID scan instead
    of the ``config.output_rate_hz`` grid) and implement the handlers.
    """

    output_on_scan: ClassVar[bool] = False
    #: The model needs a start state from ignition (False: RFID-only
    #: estimators, which start from their first scan).
    needs_start: ClassVar[bool] = True

    # -- handlers (subclasses) ------------------------------------------------
    def _init_filter(self, drive: Drive, start: StartState | None) -> None:
        """Set up the filter state at ``start.t_s`` (``needs_start``), or at the
        first measurement with ``start`` None or the user's pose (RFID-only)."""

    def _predict_to(self, t_s: float) -> None:
        """Advance the filter to ``t_s`` (never backwards)."""

    def _on_imu(self, t_s: float, accel_x: float, accel_y: float, yaw_rate: float) -> None:
        pass

    def _on_wheel(self, t_s: float, speed_mps: float) -> None:
        pass

    def _on_compass(self, t_s: float, yaw_rad: float) -> None:
        pass

    def _on_fix(self, t_s: float, channel: str, values: tuple[float, ...]) -> None:
        """A ``gnss`` or ``rsu`` row: ``values`` are its columns after ``t_s``
        in :data:`graphpos.drive.CHANNEL_SPECS` order."""

    def _on_scan(self, t_s: float, tags_en_m: np.ndarray, ranges_m: np.ndarray, sigmas_m: np.ndarray) -> None:
        pass

    def _output(self, t_s: float) -> OutputRow | None:
        """The output row at ``t_s`` (the filter has been predicted to it)."""
        raise NotImplementedError

    # -- contract ---------------------------------------------------------------
    def start(self, drive: Drive) -> None:
        self._range_models = self._resolve_range_model(drive)
        self._tag_index = {int(t): i for i, t in enumerate(drive.tags.tag_id)}
        self._tag_en = np.column_stack([drive.tags.east_m, drive.tags.north_m])
        self._rsu_en = {int(i): (float(e), float(n)) for i, e, n in zip(drive.rsus.rsu_id, drive.rsus.east_m, drive.rsus.north_m)}
        self._allowed = set(int(t) for t in drive.tags.layout(self.layout)) if self.layout else None
        self._rows: list[OutputRow] = []
        self._pending: list[dict[str, float]] = []
        self.diagnostics: dict[str, Any] = {"scans": 0, "ranges_used": 0, "ranges_gated": 0, "ranges_unusable": 0, "late_scans": 0,
                                            "non_finite": {}, "odometry_gaps": [], "range_lockouts": []}
        #: (time, ranges used, ranges gated) of the latest scans, at least LOCKOUT_RANGES ranges (:meth:`_watch_gate`).
        self._gate_record: list[tuple[float, int, int]] = []
        #: A locked-out filter's fresh ignition, fed while the filter runs on (None: not locked out).
        self._rejoining: Ignition | None = None
        self._period = 1.0 / float(getattr(self.config, "output_rate_hz", 10.0))
        self._drive = drive
        self._standstill = StandstillGyroBias()
        self._ignition = self._new_ignition(drive, self.start_pose(drive))
        self._started = self._ever_started = False
        self._own = set(super().channels_used(drive))
        #: The odometry channels this filter reads (their clocks are followed, :meth:`_follow_odometry`).
        self._own_odometry = frozenset(c for c in _ODOMETRY_CHANNELS if c in self._own)
        #: Last sample of each odometry channel seen (a filter that needs a start), and when its track was lost.
        self._last_odometry_s = {}
        self._oldest_odometry_s = math.inf
        self._lost_s: float | None = None
        self._bridged = dict(_BRIDGED_FIELDS) if drive.has_accelerometers else {}
        self._t = -math.inf
        #: An RFID-only filter begins at the first measurement it is given (the drive's
        #: first in arrival order; live: the first received), not at a time read off the drive.
        self._begin_at_first = not self.needs_start

    def _new_ignition(self, drive: Drive, user) -> Ignition:
        return Ignition(self._tag_en, drive.tags.wall_side, user=user, has_wheel=drive.has("wheel"), config=self._ignition_config())

    def _ignition_config(self) -> IgnitionConfig:
        """Ignition's settings, with this filter's own compass sigma where its config has one."""
        sigma = getattr(self.config, "compass_sigma_rad", None)
        return IgnitionConfig() if sigma is None else IgnitionConfig(compass_sigma_rad=sigma)

    def _begin(self, t0_s: float, start: StartState | None) -> None:
        """Start the filter at ``t0_s``: output grid from there, state from ``start``."""
        self._t = t0_s
        self._next_out = math.ceil(t0_s / self._period - 1e-9) * self._period
        self._n_out = 0
        self._t_grid0 = self._next_out
        self._started = self._ever_started = True
        self._range_scale = start.range_scale if start is not None else 1.0
        self._gate_record = []
        if start is not None and "start" not in self.diagnostics:
            self.diagnostics["start"] = start.describe()
        elif start is not None:
            self.diagnostics["odometry_gaps"][-1]["restart"] = start.describe()
        self._init_filter(self._drive, start)

    def _follow_odometry(self, kind: str, t_s: float) -> bool:
        """Keep the odometry's clock at a measurement; False when the measurement falls while the track is lost.

        A track (or the search for its start) is lost at the first
        measurement after a seen odometry channel has been silent for more
        than :data:`graphpos.ignition.MAX_ODOMETRY_GAP_S` (a scan in progress is applied
        first); the next measurement at which every one is fresh again
        starts a fresh ignition.
        """
        if not self.needs_start:
            return True
        last = self._last_odometry_s
        # the oldest channel is silent if any is (t_s - t is monotone in t, also in floating point)
        oldest = self._oldest_odometry_s
        if kind in self._own_odometry:
            last[kind] = t_s
            self._oldest_odometry_s = min(last.values())
        if t_s - oldest <= MAX_ODOMETRY_GAP_S and self._lost_s is None:
            return True  # every odometry channel fresh and the track held: the common case, once per sample
        silent_since = oldest if t_s - oldest > MAX_ODOMETRY_GAP_S else None
        if silent_since is not None and self._lost_s is None:
            if self._pending:
                self._flush_scan()
            self._started = False
            self._rejoining = None
            self._lost_s = silent_since
        if self._lost_s is None or self._started:
            return True
        if t_s - self._oldest_odometry_s > MAX_ODOMETRY_GAP_S:
            return False
        self.diagnostics["odometry_gaps"].append({"from_s": self._lost_s, "to_s": t_s, "restart": None})
        self._ignition = self._new_ignition(self._drive, None)
        self._lost_s = None
        return True

    def _ignite(self, state: StartState | None) -> None:
        if state is not None:
            self._begin(state.t_s, state)

    def _pre_start(self, kind: str, t_s: float, values: tuple) -> None:
        """Feed one non-RFID reading to ignition (before the filter has started)."""
        self._ignite(self._feed(self._ignition, kind, t_s, values))

    def _feed(self, ig: Ignition, kind: str, t_s: float, values: tuple) -> StartState | None:
        """Feed one non-RFID reading (the columns of :data:`_PRE_START_COLUMNS`) to an ignition; its start when it has one."""
        if kind == "imu":
            state = ig.yaw_rate(t_s, values[2])
        elif kind == "wheel":
            state = ig.speed(t_s, values[0])
        elif kind == "compass":
            state = ig.compass(t_s, values[0])
        elif kind == "gnss":
            state = ig.fix(t_s, *values)
        elif kind == "rsu":
            rsu_id, e, n, r, sigma = values
            if math.isfinite(e) and math.isfinite(n):
                state = ig.fix(t_s, e, n, sigma)
            else:
                state = ig.ranges(t_s, np.array([self._rsu_en[int(rsu_id)]]), np.array([r]), np.array([sigma]))
        else:
            return None
        return state

    def _resolve_range_model(self, drive: Drive) -> dict:
        """The range model of each RFID reading field for this drive (built once per drive; :func:`graphpos.ranging.reading_models`)."""
        if getattr(self, "_models_for", None) is not drive:
            models = reading_models(drive, self.resolved_range_model(drive), self.name) if drive.has("rfid") else {}
            self._models, self._models_for = models, drive
        return self._models

    def _finite_rows(self, kind: str, columns: dict[str, np.ndarray]) -> np.ndarray:
        """Rows of a channel whose needed fields are finite; non-finite values counted in ``diagnostics["non_finite"]``.

        RFID readings with no finite value in any field the range models
        read are counted too (the scan finds them unusable).
        """
        usable = np.ones(len(columns["t_s"]), dtype=bool)
        checks = [(f"{kind}.{name}", ~np.isfinite(columns[name]), name in _NEEDED_FIELDS.get(kind, ()))
                  for name in (*_NEEDED_FIELDS.get(kind, ()), *self._bridged.get(kind, ()))]
        if kind == "rfid" and self._range_models:
            checks.append(("rfid." + "/".join(self._range_models), ~np.any([np.isfinite(columns[f]) for f in self._range_models], axis=0), False))
        for key, bad, needed in checks:
            if bad.any():
                self.diagnostics["non_finite"][key] = self.diagnostics["non_finite"].get(key, 0) + int(bad.sum())
                if needed:
                    usable &= ~bad
        return usable

    def channels_used(self, drive: Drive) -> tuple[str, ...]:
        """The estimator's own channels and the ones ignition alone reads before the start (see
        :data:`_START_CHANNELS`), in the drive's channel order (``Estimator.channels_used``)."""
        used = set(super().channels_used(drive))
        if self.needs_start:
            used |= {c for c in _START_CHANNELS if drive.has(c)}
        return tuple(c for c in CHANNEL_NAMES if c in used)

    def _begin_at(self, t_s: float) -> None:
        """Begin an RFID-only filter at its first measurement's time (see ``start``)."""
        self._begin_at_first = False
        self._begin(t_s, self._ignition.at(t_s))

    def process(self, measurement: Measurement) -> list[OutputRow]:
        n0 = len(self._rows)
        m = measurement
        if self._begin_at_first:
            self._begin_at(m.t_s)
        usable = bool(self._finite_rows(m.channel, {k: np.array([x]) for k, x in m.values.items()})[0])
        if not usable or not self._follow_odometry(m.channel, m.t_s):
            return self._rows[n0:]  # a gap in the sensor, or in the odometry
        values = m.values
        if m.channel == "wheel":
            self._standstill.speed(m.t_s, values["speed_mps"])
        elif m.channel == "imu":
            values = {**values, "yaw_rate_radps": self._standstill.yaw_rate(m.t_s, values["yaw_rate_radps"])}
        if self._rejoining is not None and m.channel in _PRE_START_COLUMNS:
            if self._pending:
                self._flush_scan()  # the scan before this reading first, as run() applies them
            if self._rejoining is not None:
                self._rejoin(self._feed(self._rejoining, m.channel, m.t_s, tuple(values[c] for c in _PRE_START_COLUMNS[m.channel])))
        if self._started and m.channel not in self._own:
            return []  # read for ignition only
        if self._pending and (m.channel != "rfid" or (m.t_s, m.arrival_s) != self._pending_key):
            self._flush_scan()
        if m.channel == "rfid":
            if not self._pending:
                self._pending_key = (m.t_s, m.arrival_s)
            self._pending.append(m.values)
        elif not self._started:
            if m.channel in _PRE_START_COLUMNS:
                self._pre_start(m.channel, m.t_s, tuple(values[c] for c in _PRE_START_COLUMNS[m.channel]))
        else:
            v = values
            t = self._advance(m.t_s)
            if m.channel == "imu":
                self._on_imu(t, v["accel_x_mps2"], v["accel_y_mps2"], v["yaw_rate_radps"])
            elif m.channel == "wheel":
                self._on_wheel(t, v["speed_mps"])
            elif m.channel == "compass":
                self._on_compass(t, v["yaw_rad"])
            elif m.channel in _FIX_CHANNELS:
                self._on_fix(t, m.channel, tuple(v[c] for c in _FIX_CHANNELS[m.channel]))
        return self._rows[n0:]

    def finish(self) -> Estimate:
        if self._pending:
            self._flush_scan()
        if self._standstill.standstills:
            self.diagnostics["standstill"] = self._standstill.describe()
        if not self._ever_started:
            self.diagnostics["not_started"] = self._ignition.not_started()
            self.diagnostics["ignition_attempts"] = self._ignition.attempts
        return Estimate.from_rows(
            self.name,
            self._rows,
            rate_hz=float("nan") if self.output_on_scan else 1.0 / self._period,
            diagnostics=dict(self.diagnostics),
        )

    # -- timing -----------------------------------------------------------------
    def _advance(self, t_s: float) -> float:
        """Emit grid outputs up to ``t_s``, predict to it; returns the time used."""
        t = t_s if t_s > self._t else self._t
        if not self.output_on_scan:
            while self._next_out <= t:
                te = self._next_out
                self._predict_to(te)
                self._t = te
                row = self._output(te)
                if row is not None:
                    self._rows.append(row)
                self._n_out += 1
                self._next_out = self._t_grid0 + self._n_out * self._period
        if t > self._t:  # a reading at the filter's time (wheel after IMU) needs no prediction
            self._predict_to(t)
            self._t = t
        return t

    # -- RFID scans -------------------------------------------------------------
    def _emit_scan_output(self, row: OutputRow) -> None:
        """Record a per-scan output (RFID-only estimators).

        A late piece of a scan is applied at the filter's current time, which
        may be the epoch of the output just made: the refined output replaces
        that one, so epochs stay strictly increasing.
        """
        if self._rows and self._rows[-1].t_s >= row.t_s:
            self._rows[-1] = row
        else:
            self._rows.append(row)

    def _flush_scan(self) -> None:
        rows, self._pending = self._pending, []
        t_s, arrival_s = self._pending_key
        ids = [int(r["tag_id"]) for r in rows]
        d, sigma, _ = ranges_by_field(self._range_models, Channel("rfid", {k: [r[k] for r in rows] for k in rows[0]}, validate=False))
        self._scan(t_s, arrival_s, ids, d, sigma)

    def _scan(self, t_s: float, arrival_s: float, ids: list[int], d: np.ndarray, sigma: np.ndarray) -> None:
        keep = np.isfinite(d) & np.isfinite(sigma) & (sigma > 0)
        if self._allowed is not None:
            keep &= np.array([i in self._allowed for i in ids], dtype=bool)
        self.diagnostics["ranges_unusable"] += int((~keep).sum())
        if not self._started:
            idx = [self._tag_index[i] for i, k in zip(ids, keep) if k]
            self.diagnostics["ranges_before_start"] = self.diagnostics.get("ranges_before_start", 0) + int(keep.sum())
            self._ignite(self._ignition.ranges(t_s, self._tag_en[idx], d[keep], sigma[keep]))
            return
        if arrival_s > t_s or t_s < self._t:
            self.diagnostics["late_scans"] += 1
        t = self._advance(t_s)
        if not keep.any():
            return
        self.diagnostics["scans"] += 1
        idx = [self._tag_index[i] for i, k in zip(ids, keep) if k]
        k = self._range_scale
        used, gated = self.diagnostics["ranges_used"], self.diagnostics["ranges_gated"]
        self._on_scan(t, self._tag_en[idx], d[keep] / k, sigma[keep] / k)
        if self._rejoining is not None:
            self._rejoin(self._rejoining.ranges(t_s, self._tag_en[idx], d[keep], sigma[keep]))
        elif self.needs_start:
            self._watch_gate(t, self.diagnostics["ranges_used"] - used, self.diagnostics["ranges_gated"] - gated)

    def _rejoin(self, state: StartState | None) -> None:
        """A locked-out filter starts again from its fresh ignition's state (its output never stopped)."""
        if state is None:
            return
        self._rejoining = None
        self._range_scale = state.range_scale
        self._gate_record = []
        self.diagnostics["range_lockouts"][-1]["restart"] = state.describe()
        self._init_filter(self._drive, state)

    def _watch_gate(self, t_s: float, used: int, gated: int) -> None:
        """Lock-out (module docstring): when half of the last :data:`LOCKOUT_RANGES` ranges failed the gate, a fresh
        ignition is fed beside the filter, and the filter starts again from its state (:meth:`_rejoin`)."""
        record = self._gate_record
        record.append((t_s, used, gated))
        while len(record) > 1 and sum(u + g for _, u, g in record[1:]) >= LOCKOUT_RANGES:
            record.pop(0)
        n_used, n_gated = sum(u for _, u, _ in record), sum(g for _, _, g in record)
        if n_used + n_gated < LOCKOUT_RANGES or 2 * n_gated < n_used + n_gated:
            return
        self.diagnostics["range_lockouts"].append({"from_s": record[0][0], "to_s": t_s, "ranges_gated": n_gated, "ranges": n_used + n_gated,
                                                   "restart": None})
        self._rejoining = self._new_ignition(self._drive, None)

    # -- fast offline loop ----------------------------------------------------
    def run(self, drive: Drive) -> Estimate:
        """Same as ``Estimator.run`` (start / process each / finish), over arrays.

        The wall time excludes building the drive's default range model (a
        calibration fit done once per drive, not per estimator run).
        """
        drive = self.prepare(drive)
        self._resolve_range_model(drive)
        t0 = time.perf_counter()
        self.start(drive)
        names = self.channels_used(drive)
        keys, codes, rows = [], [], []
        for code, name in enumerate(names):
            ch = drive.channels[name]
            keys.append(ch["arrival_s"] if "arrival_s" in ch.columns else ch.t_s)
            codes.append(np.full(len(ch), code, dtype=np.int64))
            rows.append(np.arange(len(ch)))
        key, code, row = np.concatenate(keys), np.concatenate(codes), np.concatenate(rows)
        order = np.lexsort((row, code, key))
        code, row = code[order].tolist(), row[order].tolist()
        cols: list[Any] = []
        usable = [self._finite_rows(name, drive.channels[name].columns).tolist() for name in names]
        for name in names:
            ch = drive.channels[name]
            if name == "imu":
                cols.append((ch.t_s.tolist(), ch.accel_x_mps2.tolist(), ch.accel_y_mps2.tolist(), ch.yaw_rate_radps.tolist()))
            elif name == "wheel":
                cols.append((ch.t_s.tolist(), ch.speed_mps.tolist()))
            elif name == "compass":
                cols.append((ch.t_s.tolist(), ch.yaw_rad.tolist()))
            elif name in _FIX_CHANNELS:
                cols.append((ch.t_s.tolist(), list(zip(*(ch[c].tolist() for c in _FIX_CHANNELS[name])))))
            elif name == "rfid":
                # ranges of the whole channel at once, or per scan when only ignition reads them (a few scans)
                d, s, _ = ranges_by_field(self._range_models, ch) if name in self._own else (None, None, None)
                cols.append((ch.t_s.tolist(), ch.arrival_s.tolist(), ch.tag_id.astype(np.int64).tolist(), d, s, ch))
            else:
                cols.append(None)
        n_events = len(code)
        i = 0
        while i < n_events:
            c, r = code[i], row[i]
            kind = names[c]
            if self._begin_at_first:
                self._begin_at(cols[c][0][r])
            if not usable[c][r] or not self._follow_odometry(kind, cols[c][0][r]):
                i += 1
                continue  # a gap in the sensor or in the odometry
            if kind == "wheel":
                self._standstill.speed(cols[c][0][r], cols[c][1][r])
            elif kind == "imu":
                rates = cols[c][3]
                rates[r] = self._standstill.yaw_rate(cols[c][0][r], rates[r])
            if kind != "rfid" and (self._rejoining is not None or not self._started):
                values = _start_values(kind, cols[c], r)
                if values is not None:
                    if not self._started:
                        self._pre_start(kind, cols[c][0][r], values)
                        i += 1
                        continue
                    self._rejoin(self._feed(self._rejoining, kind, cols[c][0][r], values))
                elif not self._started:
                    i += 1
                    continue
            if self._started and kind not in self._own:
                i += 1
                continue  # read for ignition only
            if kind == "imu":
                ts, ax, ay, wz = cols[c]
                t = self._advance(ts[r])
                self._on_imu(t, ax[r], ay[r], wz[r])
            elif kind == "wheel":
                ts, v = cols[c]
                t = self._advance(ts[r])
                self._on_wheel(t, v[r])
            elif kind == "compass":
                ts, y = cols[c]
                t = self._advance(ts[r])
                self._on_compass(t, y[r])
            elif kind in _FIX_CHANNELS:
                ts, vals = cols[c]
                t = self._advance(ts[r])
                self._on_fix(t, kind, vals[r])
            elif kind == "rfid":
                ts, arr, ids, d, s, ch = cols[c]
                j = i + 1
                key_r = (ts[r], arr[r])
                while j < n_events and code[j] == c and (ts[row[j]], arr[row[j]]) == key_r:
                    j += 1
                rr = row[i:j]
                if d is None:
                    d_rr, s_rr, _ = ranges_by_field(self._range_models, ch.select(np.array(rr)))
                else:
                    d_rr, s_rr = d[rr], s[rr]
                self._scan(ts[r], arr[r], [ids[k] for k in rr], d_rr, s_rr)
                i = j
                continue
            i += 1
        est = self.finish()
        return est.with_wall_time(time.perf_counter() - t0)
