"""PNG figures of the reports (matplotlib, Agg back-end: no display needed).

Each estimator is drawn in its colour of :func:`graphpos.colors.color_of`,
the same in every figure, KML export and Foxglove map, whichever estimators
a figure shows. Windows are shaded under their display names
(:mod:`eval.names`). Legends sit outside the axes, to the right, so that
they hide no track.

Trajectories of a road drive (a tunnel 150 m long and 6 m wide, a street)
are drawn in the route frame (:func:`route_frame`): distance along the true
path against the cross-track offset from it, on a stretched cross-track
axis, so that errors of a metre show; drives in an open area (Plaza, a room)
are drawn on the map at equal aspect.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from eval.metrics import error_series, interpolate_truth, wheel_speed_error  # noqa: E402
from eval.names import span_name  # noqa: E402
from graphpos.colors import TRUTH_COLOR, color_of  # noqa: E402
from graphpos.drive import Drive  # noqa: E402
from graphpos.estimate import Estimate  # noqa: E402
from graphpos.io.outputs import atomic_output  # noqa: E402

_DPI = 110


def _save(fig, path: Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(path) as stream:
        fig.savefig(stream, format="png", dpi=_DPI, bbox_inches="tight")
    plt.close(fig)
    return path


def _legend(ax) -> None:
    """The legend outside the axes, on the right (none without labelled artists)."""
    handles, labels = ax.get_legend_handles_labels()
    if handles:
        ax.legend(handles, labels, fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)


def _label_axes(ax, xlabel: str, ylabel: str, title: str) -> None:
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    _legend(ax)
    ax.set_title(title)
    ax.grid(alpha=0.3)


def _walls(drive: Drive) -> list[np.ndarray]:
    """Wall polylines: the tags of each wall side, ordered along the truth path."""
    if not drive.has("truth") or not len(drive.tags):
        return []
    path = np.column_stack([drive.truth.east_m, drive.truth.north_m])
    seg = np.r_[0.0, np.cumsum(np.hypot(*np.diff(path, axis=0).T))]
    walls = []
    for side in (1, -1):
        sel = drive.tags.wall_side == side
        if sel.sum() < 2:
            continue
        pts = np.column_stack([drive.tags.east_m[sel], drive.tags.north_m[sel]])
        nearest = np.argmin(((pts[:, None, :] - path[None, ::10, :]) ** 2).sum(-1), axis=1)
        walls.append(pts[np.argsort(seg[::10][nearest], kind="stable")])
    return walls


def _frame_on_truth(ax, drive: Drive, margin: float = 0.15) -> None:
    """Frame the truth and the tags (a diverging estimate leaves the frame instead of squashing it)."""
    east = [drive.truth.east_m] if drive.has("truth") else []
    north = [drive.truth.north_m] if drive.has("truth") else []
    east += [drive.tags.east_m, drive.rsus.east_m]
    north += [drive.tags.north_m, drive.rsus.north_m]
    e, n = np.concatenate(east), np.concatenate(north)
    if not e.size:
        return
    span = max(np.ptp(e), np.ptp(n), 10.0)
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlim(e.min() - margin * span, e.max() + margin * span)
    ax.set_ylim(n.min() - margin * span, n.max() + margin * span)


def is_road_drive(drive: Drive) -> bool:
    """A drive along a road (simulated, or with tunnel wall tags): drawn in the route frame."""
    if not drive.has("truth") or len(drive.truth) < 2:
        return False
    return "scenario" in drive.params or bool(len(drive.tags) and np.any(drive.tags.wall_side != 0))


def _along(drive: Drive) -> tuple[np.ndarray, np.ndarray]:
    """Truth epochs and the distance travelled along the true path at each."""
    t = drive.truth
    return t.t_s, np.r_[0.0, np.cumsum(np.hypot(np.diff(t.east_m), np.diff(t.north_m)))]


def route_frame(drive: Drive, estimate: Estimate) -> dict[str, np.ndarray]:
    """An estimate in the true path's frame: ``along_m`` (distance the truth has travelled at the
    estimate's epoch), ``cross_m`` (offset from the truth, left positive, across the true heading) and
    ``along_error_m`` (ahead of the truth positive)."""
    at = interpolate_truth(drive.truth, estimate.t_s)
    t_truth, dist = _along(drive)
    de = estimate.east_m[at.mask] - at.east_m
    dn = estimate.north_m[at.mask] - at.north_m
    c, s = np.cos(at.yaw_rad), np.sin(at.yaw_rad)
    return {"along_m": np.interp(estimate.t_s[at.mask], t_truth, dist), "cross_m": -s * de + c * dn,
            "along_error_m": c * de + s * dn}


def _tags_in_route_frame(drive: Drive) -> tuple[np.ndarray, np.ndarray]:
    """Each tag's distance along the true path (of its nearest truth point) and offset across it."""
    if not len(drive.tags):
        return np.zeros(0), np.zeros(0)
    _, dist = _along(drive)
    tr = drive.truth
    step = max(1, len(tr) // 4000)
    pe, pn, yaw, d = tr.east_m[::step], tr.north_m[::step], tr.yaw_rad[::step], dist[::step]
    te, tn = drive.tags.east_m, drive.tags.north_m
    k = np.argmin((te[:, None] - pe[None, :]) ** 2 + (tn[:, None] - pn[None, :]) ** 2, axis=1)
    return d[k], -np.sin(yaw[k]) * (te - pe[k]) + np.cos(yaw[k]) * (tn - pn[k])


def trajectories(drive: Drive, estimates: list[Estimate], path: Path, layout: str | None = None) -> Path:
    """Truth and estimates: in the route frame for a road drive (:func:`is_road_drive`), else on the map."""
    if is_road_drive(drive):
        return route_trajectories(drive, estimates, path, layout)
    return map_trajectories(drive, estimates, path, layout)


def route_trajectories(drive: Drive, estimates: list[Estimate], path: Path, layout: str | None = None) -> Path:
    """Cross-track offset and along-track error against the distance along the true path (two panels,
    the cross-track axis stretched to the tunnel's width)."""
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(11, 6.5), sharex=True, height_ratios=(3, 2))
    along, offset = _tags_in_route_frame(drive)
    if along.size:
        for i, side in enumerate(sorted({int(v) for v in drive.tags.wall_side if v != 0})):
            sel = drive.tags.wall_side == side
            order = np.argsort(along[sel], kind="stable")
            top.plot(along[sel][order], offset[sel][order], color="0.6", lw=2.5, alpha=0.5,
                     label="tunnel walls" if i == 0 else None)
        heard = np.isin(drive.tags.tag_id, drive.tags.layout(layout)) if layout else np.ones(len(drive.tags), bool)
        top.scatter(along[heard], offset[heard], marker="s", s=12, color="k", label="tags", zorder=3)
        if (~heard).any():
            top.scatter(along[~heard], offset[~heard], marker="s", s=12, facecolors="none", edgecolors="0.5",
                        label="tags not used", zorder=3)
    top.axhline(0.0, color=TRUTH_COLOR, lw=1.2, ls="--", label="truth")
    bottom.axhline(0.0, color=TRUTH_COLOR, lw=1.2, ls="--")
    spread = []
    for est in estimates:
        rf = route_frame(drive, est)
        top.plot(rf["along_m"], rf["cross_m"], lw=1.0, color=color_of(est.name), label=est.name)
        bottom.plot(rf["along_m"], rf["along_error_m"], lw=1.0, color=color_of(est.name))
        spread.append(np.abs(rf["cross_m"][np.isfinite(rf["cross_m"])]))
    values = np.concatenate(spread) if spread else np.zeros(0)
    # the tags and most of every track in view; a diverging estimate leaves the frame instead of squashing it
    lim = max(4.0, float(np.percentile(values, 98)) * 1.15 if values.size else 4.0,
              float(np.abs(offset).max()) * 1.15 if along.size else 0.0)
    top.set_ylim(-lim, lim)
    top.set_ylabel("cross-track offset [m]\n(left of the truth +)")
    bottom.set_ylabel("along-track error [m]\n(ahead +)")
    bottom.set_xlabel("distance along the true path [m]")
    top.set_title(f"{drive.name}: trajectories in the route frame (cross-track axis stretched)")
    for ax in (top, bottom):
        ax.grid(alpha=0.3)
    _legend(top)
    return _save(fig, path)


def map_trajectories(drive: Drive, estimates: list[Estimate], path: Path, layout: str | None = None) -> Path:
    """Truth and estimates over the tunnel walls and tags (the heard layout filled), east against north."""
    fig, ax = plt.subplots(figsize=(10, 6))
    for i, wall in enumerate(_walls(drive)):
        ax.plot(wall[:, 0], wall[:, 1], color="0.6", lw=2.5, alpha=0.5, label="tunnel walls" if i == 0 else None)
    if len(drive.tags):
        heard = np.isin(drive.tags.tag_id, drive.tags.layout(layout)) if layout else np.ones(len(drive.tags), bool)
        ax.scatter(drive.tags.east_m[heard], drive.tags.north_m[heard], marker="s", s=14, color="k", label="tags", zorder=3)
        if (~heard).any():
            ax.scatter(drive.tags.east_m[~heard], drive.tags.north_m[~heard], marker="s", s=14,
                       facecolors="none", edgecolors="0.5", label="tags not used", zorder=3)
    if len(drive.rsus):
        ax.scatter(drive.rsus.east_m, drive.rsus.north_m, marker="^", s=40, color="tab:purple", label="RSUs", zorder=3)
    if drive.has("truth"):
        ax.plot(drive.truth.east_m, drive.truth.north_m, color=TRUTH_COLOR, lw=1.2, ls="--", label="truth")
    for est in estimates:
        ax.plot(est.east_m, est.north_m, lw=1.0, color=color_of(est.name), label=est.name)
    _frame_on_truth(ax, drive)
    ax.set_xlabel("east [m]")
    ax.set_ylabel("north [m]")
    _legend(ax)
    ax.set_title(f"{drive.name}: trajectories")
    ax.grid(alpha=0.3)
    return _save(fig, path)


#: Shading of the windows by display name (start of it), the same in every plot.
_WINDOW_COLORS = {
    "approach": "#c6dbef",
    "outside the tunnel": "#c6dbef",
    "open area": "#c6dbef",
    "in the tunnel": "#c7e9c0",
    "exit": "#fdd0a2",
    "street": "#fdd0a2",
    "straight": "#d9d9d9",
    "curve": "#dadaeb",
    "during the fault": "#fcbba1",
}


def _time_origin(drive: Drive) -> float:
    """Times are drawn from the drive's start on recorded drives (their clocks are Unix seconds or a
    logger's); a simulated drive's clock starts at 0."""
    return 0.0 if "scenario" in drive.params else float(drive.start_s)


def _time_label(t0: float) -> str:
    return "time from the drive's start [s]" if t0 else "time [s]"


def _shade_windows(ax, drive: Drive, t0: float = 0.0) -> None:
    """Shade the labelled intervals: where the vehicle is (``in_tunnel``, ``zone:*``) over the full height,
    the rest (``straight``, ``curve``, ``fault:*`` ...) as a strip along the top, each under its display
    name (:func:`eval.names.span_name`). Windows with the same bounds share one colour and one legend
    entry (``in_tunnel`` and ``zone:tunnel`` are one: "in the tunnel")."""
    cmap = plt.get_cmap("Pastel2")
    tunnel = next(((w.start_s, w.end_s) for w in drive.windows if w.label == "in_tunnel"), None)
    spans: dict[tuple[float, float, bool], list[str]] = {}
    for w in drive.windows:
        full = w.label == "in_tunnel" or w.label.startswith("zone:")
        labels = spans.setdefault((w.start_s, w.end_s, full), [])
        name = span_name(w.label, w.start_s, tunnel)
        if name not in labels:
            labels.append(name)
    legend: dict[str, int] = {}
    for (start, end, full), labels in spans.items():
        name = " / ".join(labels)
        first = name not in legend
        index = legend.setdefault(name, len(legend))
        colour = next((c for key, c in _WINDOW_COLORS.items() if name.startswith(key)), cmap(index % 8))
        ymin, alpha = (0.0, 0.35) if full else (0.94, 0.9)
        ax.axvspan(start - t0, end - t0, ymin=ymin, ymax=1.0, color=colour, alpha=alpha, lw=0, label=name if first else None)


def error_vs_time(drive: Drive, estimates: list[Estimate], path: Path) -> Path:
    """Euclidean position error against time, labelled windows shaded."""
    fig, ax = plt.subplots(figsize=(11, 4))
    t0 = _time_origin(drive)
    _shade_windows(ax, drive, t0)
    high = []
    for est in estimates:
        s = error_series(drive, est)
        ax.plot(s["t_s"] - t0, s["error_m"], lw=1.0, color=color_of(est.name), label=est.name)
        err = s["error_m"][np.isfinite(s["error_m"])]
        if err.size:
            high.append((float(np.percentile(err, 99)), float(err.max())))
    title = f"{drive.name}: position error"
    if high:
        # one estimator far off (an RSS filter on UWB data) must not flatten the others: clip the axis
        top = 3.0 * float(np.median([h[0] for h in high]))
        peak = max(h[1] for h in high)
        if 0 < top < peak:
            ax.set_ylim(0, top)
            title += f" (axis clipped at {top:.1f} m; largest {peak:.1f} m)"
    ax.set_ylim(bottom=0)
    _label_axes(ax, _time_label(t0), "position error [m]", title)
    return _save(fig, path)


def error_cdf(drive: Drive, estimates: list[Estimate], path: Path) -> Path:
    """Empirical CDF of the Euclidean position error."""
    fig, ax = plt.subplots(figsize=(6, 4))
    for est in estimates:
        err = np.sort(error_series(drive, est)["error_m"])
        err = err[np.isfinite(err)]
        if err.size:
            ax.step(err, np.arange(1, err.size + 1) / err.size, where="post", color=color_of(est.name), label=est.name)
    ax.set_ylim(0, 1)
    _label_axes(ax, "position error [m]", "fraction of epochs", f"{drive.name}: error CDF")
    return _save(fig, path)


def speed_error(drive: Drive, estimates: list[Estimate], path: Path) -> Path | None:
    """Speed error of the estimators that give a velocity, beside the raw wheel speed (song2016 Fig. 16)."""
    with_velocity = [e for e in estimates if e.has_velocity]
    wheel_t, wheel_err = wheel_speed_error(drive)
    if not with_velocity and not wheel_err.size:
        return None
    fig, ax = plt.subplots(figsize=(11, 4))
    t0 = _time_origin(drive)
    if wheel_err.size:
        ax.plot(wheel_t - t0, wheel_err, color="0.6", lw=0.6, label="raw wheel speed")
    for est in with_velocity:
        s = error_series(drive, est)
        ax.plot(s["t_s"] - t0, s["speed_error_mps"], lw=1.0, color=color_of(est.name), label=est.name)
    _label_axes(ax, _time_label(t0), "speed error [m/s]", f"{drive.name}: speed error against truth")
    return _save(fig, path)


def cost_accuracy(points: dict[str, list[tuple[float, float, float]]], path: Path, title: str,
                  baseline_m: float | None = None, bounds: dict[str, list[tuple[float, float]]] | None = None) -> Path:
    """RMS error (with spread bars) against number of tags, one line per estimator.

    ``points``: estimator -> [(n_tags, mean RMS, STD of RMS over seeds)]; ``baseline_m``: the RMS
    without tags (dead reckoning), drawn as a horizontal line; ``bounds``: bound kind (``smoother``,
    ``filtering``) -> [(n_tags, mean over seeds of the bound's RMS)], drawn in the truth's colour.
    """
    fig, ax = plt.subplots(figsize=(7, 4.5))
    if baseline_m is not None:
        ax.axhline(baseline_m, color="0.4", ls=":", label="no tags (dead reckoning)")
    for kind, pts in (bounds or {}).items():
        pts = sorted(p for p in pts if np.isfinite(p[1]))
        if pts:
            n, m = (np.array(v) for v in zip(*pts))
            ax.plot(n, m, color=TRUTH_COLOR, ls=_BOUND_STYLES[kind], marker=".", label=f"bound ({kind})")
    for name, pts in points.items():
        pts = sorted(p for p in pts if np.isfinite(p[1]))
        if not pts:
            continue
        n, m, s = (np.array(v) for v in zip(*pts))
        ax.errorbar(n, m, yerr=s, marker="o", capsize=3, color=color_of(name), label=name)
    ax.set_ylim(bottom=0)
    _label_axes(ax, "number of tags", "RMS position error in tunnel [m]", title)
    return _save(fig, path)


#: Line styles of the position bounds (drawn in the truth's colour: they are of the drive, not of an estimator).
_BOUND_STYLES = {"smoother": "--", "filtering": ":"}


def bound_vs_time(drive: Drive, estimates: list[Estimate], bound, path: Path) -> Path:
    """The position bound along the drive (sqrt(trace) of the smoother and filtering bounds,
    :class:`graphpos.bound.Bound`) beside each estimator's Euclidean position error, on a log axis (the
    bound is centimetres where the errors are metres), labelled windows shaded."""
    fig, ax = plt.subplots(figsize=(11, 4))
    t0 = _time_origin(drive)
    _shade_windows(ax, drive, t0)
    for est in estimates:
        s = error_series(drive, est)
        err = np.where(s["error_m"] > 0, s["error_m"], np.nan)  # a zero error has no place on a log axis
        ax.plot(s["t_s"] - t0, err, lw=0.8, alpha=0.8, color=color_of(est.name), label=est.name)
    for kind, style in _BOUND_STYLES.items():
        ax.plot(bound.t_s - t0, bound.sqrt_trace(kind), color=TRUTH_COLOR, lw=1.6, ls=style,
                label=f"bound ({kind}), sqrt trace")
    ax.set_yscale("log")
    _label_axes(ax, _time_label(t0), "position error / bound [m]",
                f"{drive.name}: position error against the Cramer-Rao bound")
    return _save(fig, path)


def plan_bounds(curves: list, simulated_m: list[float], path: Path, kind: str, target_m: float | None, title: str,
                tunnel_length_m: float) -> Path:
    """``plan-layout``'s figure: above, sqrt(trace) of the position bound along the tunnel for the chosen
    layout (first of ``curves``, :class:`graphpos.plan.BoundEvaluation`) and its rivals, each layout's
    simulated error in the tunnel (``simulated_m``, dashed, same colour) and the target; below, the chosen
    layout's tags on the two walls."""
    from graphpos.sim.infrastructure import family_offsets

    fig, (ax, walls) = plt.subplots(2, 1, figsize=(11, 5.5), sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    palette = plt.get_cmap("tab10")
    for i, (ev, sim) in enumerate(zip(curves, simulated_m)):
        role = "chosen" if i == 0 else f"rival {i}"
        ax.plot(ev.distance_m, ev.sqrt_trace_m, lw=2.0 if i == 0 else 1.2, color=palette(i),
                label=f"{role}: {ev.candidate.label} ({ev.n_tags} tags), bound")
        if np.isfinite(sim):
            ax.axhline(sim, color=palette(i), ls="--", lw=1.0, label=f"{role}: simulated, {sim:.2f} m")
    if target_m is not None:
        ax.axhline(target_m, color="0.2", ls=":", lw=1.5, label=f"target {target_m:g} m")
    ax.set_ylim(bottom=0)
    _label_axes(ax, "", "position error / bound [m]", title)
    s, side = family_offsets(curves[0].candidate.tags(), tunnel_length_m)
    walls.scatter(s, side, marker="s", color=palette(0), s=18)
    walls.set_yticks([-1, 1], ["right wall", "left wall"])
    walls.set_ylim(-1.8, 1.8)
    walls.set_xlabel("distance from the entry portal [m]")
    return _save(fig, path)
