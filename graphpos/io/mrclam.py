"""Importer of the UTIAS MRCLAM datasets (Leung, Halpern, Barfoot, Liu, IJRR 2011).

One MRCLAM dataset is a folder of text files: four ``#`` header lines, then
one row per line of whitespace-separated numbers. Five robots (subjects 1-5)
drive among landmarks (subjects 6-20) in a room; the files read here, checked
against Dataset 6 (see ``tests/io/test_mrclam.py``):

``Barcodes.dat`` ``subject barcode``
    The barcode a camera reads on each subject.
``Landmark_Groundtruth.dat`` ``subject x_m y_m sigma_x_m sigma_y_m``
    Surveyed landmark positions (the sigmas, a fraction of a millimetre, are
    not imported).
``RobotN_Odometry.dat`` ``t_s v_mps omega_radps``
    Forward speed and turn rate at 67-100 Hz. The speed takes a few dozen
    levels (0-0.086 m/s in Dataset 6): these are commanded velocities rather
    than encoder readings, each holding until the next row. A few time stamps
    repeat (Dataset 6: 23 of about 300 000 rows, 18 of them identical to the
    row before); of each run of rows with one stamp the *last* is kept: held
    until the next stamp, the earlier ones would last zero seconds, so
    keeping the last changes nothing a zero-order-hold integration of the
    file would give, and two rows at one time would mean two different speeds
    at the same instant. Checked against the truth (Dataset 6, five
    robots): the speed integrated is 4-10 % longer than the truth path
    (resampled at 2 Hz), the truth's heading change over 5 s windows is
    0.92-0.97 x omega's less 0.5-4 mrad/s, and the truth follows the
    odometry by about 0.25 s. None of this is corrected here.
``RobotN_Measurement.dat`` ``t_s barcode range_m bearing_rad``
    Camera sightings at 2-5 Hz, several per image (so stamps repeat; every
    row is kept). A barcode that ``Barcodes.dat`` maps to a landmark of
    ``Landmark_Groundtruth.dat`` is a landmark sighting; sightings of other
    robots (subjects 1-5), of barcodes ``Barcodes.dat`` does not list and of
    subjects without a surveyed position are dropped and counted in the
    drive's ``params``. The bearing is kept (``bearing_rad``) for the sensor
    profile's bearing-dependent range term.
    Dataset 6's ranges minus the truth-derived distances: median -0.02 to
    +0.07 m, robust sigma 0.08-0.18 m per robot. Most of that error is a
    function of the landmark's bearing ``b`` in the camera image:
    ``error = c0 + c2 b^2`` with c0 +0.09 to +0.19 m and c2 -1.5 to
    -1.9 m/rad^2 on all five robots, and fitted it leaves an RMS of
    0.06-0.08 m instead of 0.12-0.19 m. As the bearing changes slowly, a
    range-only estimator sees it as errors correlated over seconds (lag-1
    correlation of a landmark's errors 0.5-0.7 at 1 s). graph-batch's
    self-calibration fits ``c2`` from the drive itself
    (:func:`graphpos.graph.calibration.fit_bearing_term`).
``RobotN_Groundtruth.dat`` ``t_s x_m y_m theta_rad``
    Vicon poses at about 60 Hz; theta is counter-clockwise from x and agrees
    with the direction of motion. Taking x as east and y as north, it is the
    project's yaw. It is stored wrapped to [-pi, pi]; it is unwrapped here.
    Repeated stamps (none in Dataset 6) are treated as in the odometry.

Rows of every file are sorted by time (stable; Dataset 6 needs none) and the
number of rows moved is recorded in ``params``.

Times are the files' own clock, Unix seconds (Dataset 6: 1248444175-
1248445075 s), kept as they are: the five robots of a dataset share that
clock, so their drives stay aligned with each other (e.g. for a later
cooperative or robot-to-robot study) and with the date of the recording, and
float64 still resolves 0.24 microseconds at that magnitude, far below the
files' millisecond stamps.

The drive has:

- ``wheel``: ``speed_mps`` = v of each odometry row;
- ``imu``: ``yaw_rate_radps`` = omega of each odometry row; accelerometer
  columns NaN (the dataset has none);
- ``rfid``: one row per landmark sighting: ``tag_id`` = the landmark's
  subject number, ``range_m`` as recorded (uncorrected: calibration is the
  ranging layer's job), ``rss`` NaN, ``true_range_m`` the distance from the
  ground truth position (interpolated at the reading time; NaN outside the
  ground truth's time span: Dataset 6's robot 1 truth ends 130 s before its
  other files) to the landmark — truth, for evaluating ranging only;
- ``truth``: positions and unwrapped yaw; velocity by differentiating the
  positions (``numpy.gradient``, second order, uneven spacing); yaw rate
  and accelerations NaN;
- ``tags``: one per landmark, ``tag_id`` = subject, ``wall_side`` 0,
  ``group`` -1, layout ``dense`` only.

The geodetic origin defaults to an approximate position of UTIAS, Toronto
(the dataset has no geodetic reference; altitude left 0); it only places the
room on a map.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from graphpos.drive import Channel, Drive, GeoOrigin, TagMap, truth_from_poses
from graphpos.errors import DriveError, FileFormatError
from graphpos.io.files import read_input

#: Approximate geodetic position of the MRCLAM room (UTIAS, Toronto).
MRCLAM_ORIGIN = GeoOrigin(lat_deg=43.7823, lon_deg=-79.4660)
#: Where the data comes from, said when the folder is missing.
MRCLAM_SOURCE = ("the UTIAS MRCLAM datasets are published at asrl.utias.utoronto.ca/datasets/mrclam "
                 "(Leung et al., IJRR 2011): unpack one, e.g. MRCLAM_Dataset6, and give its folder")

#: Subject numbers of the robots; every other subject is a landmark.
ROBOTS = (1, 2, 3, 4, 5)

#: Column names of each file (``{n}``: the robot number).
_COLUMNS = {
    "Barcodes.dat": ("subject", "barcode"),
    "Landmark_Groundtruth.dat": ("subject", "x_m", "y_m", "sigma_x_m", "sigma_y_m"),
    "Robot{n}_Odometry.dat": ("t_s", "v_mps", "omega_radps"),
    "Robot{n}_Measurement.dat": ("t_s", "barcode", "range_m", "bearing_rad"),
    "Robot{n}_Groundtruth.dat": ("t_s", "x_m", "y_m", "theta_rad"),
}

#: Fewest data rows of each file (a robot may sight nothing; truth is differentiated).
_MIN_ROWS = {"Barcodes.dat": 1, "Landmark_Groundtruth.dat": 1, "Robot{n}_Odometry.dat": 1,
             "Robot{n}_Measurement.dat": 0, "Robot{n}_Groundtruth.dat": 2}


class _Table:
    """The numeric rows of one MRCLAM file and the file line of each row."""

    def __init__(self, path: Path, columns: tuple[str, ...], values: np.ndarray, lines: np.ndarray):
        self.path = path
        self.columns = columns
        self.values = values
        self.lines = lines

    def __len__(self) -> int:
        return int(self.lines.size)

    def column(self, name: str) -> np.ndarray:
        return self.values[:, self.columns.index(name)]

    def select(self, index: np.ndarray) -> "_Table":
        return _Table(self.path, self.columns, self.values[index], self.lines[index])

    def whole(self, name: str) -> None:
        """Require whole numbers in a column (ids)."""
        col = self.column(name)
        bad = col != np.round(col)
        if bad.any():
            i = int(np.argmax(bad))
            j = self.columns.index(name)
            raise FileFormatError(f"{self.path}: line {int(self.lines[i])}, column {j + 1} ({name}): {col[i]:g} is not a whole number")

    def sorted_by_time(self) -> tuple["_Table", int]:
        """Rows in time order (stable) and how many rows that moved."""
        order = np.argsort(self.column("t_s"), kind="stable")
        return self.select(order), int(np.count_nonzero(order != np.arange(order.size)))

    def last_of_each_stamp(self) -> tuple["_Table", int]:
        """Of each run of rows with one time stamp, the last (rows time-sorted)."""
        t = self.column("t_s")
        keep = np.r_[t[1:] != t[:-1], True] if t.size else np.zeros(0, dtype=bool)
        return self.select(keep), int(np.count_nonzero(~keep))


def _read_table(path: Path, columns: tuple[str, ...], min_rows: int) -> _Table:
    """Parse one MRCLAM text file: every non-comment line has ``columns``
    finite numbers. Errors name the file, the line and the column."""
    raw = read_input(path)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise FileFormatError(f"{path}: not a text file (byte {exc.start} is not UTF-8); not an MRCLAM file?") from None
    meaning = " ".join(columns)
    rows: list[list[str]] = []
    lines: list[int] = []
    for number, line in enumerate(text.splitlines(), start=1):
        cells = line.split()
        if not cells or cells[0].startswith("#"):
            continue
        if len(cells) != len(columns):
            raise FileFormatError(f"{path}: line {number}: {len(cells)} columns, expected {len(columns)} ({meaning})")
        rows.append(cells)
        lines.append(number)
    if len(rows) < min_rows:
        raise FileFormatError(f"{path}: {len(rows)} data rows, expected at least {min_rows} ({meaning})")
    line_numbers = np.array(lines, dtype=np.int64)
    try:
        values = np.array(rows, dtype=np.float64).reshape(len(rows), len(columns))
    except ValueError:  # find the cell (numpy's parser and Python's may differ: Python's decides)
        values = np.empty((len(rows), len(columns)))
        for i, cells in enumerate(rows):
            for j, cell in enumerate(cells):
                try:
                    values[i, j] = float(cell)
                except ValueError:
                    raise FileFormatError(f"{path}: line {lines[i]}, column {j + 1} ({columns[j]}): '{cell}' is not a number") from None
    bad = ~np.isfinite(values)
    if bad.any():
        i, j = (int(k) for k in np.argwhere(bad)[0])
        raise FileFormatError(f"{path}: line {lines[i]}, column {j + 1} ({columns[j]}): {rows[i][j]} is not a finite number")
    return _Table(path, columns, values, line_numbers)


def _files(directory: Path, robot: int) -> dict[str, Path]:
    if not directory.exists():
        raise FileFormatError(f"{directory}: no such folder ({MRCLAM_SOURCE})")
    if not directory.is_dir():
        raise FileFormatError(f"{directory}: is a file, not an MRCLAM dataset folder")
    if isinstance(robot, bool) or not isinstance(robot, (int, np.integer)) or int(robot) not in ROBOTS:
        found = sorted({p.name[5] for p in directory.glob("Robot[0-9]_*.dat")})
        raise FileFormatError(
            f"{directory}: no robot {robot!r}; MRCLAM robots are {ROBOTS[0]}-{ROBOTS[-1]} "
            f"(this folder has files of robot(s) {', '.join(found) or 'none'})"
        )
    return {key: directory / key.format(n=int(robot)) for key in _COLUMNS}


def _landmarks(barcodes: _Table, landmarks: _Table) -> tuple[TagMap, dict[int, int]]:
    """The tag map and barcode -> subject."""
    for table in (barcodes, landmarks):
        table.whole("subject")
    barcodes.whole("barcode")
    subject_of: dict[int, int] = {}
    seen_subjects: set[int] = set()
    for (subject, code), line in zip(barcodes.values.astype(np.int64).tolist(), barcodes.lines.tolist()):
        if code in subject_of:
            raise FileFormatError(f"{barcodes.path}: line {line}: barcode {code} is listed twice")
        if subject in seen_subjects:
            raise FileFormatError(f"{barcodes.path}: line {line}: subject {subject} is listed twice")
        subject_of[code] = subject
        seen_subjects.add(subject)
    subjects = landmarks.column("subject").astype(np.int64)
    for i, subject in enumerate(subjects.tolist()):
        line = int(landmarks.lines[i])
        if subject in ROBOTS:
            raise FileFormatError(f"{landmarks.path}: line {line}: subject {subject} is a robot (robots are 1-5), not a landmark")
        if subject < 0:
            raise FileFormatError(f"{landmarks.path}: line {line}: subject {subject} is negative")
        if subject in subjects[:i]:
            raise FileFormatError(f"{landmarks.path}: line {line}: landmark {subject} is listed twice")
    tags = TagMap(subjects, landmarks.column("x_m"), landmarks.column("y_m"), np.zeros(subjects.size), np.full(subjects.size, -1))
    return tags, subject_of


def _truth(gt: _Table) -> Channel:
    t = gt.column("t_s")
    east, north = gt.column("x_m"), gt.column("y_m")
    return truth_from_poses(t, east, north, gt.column("theta_rad"))


def _true_ranges(t_s: np.ndarray, tag_xy: np.ndarray, truth: Channel) -> np.ndarray:
    east = np.interp(t_s, truth.t_s, truth.east_m)
    north = np.interp(t_s, truth.t_s, truth.north_m)
    true = np.hypot(east - tag_xy[:, 0], north - tag_xy[:, 1])
    true[(t_s < truth.t_s[0]) | (t_s > truth.t_s[-1])] = np.nan
    return true


def import_mrclam(directory: str | os.PathLike, robot: int, origin: GeoOrigin = MRCLAM_ORIGIN) -> Drive:
    """Read one robot of an MRCLAM dataset folder as a drive (conventions: module docstring).

    Parameters
    ----------
    directory : path-like
        The dataset folder (e.g. ``MRCLAM_Dataset6``) with ``Barcodes.dat``,
        ``Landmark_Groundtruth.dat`` and the robot's ``RobotN_Odometry.dat``,
        ``RobotN_Measurement.dat`` and ``RobotN_Groundtruth.dat``.
    robot : int
        The robot number, 1-5.
    origin : GeoOrigin
        Geodetic origin of the dataset's x/y frame, for map views.

    Returns
    -------
    Drive
        Named ``<folder>-robot<N>``, with channels ``imu``, ``wheel``,
        ``rfid`` and ``truth``, the landmarks as tags, and ``params``
        recording the source and the rows dropped or reordered.

    Raises
    ------
    FileFormatError
        A missing folder or file, an unknown robot number, a line with the
        wrong number of columns, a cell that is not a finite number, an id
        that is not whole or is listed twice; the message names the file,
        line and column.
    DriveError
        Values the drive model rejects (e.g. a negative range, a turn rate
        beyond 10 rad/s), naming the file, channel, row and file line.
    """
    directory = Path(directory)
    paths = _files(directory, robot)
    robot = int(robot)
    tables = {key: _read_table(path, _COLUMNS[key], _MIN_ROWS[key]) for key, path in paths.items()}
    barcodes, landmarks = tables["Barcodes.dat"], tables["Landmark_Groundtruth.dat"]
    tags, subject_of = _landmarks(barcodes, landmarks)

    odo, odo_moved = tables["Robot{n}_Odometry.dat"].sorted_by_time()
    odo, odo_repeats = odo.last_of_each_stamp()
    gt, gt_moved = tables["Robot{n}_Groundtruth.dat"].sorted_by_time()
    gt, gt_repeats = gt.last_of_each_stamp()
    if len(gt) < 2:
        raise FileFormatError(f"{gt.path}: {len(gt)} distinct time stamps, expected at least 2 (to differentiate positions)")
    meas = tables["Robot{n}_Measurement.dat"]
    meas.whole("barcode")
    meas, meas_moved = meas.sorted_by_time()
    subject = np.array([subject_of.get(int(code), -1) for code in meas.column("barcode")], dtype=np.int64)
    is_robot = np.isin(subject, ROBOTS)
    unknown = subject < 0
    is_landmark = np.isin(subject, tags.tag_id)
    unsurveyed = ~(is_robot | unknown | is_landmark)
    sightings = meas.select(is_landmark)
    tag_id = subject[is_landmark]

    sources = {"imu": odo, "wheel": odo, "rfid": sightings, "truth": gt}
    try:
        truth = _truth(gt)
        t_odo = odo.column("t_s")
        nan_odo = np.full(t_odo.size, np.nan)
        t_rfid = sightings.column("t_s")
        channels = {
            "imu": Channel("imu", {"t_s": t_odo, "accel_x_mps2": nan_odo, "accel_y_mps2": nan_odo,
                                   "yaw_rate_radps": odo.column("omega_radps")}),
            "wheel": Channel("wheel", {"t_s": t_odo, "speed_mps": odo.column("v_mps")}),
            "rfid": Channel("rfid", {
                "t_s": t_rfid,
                "tag_id": tag_id,
                "rss": np.full(t_rfid.size, np.nan),
                "range_m": sightings.column("range_m"),
                "true_range_m": _true_ranges(t_rfid, tags.positions(tag_id), truth),
                "bearing_rad": sightings.column("bearing_rad"),
            }),
            "truth": truth,
        }
    except DriveError as exc:
        table = sources.get(exc.channel)
        if table is None or exc.row is None:
            raise exc.with_source(str(directory)) from None
        raise DriveError(exc.channel, exc.row, f"{exc.reason} (line {int(table.lines[exc.row])})", str(table.path)) from None
    dataset = directory.resolve().name
    params = {
        "source": "mrclam",
        "dataset": dataset,
        "robot": robot,
        "sightings_of_robots_dropped": int(np.count_nonzero(is_robot)),
        "sightings_of_unknown_barcodes_dropped": int(np.count_nonzero(unknown)),
        "sightings_of_unsurveyed_subjects_dropped": int(np.count_nonzero(unsurveyed)),
        "odometry_repeated_stamps_dropped": odo_repeats,
        "truth_repeated_stamps_dropped": gt_repeats,
        "rows_reordered": {"odometry": odo_moved, "measurement": meas_moved, "groundtruth": gt_moved},
        "true_range_m": "distance from the ground truth (linearly interpolated at the reading time) to the landmark; truth, not a sensor",
    }
    return Drive(name=f"{dataset}-robot{robot}", channels=channels, tags=tags, origin=origin, params=params)
