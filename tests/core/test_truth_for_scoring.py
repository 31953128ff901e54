"""Truth is for scoring only (issue 13): no estimator's output depends on the drive's truth.

Every registered estimator runs on a short simulated drive with its truth and
on the same drive without it (:meth:`graphpos.drive.Drive.without_truth`:
no ``truth`` channel, ``rfid.true_range_m`` NaN); the outputs must be the
same, column for column and row for row. A third run on the drive stripped
of everything else the simulator derives from its ground truth — the
windows (``in_tunnel``, zones, fault episodes) and the provenance
``params`` (realised sensor errors, fault specs, noise parameters; only
``rss_environment``, which names the radio's environment, is kept) — must
agree too: :meth:`~graphpos.drive.Drive.without_truth` keeps those, so no
estimator may read them either. The drives:

- ``paper-straight`` (imu, wheel, compass, RFID with true ranges, a DGPS
  ``gnss`` approach): every estimator runs on it;
- 30 s of ``urban-rsu-gnss`` around the tunnel entrance (GNSS fixes, then
  RSU fixes and ranges): the estimators that use ``rsu`` (``fkf``, the
  graphs) and ``dr``.
"""

from __future__ import annotations

import numpy as np
import pytest

from graphpos.drive import CHANNEL_SPECS, TRUTH_DERIVED_COLUMNS
from graphpos.ignition import StartPose
from graphpos.registry import estimator_classes, make_estimator
from graphpos.sim import simulate

#: Absolute tolerance of the comparison (the outputs should be bit-identical).
TOLERANCE = 1e-9
#: The urban-rsu-gnss segment: GNSS until the tunnel at 54 s, RSU readings after.
URBAN_SPAN_S = (45.0, 75.0)


@pytest.fixture(scope="module")
def paper_drive():
    return simulate("paper-straight", seed=1, duration_s=25.0)


@pytest.fixture(scope="module")
def urban_drive():
    drive = simulate("urban-rsu-gnss", seed=0)
    lo, hi = URBAN_SPAN_S
    return drive.replace(name=f"{drive.name}-{lo:.0f}-{hi:.0f}s",
                         channels={k: ch.between(lo, hi) for k, ch in drive.channels.items()},
                         windows=())


def _runs_on(name: str, drive) -> bool:
    cls = estimator_classes()[name]
    return all(drive.has(c) for c in cls.required_channels)


def bare(drive):
    """The drive without truth, windows or provenance (but the RSS environment, see the module doc)."""
    kept = {k: drive.params[k] for k in ("rss_environment",) if k in drive.params}
    return drive.without_truth().replace(windows=(), params=kept)


def assert_same_table(name: str, reference, other, what: str) -> None:
    assert len(other) == len(reference), f"{name}: {len(other)} rows {what}, {len(reference)} with truth"
    a, b = reference.table(), other.table()
    assert a.keys() == b.keys()
    for column in a:
        np.testing.assert_allclose(b[column], a[column], rtol=0.0, atol=TOLERANCE, equal_nan=True,
                                   err_msg=f"{name}: column {column} differs {what}")
    for key in ("start", "not_started"):
        assert other.diagnostics.get(key) == reference.diagnostics.get(key), f"{name}: diagnostics[{key!r}] differs {what}"


def assert_same_output(name: str, drive, **kwargs) -> None:
    """Run ``name`` (fresh instances, built with ``kwargs``) on ``drive``, ``drive.without_truth()`` and :func:`bare`;
    the tables must agree."""
    with_truth = make_estimator(name, **kwargs).run(drive)
    assert len(with_truth) > 0, f"{name} gave no output on {drive.name}: the test drive does not exercise it"
    assert_same_table(name, with_truth, make_estimator(name, **kwargs).run(drive.without_truth()), f"without truth on {drive.name}")
    assert_same_table(name, with_truth, make_estimator(name, **kwargs).run(bare(drive)), f"without windows and params on {drive.name}")


def test_paper_drive_carries_truth_and_every_channel(paper_drive):
    """The test drive really has truth to leak, and every channel the estimators need."""
    assert paper_drive.has("truth")
    assert np.isfinite(paper_drive.rfid.true_range_m).all()
    for name, cls in estimator_classes().items():
        assert _runs_on(name, paper_drive), f"{name} needs {cls.required_channels}"


@pytest.mark.parametrize("name", list(estimator_classes()))
def test_same_output_without_truth(name, paper_drive):
    assert_same_output(name, paper_drive)


#: Estimators that read ``rsu`` (and ``dr``, which starts from the GNSS fixes there).
RSU_ESTIMATORS = ["dr"] + [n for n, cls in estimator_classes().items() if "rsu" in (*cls.required_channels, *cls.optional_channels)]


#: Estimators that cannot start there by themselves: graph-ranges hears one RSU a second, and a ranges-only
#: start (no dead reckoning) needs two landmarks at once; it is given a start pose at the first RSU reading.
GIVEN_A_POSE = ("graph-ranges",)


@pytest.mark.parametrize("name", RSU_ESTIMATORS)
def test_same_output_without_truth_on_rsu_drive(name, urban_drive):
    assert urban_drive.has("rsu") and urban_drive.has("gnss") and urban_drive.has("truth")
    assert _runs_on(name, urban_drive)
    kwargs = {}
    if name in GIVEN_A_POSE:
        t0 = urban_drive.rsu.t_s[0]
        tr = urban_drive.truth
        kwargs["initial_pose"] = StartPose(float(np.interp(t0, tr.t_s, tr.east_m)), float(np.interp(t0, tr.t_s, tr.north_m)), 0.0, 2.0)
    assert_same_output(name, urban_drive, **kwargs)


def test_without_truth_removes_the_truth(paper_drive):
    blind = paper_drive.without_truth()
    assert "truth" not in blind.channels and not blind.has("truth")
    with pytest.raises(AttributeError):
        blind.truth  # noqa: B018 - the attribute must be gone
    assert np.isnan(blind.rfid.true_range_m).all()
    # nothing else changed: the other rfid columns, the other channels, maps, windows, params
    for column in CHANNEL_SPECS["rfid"]:
        if column.name not in TRUTH_DERIVED_COLUMNS["rfid"]:
            np.testing.assert_array_equal(blind.rfid[column.name], paper_drive.rfid[column.name])
    assert set(blind.channels) == set(paper_drive.channels) - {"truth"}
    for name, channel in blind.channels.items():
        if name != "rfid":
            assert channel == paper_drive.channels[name]
    assert blind.tags == paper_drive.tags and blind.rsus == paper_drive.rsus
    assert blind.windows == paper_drive.windows and blind.params == paper_drive.params
    # the original drive keeps its truth; a second removal changes nothing
    assert paper_drive.has("truth") and np.isfinite(paper_drive.rfid.true_range_m).all()
    twice = blind.without_truth()
    assert set(twice.channels) == set(blind.channels)
    assert all(twice.channels[k] == blind.channels[k] for k in blind.channels)
