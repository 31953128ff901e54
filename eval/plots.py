"""PNG figures of the reports (matplotlib, Agg back-end: no display needed).

Each estimator is drawn in its colour of :func:`graphpos.colors.color_of`,
the same in every figure, KML export and Foxglove map, whichever estimators
a figure shows.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from eval.metrics import error_series, wheel_speed_error  # noqa: E402
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


def _label_axes(ax, xlabel: str, ylabel: str, title: str, ncol: int = 1) -> None:
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.legend(fontsize=8, ncol=ncol)
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


def trajectories(drive: Drive, estimates: list[Estimate], path: Path, layout: str | None = None) -> Path:
    """Truth and estimates over the tunnel walls and tags (the heard layout filled)."""
    fig, ax = plt.subplots(figsize=(10, 5))
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
    ax.legend(fontsize=8, loc="best")
    ax.set_title(f"{drive.name}: trajectories")
    ax.grid(alpha=0.3)
    return _save(fig, path)


def _shade_windows(ax, drive: Drive) -> None:
    """Shade the labelled intervals: where the vehicle is (``in_tunnel``, ``zone:*``) over the full height,
    the rest (``straight``, ``curve``, ``fault:*`` ...) as a strip along the top. Windows with the same
    bounds share one colour and one legend entry."""
    cmap = plt.get_cmap("Pastel1")
    spans: dict[tuple[float, float, bool], list[str]] = {}
    for w in drive.windows:
        full = w.label == "in_tunnel" or w.label.startswith("zone:")
        labels = spans.setdefault((w.start_s, w.end_s, full), [])
        if w.label not in labels:
            labels.append(w.label)
    legend: dict[str, int] = {}
    for (start, end, full), labels in spans.items():
        name = " = ".join(labels)
        first = name not in legend
        colour = cmap(legend.setdefault(name, len(legend)) % 9)
        ymin, alpha = (0.0, 0.35) if full else (0.94, 0.9)
        ax.axvspan(start, end, ymin=ymin, ymax=1.0, color=colour, alpha=alpha, lw=0, label=name if first else None)


def error_vs_time(drive: Drive, estimates: list[Estimate], path: Path) -> Path:
    """Euclidean position error against time, labelled windows shaded."""
    fig, ax = plt.subplots(figsize=(10, 4))
    _shade_windows(ax, drive)
    for est in estimates:
        s = error_series(drive, est)
        ax.plot(s["t_s"], s["error_m"], lw=1.0, color=color_of(est.name), label=est.name)
    ax.set_ylim(bottom=0)
    _label_axes(ax, "time [s]", "position error [m]", f"{drive.name}: position error", ncol=2)
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
    fig, ax = plt.subplots(figsize=(10, 4))
    if wheel_err.size:
        ax.plot(wheel_t, wheel_err, color="0.6", lw=0.6, label="raw wheel speed")
    for est in with_velocity:
        s = error_series(drive, est)
        ax.plot(s["t_s"], s["speed_error_mps"], lw=1.0, color=color_of(est.name), label=est.name)
    _label_axes(ax, "time [s]", "speed error [m/s]", f"{drive.name}: speed error against truth", ncol=2)
    return _save(fig, path)


def cost_accuracy(points: dict[str, list[tuple[float, float, float]]], path: Path, title: str,
                  baseline_m: float | None = None) -> Path:
    """RMS error (with spread bars) against number of tags, one line per estimator.

    ``points``: estimator -> [(n_tags, mean RMS, STD of RMS over seeds)]; ``baseline_m``: the RMS
    without tags (dead reckoning), drawn as a horizontal line.
    """
    fig, ax = plt.subplots(figsize=(7, 4.5))
    if baseline_m is not None:
        ax.axhline(baseline_m, color="0.4", ls=":", label="no tags (dead reckoning)")
    for name, pts in points.items():
        pts = sorted(p for p in pts if np.isfinite(p[1]))
        if not pts:
            continue
        n, m, s = (np.array(v) for v in zip(*pts))
        ax.errorbar(n, m, yerr=s, marker="o", capsize=3, color=color_of(name), label=name)
    ax.set_ylim(bottom=0)
    _label_axes(ax, "number of tags", "RMS position error in tunnel [m]", title)
    return _save(fig, path)

