"""Display names of the reports: windows (zones) and the sensors each estimator uses.

The keys of ``results.json`` stay the drives' own window labels
(``in_tunnel``, ``zone:approach`` ...); the report tables and plot legends
show :func:`window_name` of them, defined here and nowhere else.

Window labels come from the drives: :mod:`graphpos.sim` marks ``in_tunnel``
and one ``zone:*`` window per zone the vehicle passes (``zone:tunnel`` has
the bounds of ``in_tunnel``; ``zone:approach`` is both the road before the
tunnel and the road after it: windows of one label are united when scored,
:func:`eval.metrics.window_masks`), ``straight`` and ``curve`` for the
route's geometry and ``fault:*`` for injected faults; :data:`eval.metrics.WHOLE`
is the whole drive.
"""

from __future__ import annotations

from typing import Any, Iterable

#: Display name of each window label (scored windows: a label's intervals united).
WINDOW_NAMES: dict[str, str] = {
    "whole": "whole drive",
    "in_tunnel": "in the tunnel",
    "zone:tunnel": "in the tunnel",
    "zone:approach": "outside the tunnel (approach and exit)",
    "zone:open": "open area (before the tunnel)",
    "zone:street": "street (after the tunnel)",
    "straight": "straight sections",
    "curve": "curve",
}

#: Display names of the channels an estimator may read, in the order they are listed.
SENSOR_NAMES: dict[str, str] = {"rfid": "RFID", "imu": "IMU", "wheel": "wheel", "compass": "compass",
                                "rsu": "RSU", "gnss": "GNSS"}
#: What an estimator reading only RFID uses of it: ranges (from RSS through the range model, or the
#: radio's own ranges).
RFID_ONLY = "RFID ranges only"
#: Estimators whose sensors are not their declared channels (graph-ranges shares the graph's channel
#: declaration but adds only range factors).
SENSOR_OVERRIDES: dict[str, str] = {"graph-ranges": RFID_ONLY}


def window_name(label: str) -> str:
    """A reader's name of a window label (``fault:rfid_blackout`` -> ``during the fault rfid blackout``)."""
    if label in WINDOW_NAMES:
        return WINDOW_NAMES[label]
    if label.startswith("fault:"):
        return f"during the fault {label[len('fault:'):].replace('_', ' ')}"
    if label.startswith("zone:"):
        return f"zone {label[len('zone:'):]}"
    return label


def span_name(label: str, start_s: float, tunnel: tuple[float, float] | None) -> str:
    """The name of one interval of a window (plots shade each interval): the approach zone's interval
    after the tunnel is the exit."""
    if label == "zone:approach" and tunnel is not None:
        return "exit (after the tunnel)" if start_s >= tunnel[1] else "approach (before the tunnel)"
    return window_name(label)


def same_windows(windows: Iterable[Any]) -> list[list[str]]:
    """Window labels grouped by identical interval sets (``in_tunnel`` and ``zone:tunnel`` score the same
    epochs), each group in first-seen order, groups in order of their first label."""
    spans: dict[str, list[tuple[float, float]]] = {}
    for w in windows:
        spans.setdefault(w.label, []).append((float(w.start_s), float(w.end_s)))
    groups: dict[tuple, list[str]] = {}
    for label, s in spans.items():
        groups.setdefault(tuple(sorted(s)), []).append(label)
    return list(groups.values())


def sensors_of(estimator: str, channels: Iterable[str] | None = None) -> str:
    """The sensors ``estimator`` reads on a drive carrying ``channels`` (all it can read when None):
    ``"RFID ranges only"``, ``"RFID + IMU + wheel + compass"`` ...; ``"–"`` for an unknown name."""
    from graphpos.registry import estimator_classes

    if estimator in SENSOR_OVERRIDES:
        return SENSOR_OVERRIDES[estimator]
    cls = estimator_classes().get(estimator)
    if cls is None:
        return "–"
    used = set(getattr(cls, "required_channels", ())) | set(getattr(cls, "optional_channels", ()))
    if channels is not None:
        used &= set(channels)
    names = [SENSOR_NAMES[c] for c in SENSOR_NAMES if c in used]
    if names == ["RFID"]:
        return RFID_ONLY
    return " + ".join(names) if names else "–"
