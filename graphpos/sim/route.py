"""Road centrelines made of straight and circular segments, with named zones.

A :class:`Route` is the road a scenario drives: a chain of segments of
constant curvature (0 for straight, +1/R for a left bend), each in a zone
(``approach``, ``tunnel``, ``open``, ``street`` ...). Positions along it are
given by the arc length ``s`` of the centreline; the closed forms below are
exact, so the simulated track has no integration error.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Segment:
    """A piece of road of constant curvature.

    Attributes
    ----------
    length_m : float
        Centreline arc length.
    curvature_1pm : float
        1/radius, positive for a left (counter-clockwise) bend, 0 if straight.
    zone : str
        Zone the segment belongs to (``tunnel`` has walls and tags).
    """

    length_m: float
    curvature_1pm: float
    zone: str


def advance(x0, y0, heading0, curvature, u):
    """Pose after travelling ``u`` metres at constant curvature (exact, vectorised).

    Parameters
    ----------
    x0, y0, heading0 : float or array
        Start pose (heading from east, counter-clockwise).
    curvature : float or array
        1/radius, positive to the left.
    u : float or array
        Distance travelled.

    Returns
    -------
    x, y, heading : arrays
    """
    k = np.asarray(curvature, dtype=np.float64)
    u = np.asarray(u, dtype=np.float64)
    heading = heading0 + k * u
    straight = np.abs(k) < 1e-12
    k_safe = np.where(straight, 1.0, k)
    x = np.where(straight, x0 + u * np.cos(heading0), x0 + (np.sin(heading) - np.sin(heading0)) / k_safe)
    y = np.where(straight, y0 + u * np.sin(heading0), y0 - (np.cos(heading) - np.cos(heading0)) / k_safe)
    return x, y, heading


class Route:
    """A road centreline starting at the origin heading east.

    Parameters
    ----------
    segments : sequence of Segment
    width_m : float
        Wall-to-wall width of the tunnel (the road's width elsewhere).
    lane_width_m : float
        Lane width; the vehicle keeps to the centre of the right-hand lane,
        ``lane_width_m / 2`` to the right of the centreline.
    """

    def __init__(self, segments: list[Segment], width_m: float, lane_width_m: float):
        self.segments = tuple(seg for seg in segments if seg.length_m > 0)
        self.width_m = float(width_m)
        self.lane_width_m = float(lane_width_m)
        lengths = np.array([seg.length_m for seg in self.segments])
        self.seg_start_s = np.concatenate([[0.0], np.cumsum(lengths)[:-1]])
        self.seg_curvature = np.array([seg.curvature_1pm for seg in self.segments])
        self.length_m = float(lengths.sum())
        self.zones: tuple[str, ...] = tuple(dict.fromkeys(seg.zone for seg in self.segments))
        self.seg_zone = np.array([self.zones.index(seg.zone) for seg in self.segments])
        poses = [(0.0, 0.0, 0.0)]
        for seg in self.segments[:-1]:
            x, y, h = advance(*poses[-1], seg.curvature_1pm, seg.length_m)
            poses.append((float(x), float(y), float(h)))
        self.seg_pose = np.array(poses)
        end = advance(*poses[-1], self.segments[-1].curvature_1pm, self.segments[-1].length_m)
        self.end_pose = tuple(float(v) for v in end)

    def _segment_index(self, s: np.ndarray) -> np.ndarray:
        return np.clip(np.searchsorted(self.seg_start_s, s, side="right") - 1, 0, len(self.segments) - 1)

    def centre(self, s_m: np.ndarray):
        """Centreline east, north, heading and curvature at arc lengths ``s_m``.

        Beyond either end the road continues straight along its end heading.
        """
        s = np.asarray(s_m, dtype=np.float64)
        i = self._segment_index(s)
        u = s - self.seg_start_s[i]
        k = np.where((s < 0) | (s > self.length_m), 0.0, self.seg_curvature[i])
        x0, y0, h0 = self.seg_pose[i, 0], self.seg_pose[i, 1], self.seg_pose[i, 2]
        after = s > self.length_m
        if after.any():
            x0 = np.where(after, self.end_pose[0], x0)
            y0 = np.where(after, self.end_pose[1], y0)
            h0 = np.where(after, self.end_pose[2], h0)
            u = np.where(after, s - self.length_m, u)
        x, y, h = advance(x0, y0, h0, k, u)
        return x, y, h, k

    def zone_index(self, s_m: np.ndarray) -> np.ndarray:
        """Index into :attr:`zones` of the segment at each ``s_m``."""
        return self.seg_zone[self._segment_index(np.asarray(s_m, dtype=np.float64))]

    def spans(self, zone: str | None = None, curved: bool | None = None) -> list[tuple[float, float]]:
        """``(s_start, s_end)`` of the segments in a zone and/or of a kind, merged."""
        out: list[list[float]] = []
        for seg, s0 in zip(self.segments, self.seg_start_s):
            if zone is not None and seg.zone != zone:
                continue
            if curved is not None and (seg.curvature_1pm != 0.0) != curved:
                continue
            if out and abs(out[-1][1] - s0) < 1e-9:
                out[-1][1] = s0 + seg.length_m
            else:
                out.append([float(s0), float(s0 + seg.length_m)])
        return [(a, b) for a, b in out]

    def wall_points(self, s_m: np.ndarray, side: int):
        """East, north of the wall on ``side`` (+1 left, -1 right) at ``s_m``."""
        x, y, h, _ = self.centre(s_m)
        off = side * self.width_m / 2.0
        return x - off * np.sin(h), y + off * np.cos(h)
