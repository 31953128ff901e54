"""The drive: tag and RSU maps, time-sorted sensor channels, truth and windows.

A :class:`Drive` is what every estimator consumes and what one MCAP file
holds. Channels are columnar numpy arrays (one float64 array per column),
sorted by measurement time ``t_s``. Column names carry their unit; frames are
the project's: east-north metres in a local frame, yaw from east,
counter-clockwise, in radians (see ``../shared/papers/README.md``).

Every channel is validated on construction; a failure raises
:class:`~graphpos.errors.DriveError` naming the channel, the row and the
reason.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Iterator, Mapping, NamedTuple

import numpy as np

from graphpos.errors import DriveError

# ---------------------------------------------------------------------------
# Channel schemas
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class ColumnSpec:
    """One column of a channel.

    Parameters
    ----------
    name : str
        Column name, with its unit as suffix (``_m``, ``_mps``, ``_rad`` ...).
    lo, hi : float
        Plausible bounds (inclusive); a value outside them is rejected.
    required : bool
        A required column must be finite in every row. An optional column
        may hold NaN where the source does not give the quantity (e.g. RSS
        for a UWB radio); it is filled with NaN when not given at all.
    integer : bool
        The column holds integer ids (stored as float64, must be whole).
    """

    name: str
    lo: float
    hi: float
    required: bool = True
    integer: bool = False


_T = ColumnSpec("t_s", -1e10, 1e10)
_ARRIVAL = ColumnSpec("arrival_s", -1e10, 1e10, required=False)
_EAST = ColumnSpec("east_m", -1e7, 1e7)
_NORTH = ColumnSpec("north_m", -1e7, 1e7)

#: Column specs of every channel, in storage order. ``t_s`` is first.
CHANNEL_SPECS: dict[str, tuple[ColumnSpec, ...]] = {
    # Body-frame specific force (x forward, y left) and yaw rate. A source
    # with a gyro but no accelerometers (the Plaza data) leaves them NaN.
    "imu": (
        _T,
        ColumnSpec("accel_x_mps2", -50.0, 50.0, required=False),
        ColumnSpec("accel_y_mps2", -50.0, 50.0, required=False),
        ColumnSpec("yaw_rate_radps", -10.0, 10.0),
    ),
    # Speed along the body x axis from the wheel encoders (negative: reverse).
    "wheel": (_T, ColumnSpec("speed_mps", -30.0, 100.0)),
    # Heading as yaw from east, counter-clockwise (already converted).
    "compass": (_T, ColumnSpec("yaw_rad", -4 * np.pi, 4 * np.pi)),
    # One row per tag reading. rss is 0-255 where the radio reports it,
    # range_m where it reports a range; true_range_m only in simulation;
    # arrival_s is when the reading reached the computer (>= t_s).
    "rfid": (
        _T,
        ColumnSpec("tag_id", 0, 2**53, integer=True),
        ColumnSpec("rss", 0.0, 255.0, required=False),
        ColumnSpec("range_m", 0.0, 1e4, required=False),
        ColumnSpec("true_range_m", 0.0, 1e4, required=False),
        _ARRIVAL,
    ),
    # One row per roadside-unit reading: a position fix (east_m, north_m) or
    # a range to the RSU (range_m), with its 1-sigma.
    "rsu": (
        _T,
        ColumnSpec("rsu_id", 0, 2**53, integer=True),
        dataclasses.replace(_EAST, required=False),
        dataclasses.replace(_NORTH, required=False),
        ColumnSpec("range_m", 0.0, 1e5, required=False),
        ColumnSpec("sigma_m", 1e-6, 1e4),
        _ARRIVAL,
    ),
    "gnss": (_T, _EAST, _NORTH, ColumnSpec("sigma_m", 1e-6, 1e4)),
    # Reference trajectory. Yaw may be unwrapped (continuous). The body
    # accelerations and yaw rate are given by the simulator, NaN elsewhere.
    "truth": (
        _T,
        _EAST,
        _NORTH,
        ColumnSpec("v_east_mps", -100.0, 100.0),
        ColumnSpec("v_north_mps", -100.0, 100.0),
        ColumnSpec("yaw_rad", -1e4, 1e4),
        ColumnSpec("yaw_rate_radps", -10.0, 10.0, required=False),
        ColumnSpec("accel_x_mps2", -50.0, 50.0, required=False),
        ColumnSpec("accel_y_mps2", -50.0, 50.0, required=False),
    ),
}

CHANNEL_NAMES: tuple[str, ...] = tuple(CHANNEL_SPECS)


def truth_from_poses(t_s: np.ndarray, east_m: np.ndarray, north_m: np.ndarray, yaw_rad: np.ndarray) -> "Channel":
    """A ``truth`` channel from recorded poses (an importer's reference).

    Velocities by differentiating the positions (``numpy.gradient``, second
    order, uneven spacing); yaw unwrapped; yaw rate and accelerations NaN.
    """
    t = np.asarray(t_s, dtype=np.float64)
    east, north = np.asarray(east_m, dtype=np.float64), np.asarray(north_m, dtype=np.float64)
    return Channel("truth", {"t_s": t, "east_m": east, "north_m": north, "v_east_mps": np.gradient(east, t),
                             "v_north_mps": np.gradient(north, t), "yaw_rad": np.unwrap(np.asarray(yaw_rad, dtype=np.float64))})

#: Columns computed from the truth (simulation, or an importer with truth):
#: for scoring only, removed by :meth:`Drive.without_truth`.
TRUTH_DERIVED_COLUMNS: dict[str, tuple[str, ...]] = {"rfid": ("true_range_m",)}


class Channel:
    """Columnar, time-sorted samples of one sensor.

    Columns are read as attributes (``drive.imu.yaw_rate_radps``) or by
    name (``channel["t_s"]``). A channel is immutable in spirit: its arrays
    are made read-only.

    Parameters
    ----------
    kind : str
        One of :data:`CHANNEL_NAMES`.
    columns : mapping of str to array-like
        At least the required columns of ``kind``; optional ones default to
        NaN (``arrival_s`` defaults to ``t_s``).
    validate : bool
        Check values (finite, in bounds, time order). Only internal code that
        slices an already valid channel turns this off.
    """

    __slots__ = ("kind", "_columns")

    def __init__(self, kind: str, columns: Mapping[str, Any], validate: bool = True):
        if kind not in CHANNEL_SPECS:
            raise DriveError(kind, None, f"unknown channel (known: {', '.join(CHANNEL_NAMES)})")
        specs = CHANNEL_SPECS[kind]
        known = {s.name for s in specs}
        unknown = set(columns) - known
        if unknown:
            raise DriveError(kind, None, f"unknown column(s) {sorted(unknown)}; expected {sorted(known)}")
        if "t_s" not in columns:
            raise DriveError(kind, None, "missing column 't_s'")
        try:
            t = np.array(columns["t_s"], dtype=np.float64).reshape(-1)
        except (TypeError, ValueError) as exc:
            raise DriveError(kind, None, f"column 't_s' is not numeric ({exc})") from None
        n = t.shape[0]
        cols: dict[str, np.ndarray] = {}
        for spec in specs:
            if spec.name in columns:
                try:
                    arr = np.array(columns[spec.name], dtype=np.float64)
                except (TypeError, ValueError) as exc:
                    raise DriveError(kind, None, f"column '{spec.name}' is not numeric ({exc})") from None
                if arr.ndim != 1 or arr.shape[0] != n:
                    raise DriveError(
                        kind, None, f"column '{spec.name}' has shape {arr.shape}, expected ({n},) like 't_s'"
                    )
            elif spec.required:
                raise DriveError(kind, None, f"missing required column '{spec.name}'")
            elif spec.name == "arrival_s":
                arr = t.copy()
            else:
                arr = np.full(n, np.nan)
            arr.flags.writeable = False
            cols[spec.name] = arr
        self.kind = kind
        self._columns = cols
        if validate:
            self._validate()

    # -- access -------------------------------------------------------------
    def __getattr__(self, name: str) -> np.ndarray:
        if name.startswith("_"):  # pickle probes __setstate__ etc. before _columns exists
            raise AttributeError(name)
        try:
            return self._columns[name]
        except KeyError:
            raise AttributeError(f"channel '{self.kind}' has no column '{name}'") from None

    def __getitem__(self, name: str) -> np.ndarray:
        return self._columns[name]

    def __len__(self) -> int:
        return self._columns["t_s"].shape[0]

    def __repr__(self) -> str:
        return f"Channel({self.kind!r}, {len(self)} rows)"

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Channel) or other.kind != self.kind:
            return NotImplemented
        return all(
            np.array_equal(self._columns[k], other._columns[k], equal_nan=True) for k in self._columns
        )

    @property
    def columns(self) -> dict[str, np.ndarray]:
        """Column name -> array (read-only arrays), in schema order."""
        return dict(self._columns)

    @property
    def specs(self) -> tuple[ColumnSpec, ...]:
        return CHANNEL_SPECS[self.kind]

    def select(self, mask_or_index: np.ndarray) -> "Channel":
        """The rows picked by a boolean mask or an increasing index array."""
        return Channel(self.kind, {k: v[mask_or_index] for k, v in self._columns.items()}, validate=False)

    def between(self, start_s: float, end_s: float) -> "Channel":
        """Rows with ``start_s <= t_s <= end_s``."""
        t = self._columns["t_s"]
        return self.select((t >= start_s) & (t <= end_s))

    def replace(self, **columns: np.ndarray) -> "Channel":
        """A validated copy with some columns replaced."""
        merged = {**self._columns, **columns}
        return Channel(self.kind, merged)

    # -- validation ---------------------------------------------------------
    def _validate(self) -> None:
        for spec in self.specs:
            arr = self._columns[spec.name]
            finite = np.isfinite(arr)
            bad = ~finite if spec.required else np.isinf(arr)
            if bad.any():
                row = int(np.argmax(bad))
                raise DriveError(self.kind, row, f"{spec.name} is {arr[row]} (must be finite)")
            with np.errstate(invalid="ignore"):
                out = finite & ((arr < spec.lo) | (arr > spec.hi))
            if out.any():
                row = int(np.argmax(out))
                raise DriveError(
                    self.kind, row, f"{spec.name} = {arr[row]:.6g} is outside the plausible range [{spec.lo:g}, {spec.hi:g}]"
                )
            if spec.integer:
                frac = finite & (arr != np.round(arr))
                if frac.any():
                    row = int(np.argmax(frac))
                    raise DriveError(self.kind, row, f"{spec.name} = {float(arr[row])!r} is not a whole number")
        t = self._columns["t_s"]
        if t.size > 1:
            back = np.diff(t) < 0
            if back.any():
                row = int(np.argmax(back)) + 1
                raise DriveError(self.kind, row, f"time goes backwards ({float(t[row - 1])!r} -> {float(t[row])!r})")
        if "arrival_s" in self._columns:
            early = self._columns["arrival_s"] < t
            if early.any():
                row = int(np.argmax(early))
                raise DriveError(self.kind, row, "arrival_s is before t_s (a reading cannot arrive before it was taken)")


# ---------------------------------------------------------------------------
# Maps, windows, metadata
# ---------------------------------------------------------------------------


def _as_int_ids(values: Any, what: str) -> np.ndarray:
    arr = np.asarray(values, dtype=np.float64).reshape(-1)
    if not np.all(np.isfinite(arr)) or np.any(arr != np.round(arr)) or np.any(arr < 0):
        raise DriveError(what, None, "ids must be non-negative whole numbers")
    return arr.astype(np.int64)


@dataclass(frozen=True, eq=False)
class TagMap:
    """Tags (or beacons) at surveyed positions.

    Parameters
    ----------
    tag_id : array of int
        Unique ids.
    east_m, north_m : array of float
        Positions in the drive's local frame.
    wall_side : array of int
        +1 left wall, -1 right wall (looking along the road), 0 not on a wall.
    group : array of int
        Group index along the road (song2016 §5.1 groups of four), -1 if none.
    layouts : dict of str to array of int
        Named subsets of tag ids. ``dense`` (all tags) is always present.
    """

    tag_id: np.ndarray
    east_m: np.ndarray
    north_m: np.ndarray
    wall_side: np.ndarray
    group: np.ndarray
    layouts: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        ids = _as_int_ids(self.tag_id, "tags")
        n = ids.size
        object.__setattr__(self, "tag_id", ids)
        for name in ("east_m", "north_m"):
            arr = np.asarray(getattr(self, name), dtype=np.float64).reshape(-1)
            if arr.size != n:
                raise DriveError("tags", None, f"{name} has {arr.size} entries for {n} tags")
            if not np.all(np.isfinite(arr)) or np.any(np.abs(arr) > 1e7):
                row = int(np.argmax(~np.isfinite(arr) | (np.abs(arr) > 1e7)))
                raise DriveError("tags", row, f"{name} is not a plausible coordinate")
            object.__setattr__(self, name, arr)
        for name in ("wall_side", "group"):
            arr = np.asarray(getattr(self, name), dtype=np.int64).reshape(-1)
            if arr.size != n:
                raise DriveError("tags", None, f"{name} has {arr.size} entries for {n} tags")
            object.__setattr__(self, name, arr)
        if np.any(~np.isin(self.wall_side, (-1, 0, 1))):
            raise DriveError("tags", int(np.argmax(~np.isin(self.wall_side, (-1, 0, 1)))), "wall_side must be -1, 0 or +1")
        if np.unique(ids).size != n:
            raise DriveError("tags", None, "tag ids are not unique")
        layouts = {k: np.sort(_as_int_ids(v, f"layout '{k}'")) for k, v in dict(self.layouts).items()}
        layouts.setdefault("dense", np.sort(ids))
        for name, members in layouts.items():
            missing = members[~np.isin(members, ids)]
            if missing.size:
                raise DriveError("tags", None, f"layout '{name}' names unknown tag id {int(missing[0])}")
        object.__setattr__(self, "layouts", layouts)

    @classmethod
    def empty(cls) -> "TagMap":
        z = np.zeros(0)
        return cls(z, z, z, z, z)

    def __len__(self) -> int:
        return int(self.tag_id.size)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, TagMap):
            return NotImplemented
        return (
            all(np.array_equal(getattr(self, k), getattr(other, k)) for k in ("tag_id", "east_m", "north_m", "wall_side", "group"))
            and self.layouts.keys() == other.layouts.keys()
            and all(np.array_equal(self.layouts[k], other.layouts[k]) for k in self.layouts)
        )

    def index_of(self, tag_ids: np.ndarray) -> np.ndarray:
        """Row index in this map of each id (ids must be known)."""
        order = np.argsort(self.tag_id)
        pos = np.searchsorted(self.tag_id, tag_ids, sorter=order)
        return order[np.clip(pos, 0, max(len(self) - 1, 0))]

    def positions(self, tag_ids: np.ndarray) -> np.ndarray:
        """(N, 2) east/north of the given ids."""
        idx = self.index_of(np.asarray(tag_ids, dtype=np.int64))
        return np.column_stack([self.east_m[idx], self.north_m[idx]])

    def layout(self, name: str) -> np.ndarray:
        """Tag ids of a named layout; a clear error for an unknown name."""
        if name not in self.layouts:
            raise DriveError("tags", None, f"no layout '{name}' (this drive has: {', '.join(sorted(self.layouts))})")
        return self.layouts[name]


@dataclass(frozen=True, eq=False)
class RsuMap:
    """Roadside units at surveyed positions (same conventions as :class:`TagMap`)."""

    rsu_id: np.ndarray
    east_m: np.ndarray
    north_m: np.ndarray

    def __post_init__(self) -> None:
        ids = _as_int_ids(self.rsu_id, "rsus")
        object.__setattr__(self, "rsu_id", ids)
        for name in ("east_m", "north_m"):
            arr = np.asarray(getattr(self, name), dtype=np.float64).reshape(-1)
            if arr.size != ids.size or not np.all(np.isfinite(arr)):
                raise DriveError("rsus", None, f"{name} must be finite, one per RSU")
            object.__setattr__(self, name, arr)
        if np.unique(ids).size != ids.size:
            raise DriveError("rsus", None, "RSU ids are not unique")

    @classmethod
    def empty(cls) -> "RsuMap":
        z = np.zeros(0)
        return cls(z, z, z)

    def __len__(self) -> int:
        return int(self.rsu_id.size)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, RsuMap):
            return NotImplemented
        return all(np.array_equal(getattr(self, k), getattr(other, k)) for k in ("rsu_id", "east_m", "north_m"))


@dataclass(frozen=True)
class Window:
    """A labelled time interval of a drive (e.g. ``in_tunnel``, ``zone:open``)."""

    label: str
    start_s: float
    end_s: float

    def __post_init__(self) -> None:
        if not (np.isfinite(self.start_s) and np.isfinite(self.end_s)) or self.end_s < self.start_s:
            raise DriveError("windows", None, f"window '{self.label}' has bad bounds [{self.start_s}, {self.end_s}]")

    def contains(self, t_s: np.ndarray) -> np.ndarray:
        return (t_s >= self.start_s) & (t_s <= self.end_s)


@dataclass(frozen=True)
class GeoOrigin:
    """Geodetic position of the local frame's origin (WGS84), for map views."""

    lat_deg: float = 29.5630
    lon_deg: float = 106.5516
    alt_m: float = 0.0


class Measurement(NamedTuple):
    """One row of one channel, as an online estimator receives it."""

    channel: str
    t_s: float
    arrival_s: float
    values: dict[str, float]


# ---------------------------------------------------------------------------
# The drive
# ---------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Drive:
    """One recorded or simulated drive.

    Parameters
    ----------
    name : str
        Human-readable name (file stem, scenario and seed ...).
    channels : dict of str to Channel
        Present channels only; any may be absent.
    tags : TagMap
    rsus : RsuMap
    windows : tuple of Window
    origin : GeoOrigin
    params : dict
        JSON-serialisable provenance: scenario, seed, pattern, parameters.
    """

    name: str
    channels: dict[str, Channel]
    tags: TagMap = field(default_factory=TagMap.empty)
    rsus: RsuMap = field(default_factory=RsuMap.empty)
    windows: tuple[Window, ...] = ()
    origin: GeoOrigin = field(default_factory=GeoOrigin)
    params: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        chans = dict(self.channels)
        for key, ch in chans.items():
            if not isinstance(ch, Channel) or ch.kind != key:
                raise DriveError(key, None, "channel stored under the wrong name")
        object.__setattr__(self, "channels", {k: chans[k] for k in CHANNEL_NAMES if k in chans})
        object.__setattr__(self, "windows", tuple(self.windows))
        if "rfid" in chans and len(chans["rfid"]):
            known = np.isin(chans["rfid"].tag_id.astype(np.int64), self.tags.tag_id)
            if not known.all():
                row = int(np.argmax(~known))
                raise DriveError("rfid", row, f"tag id {int(chans['rfid'].tag_id[row])} is not in the tag map")
        if "rsu" in chans and len(chans["rsu"]):
            rsu = chans["rsu"]
            known = np.isin(rsu.rsu_id.astype(np.int64), self.rsus.rsu_id)
            if not known.all():
                row = int(np.argmax(~known))
                raise DriveError("rsu", row, f"RSU id {int(rsu.rsu_id[row])} is not in the RSU map")
            fix = np.isfinite(rsu.east_m) & np.isfinite(rsu.north_m)
            neither = ~fix & ~np.isfinite(rsu.range_m)
            if neither.any():
                raise DriveError("rsu", int(np.argmax(neither)), "a reading needs a position fix or a range")

    # -- convenience --------------------------------------------------------
    def has(self, channel: str) -> bool:
        """True when the channel is present with at least one row."""
        return channel in self.channels and len(self.channels[channel]) > 0

    @property
    def reports_ranges(self) -> bool:
        """True when the ``rfid`` channel carries ranges (``range_m``), as a ranging radio reports them."""
        return self.has("rfid") and bool(np.isfinite(self.channels["rfid"].range_m).any())

    @property
    def has_accelerometers(self) -> bool:
        """True when the ``imu`` channel carries accelerometer readings."""
        return self.has("imu") and bool(np.isfinite(self.channels["imu"].accel_x_mps2).all())

    def __getattr__(self, name: str) -> Channel:
        # drive.imu, drive.truth ... for present channels
        if name in CHANNEL_SPECS:
            chans = object.__getattribute__(self, "channels")
            if name in chans:
                return chans[name]
            raise AttributeError(f"drive has no '{name}' channel")
        raise AttributeError(name)

    @property
    def start_s(self) -> float:
        starts = [ch.t_s[0] for ch in self.channels.values() if len(ch)]
        return float(min(starts)) if starts else 0.0

    @property
    def end_s(self) -> float:
        ends = [ch.t_s[-1] for ch in self.channels.values() if len(ch)]
        return float(max(ends)) if ends else 0.0

    @property
    def duration_s(self) -> float:
        return self.end_s - self.start_s

    def window(self, label: str) -> list[Window]:
        """All windows with this label (possibly none)."""
        return [w for w in self.windows if w.label == label]

    def replace(self, **changes: Any) -> "Drive":
        """A copy with some fields replaced (validated again)."""
        return dataclasses.replace(self, **changes)

    def without_truth(self) -> "Drive":
        """The drive as an estimator may see it: no ``truth`` channel and no truth-derived column.

        Truth is for scoring only (issue 13): every command hands estimators
        this view and scores their output against the full drive afterwards.
        Removed: the ``truth`` channel and each column listed in
        :data:`TRUTH_DERIVED_COLUMNS` (set to NaN).
        """
        channels = {}
        for name, ch in self.channels.items():
            if name == "truth":
                continue
            derived = [c for c in TRUTH_DERIVED_COLUMNS.get(name, ()) if np.isfinite(ch[c]).any()]
            channels[name] = ch.replace(**{c: np.full(len(ch), np.nan) for c in derived}) if derived else ch
        return dataclasses.replace(self, channels=channels)

    def with_layout(self, layout: str) -> "Drive":
        """The same drive hearing only the tags of a named layout.

        The tag map keeps every tag (so plots still show them); RFID readings
        of tags outside the layout are dropped.
        """
        ids = self.tags.layout(layout)
        if "rfid" not in self.channels:
            return self
        rfid = self.channels["rfid"]
        keep = np.isin(rfid.tag_id.astype(np.int64), ids)
        return self.replace(
            channels={**self.channels, "rfid": rfid.select(keep)},
            params={**self.params, "layout": layout},
        )

    def measurements(self, channels: tuple[str, ...] | list[str], by: str = "arrival") -> Iterator[Measurement]:
        """Rows of the given channels merged in time order.

        Parameters
        ----------
        channels : sequence of str
            Channels to merge; absent ones are skipped. On equal times the
            order of this sequence decides (put ``imu`` first so a filter
            predicts before it updates).
        by : {"arrival", "t"}
            Merge on arrival time (what a live system sees; filters) or on
            measurement time.
        """
        names = [c for c in channels if self.has(c)]
        if not names:
            return
        keys, codes, rows = [], [], []
        for code, name in enumerate(names):
            ch = self.channels[name]
            key = ch["arrival_s"] if (by == "arrival" and "arrival_s" in ch.columns) else ch.t_s
            keys.append(key)
            codes.append(np.full(len(ch), code, dtype=np.int64))
            rows.append(np.arange(len(ch)))
        key = np.concatenate(keys)
        code = np.concatenate(codes)
        row = np.concatenate(rows)
        order = np.lexsort((row, code, key))
        cols = [
            (name, list(self.channels[name].columns.keys()), np.column_stack(list(self.channels[name].columns.values())).tolist())
            for name in names
        ]
        for i in order.tolist():
            name, col_names, table = cols[code[i]]
            values = dict(zip(col_names, table[row[i]]))
            t = values["t_s"]
            yield Measurement(name, t, values.get("arrival_s", t), values)
