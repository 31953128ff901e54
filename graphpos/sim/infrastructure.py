"""RFID tags and roadside units placed along a route's tunnels.

Tag geometry (2-D): tags sit on both tunnel walls, ``width_m / 2`` either
side of the centreline, at every ``spacing_m`` of centreline arc length from
the tunnel's entry portal (the first pair at the portal), the same positions
on both walls. The reader is on the vehicle (its position is the vehicle's;
height differences are ignored).

Layouts (named subsets of one drive's tags):

- ``dense``: every tag (song2016 §6.2: both walls every 6 m);
- ``optimized``: song2016 §5.1 groups of four (two per wall, 6 m apart)
  every ``group_spacing_m`` (30 m); in the paper-* tunnels 16 of the 42 tags;
- ``groups-60m``, ``groups-90m``, ``groups-120m``: the same groups every 60,
  90, 120 m, for a layout study. Only groups that fit inside a tunnel are
  placed, so a short tunnel holds fewer groups.

``group`` in the tag map is the index of a tag's ``optimized`` group (-1 for
a tag outside every group).

A planned layout (``graphpos plan-layout``, issue 18) replaces these: with
``tags.family`` set, the tunnel holds exactly that family's tags (the
``planned`` layout, also ``dense``), placed by :func:`family_offsets`:

- ``pairs``: both walls at the same positions every ``family_spacing_m``;
- ``staggered``: each wall every ``family_spacing_m``, the right wall's
  tags half a spacing after the left's;
- ``one-wall``: the left wall only, every ``family_spacing_m``;
- ``groups``: groups of ``family_group_tags`` pairs ``family_group_pitch_m``
  apart, a group starting every ``family_spacing_m`` (song2016 §5.1's
  optimized layout is groups of 2 pairs 6 m apart every 30 m).

Positions start at each tunnel's entry portal; a tag (or group) that would
lie past the tunnel's end is not placed.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from graphpos.drive import RsuMap, TagMap
from graphpos.errors import ConfigError
from graphpos.sim.route import Route

#: Layout families a planned layout may take (``tags.family``).
FAMILIES = ("pairs", "staggered", "one-wall", "groups")

#: Group spacings (m) of the layout-study layouts ``groups-<N>m``.
STUDY_GROUP_SPACINGS_M = (60, 90, 120)

_EPS = 1e-6


def family_offsets(tags: dict[str, Any], length_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Offsets from a tunnel's entry (m) and wall sides (+1 left, -1 right) of a planned layout.

    Parameters
    ----------
    tags : dict
        The ``tags`` parameters (``family``, ``family_spacing_m``,
        ``family_group_tags``, ``family_group_pitch_m``).
    length_m : float
        The tunnel's centreline length.
    """
    family, every = tags["family"], float(tags["family_spacing_m"])
    starts = np.arange(0.0, length_m + _EPS, every)
    if family == "pairs":
        return np.repeat(starts, 2), np.tile([1, -1], starts.size)
    if family == "one-wall":
        return starts, np.ones(starts.size, dtype=np.int64)
    if family == "staggered":
        right = starts[starts + every / 2 <= length_m + _EPS] + every / 2
        offsets = np.concatenate([starts, right])
        side = np.concatenate([np.ones(starts.size, dtype=np.int64), -np.ones(right.size, dtype=np.int64)])
        order = np.argsort(offsets, kind="stable")
        return offsets[order], side[order]
    if family == "groups":
        span_m = (int(tags["family_group_tags"]) - 1) * float(tags["family_group_pitch_m"])
        starts = starts[starts + span_m <= length_m + _EPS]
        within = np.arange(int(tags["family_group_tags"])) * float(tags["family_group_pitch_m"])
        pairs = (starts[:, None] + within[None, :]).ravel()
        return np.repeat(pairs, 2), np.tile([1, -1], pairs.size)
    raise ConfigError(f"unknown tags.family '{family}' (known: {', '.join(FAMILIES)})")


def _planned_tags(route: Route, tags: dict[str, Any], spans: list[tuple[float, float]]) -> TagMap:
    """The tag map of a planned layout (``tags.family`` set): its tags are every layout."""
    s_parts, side_parts = [], []
    for t0, t1 in spans:
        offsets, side = family_offsets(tags, t1 - t0)
        s_parts.append(t0 + offsets)
        side_parts.append(side)
    s, side = np.concatenate(s_parts), np.concatenate(side_parts).astype(np.int64)
    east, north = np.empty(s.size), np.empty(s.size)
    for sd in (+1, -1):
        m = side == sd
        if m.any():
            east[m], north[m] = route.wall_points(s[m], sd)
    ids = np.arange(1, s.size + 1, dtype=np.int64)
    return TagMap(ids, east, north, side, np.full(s.size, -1, dtype=np.int64), {"dense": ids, "planned": ids})


def place_tags(route: Route, tags: dict[str, Any]) -> TagMap:
    """Tag map with the ``dense``, ``optimized`` and ``groups-<N>m`` layouts,
    or a planned layout's tags when ``tags.family`` is set."""
    spacing, group_len = tags["spacing_m"], tags["group_length_m"]
    spans = route.spans(zone="tunnel")
    if not spans:
        return no_tags()
    if tags.get("family"):
        return _planned_tags(route, tags, spans)
    s_parts, side_parts, span_parts, off_parts = [], [], [], []
    for k, (t0, t1) in enumerate(spans):
        offsets = np.repeat(np.arange(0.0, t1 - t0 + _EPS, spacing), 2)
        s_parts.append(t0 + offsets)
        off_parts.append(offsets)
        side_parts.append(np.tile([1, -1], offsets.size // 2))
        span_parts.append(np.full(offsets.size, k))
    s = np.concatenate(s_parts)
    offset = np.concatenate(off_parts)
    side = np.concatenate(side_parts).astype(np.int64)
    span = np.concatenate(span_parts)
    lengths = np.array([t1 - t0 for t0, t1 in spans])
    n = s.size
    east = np.empty(n)
    north = np.empty(n)
    for sd in (+1, -1):
        m = side == sd
        east[m], north[m] = route.wall_points(s[m], sd)
    ids = np.arange(1, n + 1, dtype=np.int64)

    def groups(every_m: float) -> np.ndarray:
        """Group index per tag for groups of length ``group_len`` starting
        every ``every_m`` from each tunnel's entry (-1 outside a group);
        a group that would run past the tunnel's end is not placed."""
        g = np.floor((offset + _EPS) / every_m)
        start = g * every_m
        member = (offset - start <= group_len + _EPS) & (start + group_len <= lengths[span] + _EPS)
        per_span = np.maximum(np.floor((lengths - group_len + _EPS) / every_m) + 1, 0)
        first = np.concatenate([[0], np.cumsum(per_span)])[:-1]
        return np.where(member, first[span] + g, -1).astype(np.int64)

    optimized = groups(tags["group_spacing_m"])
    layouts = {"dense": ids, "optimized": ids[optimized >= 0]}
    for every in STUDY_GROUP_SPACINGS_M:
        layouts[f"groups-{every}m"] = ids[groups(float(every)) >= 0]
    return TagMap(ids, east, north, side, optimized, layouts)


def no_tags() -> TagMap:
    """An empty tag map that still names every layout (a route without tags)."""
    none = np.zeros(0, dtype=np.int64)
    names = ["dense", "optimized"] + [f"groups-{every}m" for every in STUDY_GROUP_SPACINGS_M]
    return TagMap(none, none, none, none, none, {name: none for name in names})


def place_rsus(route: Route, rsu: dict[str, Any]) -> RsuMap:
    """``count`` RSUs evenly along the tunnels (centred in equal shares),
    alternately on the right and left wall (liu2016 §3: 7 RSUs in the tunnel)."""
    spans = route.spans(zone="tunnel")
    total = sum(b - a for a, b in spans)
    count = int(rsu["count"])
    if count == 0 or total <= 0:
        return RsuMap.empty()
    along = (np.arange(count) + 0.5) * total / count
    s = np.empty(count)
    for i, d in enumerate(along):
        for a, b in spans:
            if d <= b - a:
                s[i] = a + d
                break
            d -= b - a
    side = np.where(np.arange(count) % 2 == 0, -1, 1)
    east, north = np.empty(count), np.empty(count)
    for sd in (+1, -1):
        m = side == sd
        east[m], north[m] = route.wall_points(s[m], sd)
    return RsuMap(np.arange(1, count + 1), east, north)
