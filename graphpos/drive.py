"""The drive: tag and RSU maps, time-sorted sensor channels, truth and windows.

A :class:`Drive` is what every estimator consumes and what one MCAP file
holds. Channels are columnar numpy arrays (one float64 array per column),
sorted by measurement time ``t_s``. Column names carry their unit; frames are
the project's: east-north metres in a local frame, yaw from east,
counter-clockwise, in radians (see ``../shared/papers/README.md``).

Every channel, map and origin is validated on construction against its
column specs (:data:`CHANNEL_SPECS`, :data:`TAG_SPECS`, :data:`RSU_SPECS`,
:data:`ORIGIN_SPECS`; :func:`check_column`): finite where required, within
plausible bounds, whole for ids, never truncated. A failure raises
:class:`~graphpos.errors.DriveError` naming the channel (or map), the row,
the column and the value.
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
    # bearing_rad (counter-clockwise from the body x axis) where the sensor
    # reports one, as a camera does: the sensor profile corrects ranges
    # whose error depends on it; arrival_s is when the reading reached the
    # computer (>= t_s).
    "rfid": (
        _T,
        ColumnSpec("tag_id", 0, 2**53, integer=True),
        ColumnSpec("rss", 0.0, 255.0, required=False),
        ColumnSpec("range_m", 0.0, 1e4, required=False),
        ColumnSpec("true_range_m", 0.0, 1e4, required=False),
        ColumnSpec("bearing_rad", -np.pi, np.pi, required=False),
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

#: Columns of the tag map (:class:`TagMap`), checked as channel columns are.
#: ``wall_side``: +1 left, -1 right, 0 not on a wall; ``group``: -1 for none.
TAG_SPECS: tuple[ColumnSpec, ...] = (
    ColumnSpec("tag_id", 0, 2**53, integer=True),
    _EAST,
    _NORTH,
    ColumnSpec("wall_side", -1, 1, integer=True),
    ColumnSpec("group", -1, 2**53, integer=True),
)
#: Columns of the RSU map (:class:`RsuMap`).
RSU_SPECS: tuple[ColumnSpec, ...] = (ColumnSpec("rsu_id", 0, 2**53, integer=True), _EAST, _NORTH)
#: Fields of the geodetic origin (:class:`GeoOrigin`): WGS84 degrees, and
#: metres from the deepest road tunnel to the highest pass with margin.
ORIGIN_SPECS: tuple[ColumnSpec, ...] = (
    ColumnSpec("lat_deg", -90.0, 90.0),
    ColumnSpec("lon_deg", -180.0, 180.0),
    ColumnSpec("alt_m", -1e4, 1e4),
)


def check_column(what: str, spec: ColumnSpec, values: np.ndarray, rows: bool = True) -> None:
    """Check the values of one column against its spec.

    A required column must be finite, an optional one may hold NaN (never
    an infinity); every finite value must lie within the plausible bounds
    and, for an integer column, be whole.

    Parameters
    ----------
    what : str
        The channel or map (``tags``, ``rsus``, ``origin``) of the column.
    spec : ColumnSpec
    values : array of float
        The column (1-D).
    rows : bool
        Name the row of a bad value (False for a single value).

    Raises
    ------
    DriveError
        Naming ``what``, the row, the column and the value.
    """
    finite = np.isfinite(values)
    bad = ~finite if spec.required else np.isinf(values)
    with np.errstate(invalid="ignore"):
        out = finite & ((values < spec.lo) | (values > spec.hi))
    fraction = finite & (values != np.round(values)) if spec.integer else np.zeros(values.shape, dtype=bool)
    for fault, reason in (
        (bad, lambda v: f"{spec.name} is {v} (must be finite)"),
        (out, lambda v: f"{spec.name} = {v:.6g} is outside the plausible range [{spec.lo:g}, {spec.hi:g}]"),
        (fraction, lambda v: f"{spec.name} = {float(v)!r} is not a whole number"),
    ):
        if fault.any():
            row = int(np.argmax(fault))
            raise DriveError(what, row if rows else None, reason(values[row]))


def _checked_column(what: str, spec: ColumnSpec, values: Any, size: int | None, rows: bool = True) -> np.ndarray:
    """``values`` as a checked 1-D column (:func:`check_column`) of ``size``
    entries (any size if None): int64 for an integer column, else float64."""
    try:
        arr = np.asarray(values, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise DriveError(what, None, f"{spec.name} is not numeric") from None
    if size is not None and arr.size != size:
        raise DriveError(what, None, f"{spec.name} has {arr.size} entries for {size} ids")
    check_column(what, spec, arr, rows)
    return arr.astype(np.int64) if spec.integer else arr


def _check_unique(what: str, name: str, ids: np.ndarray) -> None:
    """DriveError naming the first id listed twice, if any."""
    values, counts = np.unique(ids, return_counts=True)
    if (counts > 1).any():
        first = int(np.argmax(counts > 1))
        raise DriveError(what, None, f"{name}s are not unique: {name} {int(values[first])} is listed {int(counts[first])} times")


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
            check_column(self.kind, spec, self._columns[spec.name])
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
        n = np.size(self.tag_id)
        for spec in TAG_SPECS:
            object.__setattr__(self, spec.name, _checked_column("tags", spec, getattr(self, spec.name), n))
        ids = self.tag_id
        _check_unique("tags", "tag id", ids)
        layouts = {k: np.sort(_checked_column("tags", dataclasses.replace(TAG_SPECS[0], name=f"layout '{k}' tag id"), v, None))
                   for k, v in dict(self.layouts).items()}
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
        n = np.size(self.rsu_id)
        for spec in RSU_SPECS:
            object.__setattr__(self, spec.name, _checked_column("rsus", spec, getattr(self, spec.name), n))
        _check_unique("rsus", "RSU id", self.rsu_id)

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
        if not (_T.lo <= self.start_s <= self.end_s <= _T.hi):
            raise DriveError("windows", None, f"window '{self.label}' has bad bounds [{self.start_s}, {self.end_s}]")

    def contains(self, t_s: np.ndarray) -> np.ndarray:
        return (t_s >= self.start_s) & (t_s <= self.end_s)


@dataclass(frozen=True)
class GeoOrigin:
    """Geodetic position of the local frame's origin (WGS84), for map views."""

    lat_deg: float = 29.5630
    lon_deg: float = 106.5516
    alt_m: float = 0.0

    def __post_init__(self) -> None:
        for spec in ORIGIN_SPECS:
            _checked_column("origin", spec, getattr(self, spec.name), None, rows=False)


class Measurement(NamedTuple):
    """One row of one channel, as an online estimator receives it."""

    channel: str
    t_s: float
    arrival_s: float
    values: dict[str, float]


@dataclass(frozen=True, eq=False)
class RowRun:
    """Consecutive rows of a merged feed (:meth:`Drive.feed`) from a few channels, as columns of Python floats.

    Attributes
    ----------
    names : list of str
        The feed's channels; ``code`` indexes them.
    code : list of int
        Each row's channel.
    key_s : list of float
        Each row's merge time: its arrival (``by="arrival"``) or its ``t_s``.
    columns : dict of str to list of float
        Every column of the run's channels, ``t_s`` included; NaN on the
        rows of a channel without that column. Python floats: a loop over
        rows reads them without a NumPy scalar each.
    """

    names: list[str]
    code: list[int]
    key_s: list[float]
    columns: dict[str, list[float]]
    _tables: list = field(repr=False)
    _row: list[int] = field(repr=False)

    def __len__(self) -> int:
        return len(self.code)

    def measurement(self, i: int) -> Measurement:
        """Row ``i`` as the :class:`Measurement` :meth:`Drive.measurements` gives."""
        return next(_rows_as_measurements(self._tables, [self.code[i]], [self._row[i]]))


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
        """True when the ``imu`` channel carries accelerometer readings: both axes finite in most rows.

        A non-finite sample among them is a gap in the accelerometers, which
        the estimators bridge (hold the last sample, or use their model
        without accelerometers for a while), not their absence: one NaN in
        7601 rows keeps the inertial models (issue 14, item 5). A source
        without accelerometers (Plaza, MRCLAM) leaves every row NaN.
        """
        if not self.has("imu"):
            return False
        imu = self.channels["imu"]
        finite = np.isfinite(imu.accel_x_mps2) & np.isfinite(imu.accel_y_mps2)
        return 2 * int(np.count_nonzero(finite)) > len(imu)

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
        yield from self.feed(channels, by)

    def feed(self, channels: tuple[str, ...] | list[str], by: str = "arrival", runs_of: tuple[str, ...] = ()) -> Iterator[Measurement | RowRun]:
        """The merge of :meth:`measurements`, with consecutive rows of the ``runs_of`` channels as one :class:`RowRun`.

        An offline estimator takes the high-rate channels (IMU, wheel) of a
        recorded drive as arrays between the readings that interrupt them,
        instead of one :class:`Measurement` at a time; the order is the
        same.
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
        order = np.lexsort((np.concatenate(rows), np.concatenate(codes), np.concatenate(keys)))
        key = np.concatenate(keys)[order]
        code = np.concatenate(codes)[order]
        row = np.concatenate(rows)[order]
        tables = [
            (name, list(self.channels[name].columns.keys()), np.column_stack(list(self.channels[name].columns.values())).tolist())
            for name in names
        ]
        batched = np.isin(code, [i for i, name in enumerate(names) if name in runs_of])
        if not batched.any():
            yield from _rows_as_measurements(tables, code.tolist(), row.tolist())
            return
        columns = {c: v.tolist() for c, v in _merged_columns(self, names, runs_of, code, row).items()}
        edges = [0, *(np.flatnonzero(np.diff(batched)) + 1).tolist(), len(code)]
        code, row, key = code.tolist(), row.tolist(), key.tolist()
        for a, b in zip(edges[:-1], edges[1:]):
            if batched[a]:
                yield RowRun(names, code[a:b], key[a:b], {c: v[a:b] for c, v in columns.items()}, tables, row[a:b])
            else:
                yield from _rows_as_measurements(tables, code[a:b], row[a:b])


def _rows_as_measurements(tables: list, codes: list[int], rows: list[int]) -> Iterator[Measurement]:
    """Measurements of rows given by channel code and row number; ``tables``: (name, column names, rows as lists) per code."""
    for c, r in zip(codes, rows):
        name, col_names, table = tables[c]
        values = dict(zip(col_names, table[r]))
        t = values["t_s"]
        yield Measurement(name, t, values.get("arrival_s", t), values)


def _merged_columns(drive: Drive, names: list[str], channels: tuple[str, ...], code: np.ndarray, row: np.ndarray) -> dict[str, np.ndarray]:
    """The columns of ``channels`` over a merge (``code``, ``row``), NaN where a row is of another channel."""
    columns: dict[str, np.ndarray] = {}
    for i, name in enumerate(names):
        if name not in channels:
            continue
        at = code == i
        for column, values in drive.channels[name].columns.items():
            merged = columns.setdefault(column, np.full(len(code), np.nan))
            merged[at] = values[row[at]]
    return columns
