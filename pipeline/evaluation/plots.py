"""Figures of training, evaluation, benchmarks and sweeps (paper 000 Figs. 9-11), drawn with matplotlib.

Figures are made with matplotlib's object API (``Figure``), not pyplot: no backend is chosen, no
process-wide state is touched, and a figure is freed like any object once saved or logged.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from pipeline.geometry.collision import SAFETY_KINDS
from pipeline.geometry.tunnel import Tunnel


def figure(nrows: int = 1, ncols: int = 1, **kwargs):
    """A new figure and its axes (``squeeze`` as in pyplot's ``subplots``)."""
    fig = Figure(**{k: v for k, v in kwargs.items() if k in ("figsize", "layout")})
    axes = fig.subplots(nrows, ncols, **{k: v for k, v in kwargs.items() if k not in ("figsize", "layout")})
    return fig, axes


def training_curves(histories: dict[str, pd.DataFrame]):
    """Held-out start and preview error against training step (Fig. 9)."""
    fig, axes = figure(1, 2, figsize=(10, 4), sharey=True)
    for ax, col, title in zip(axes, ["val_start_mm", "val_preview_mm"], ["start point", "preview point"], strict=True):
        for method, hist in histories.items():
            ax.plot(hist["step"], hist[col], label=method)
        ax.set_yscale("log")
        ax.set_xlabel("training step")
        ax.set_title(f"held-out {title} error")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("error (mm)")
    axes[0].legend()
    fig.tight_layout()
    return fig


def face_projection(projections: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]], tunnel: Tunnel):
    """Collars on the face (y, z) coloured by hole-seeking error, one panel per method (Fig. 10).

    Each panel has its own colour scale, capped at its p95, since the methods' errors can
    differ by orders of magnitude."""
    n = len(projections)
    fig, axes = figure(1, n, figsize=(4.6 * n, 4.4), squeeze=False)
    ys, zs = tunnel.profile_polyline()
    for ax, (method, (y, z, err)) in zip(axes[0], projections.items(), strict=True):
        ax.plot(ys, zs, color="k", lw=1)
        vmax = float(np.percentile(err, 95)) if err.size else 1.0
        sc = ax.scatter(y, z, c=err, s=4, cmap="viridis", vmin=0, vmax=vmax)
        ax.set_title(f"{method}: mean {np.mean(err):.1f} mm")
        ax.set_aspect("equal")
        ax.set_xlabel("y (m)")
        fig.colorbar(sc, ax=ax, shrink=0.8, label="hole-seeking error (mm, capped at p95)")
    axes[0][0].set_ylabel("z (m)")
    return fig


def method_comparison(metrics: dict[str, dict[str, float]]):
    """Mean / p95 hole-seeking error and collision counts per method (Fig. 11a, Table 3)."""
    methods = list(metrics)
    x = np.arange(len(methods))
    fig, (ax1, ax2) = figure(1, 2, figsize=(10, 4))
    ax1.bar(x - 0.2, [metrics[m]["hole_mm_mean"] for m in methods], 0.4, label="mean")
    ax1.bar(x + 0.2, [metrics[m]["hole_mm_p95"] for m in methods], 0.4, label="p95")
    ax1.set_yscale("log")
    ax1.set_xticks(x, methods)
    ax1.set_ylabel("hole-seeking error (mm)")
    ax1.legend()
    bottom = np.zeros(len(methods))
    for kind in SAFETY_KINDS:
        counts = np.array([metrics[m][f"collisions_{kind}"] for m in methods], dtype=float)
        ax2.bar(x, counts, 0.6, bottom=bottom, label=kind)
        bottom += counts
    ax2.set_xticks(x, methods)
    ax2.set_ylabel("violations over all test groups")
    ax2.legend()
    fig.tight_layout()
    return fig


def error_vs_time(df: pd.DataFrame):
    """Benchmark: mean hole-seeking error against batched time per hole, coloured by collision rate."""
    fig, ax = figure(figsize=(6.5, 4.5))
    sc = ax.scatter(df["batch_ms_per_hole"], df["hole_mm_mean"], c=100 * df["collision_rate_paper"],
                    cmap="viridis_r", s=60, edgecolor="k")
    for r in df.itertuples():
        ax.annotate(r.method, (r.batch_ms_per_hole, r.hole_mm_mean), textcoords="offset points", xytext=(4, 4),
                    fontsize=8)
    ax.set(xscale="log", yscale="log", xlabel="time per hole, batched (ms)", ylabel="mean hole-seeking error (mm)",
           title="IK methods on the same holes (colour: collision rate %)")
    fig.colorbar(sc, ax=ax, label="collision rate (%)")
    fig.tight_layout()
    return fig


def tradeoff_figure(df: pd.DataFrame):
    """Sweep: mean error against collision rate of the finished jobs, Pareto front marked."""
    done = df[df["status"] == "FINISHED"]
    fig, ax = figure(figsize=(6.5, 4.5))
    ax.scatter(done["val_collision_rate"] * 100, done["val_hole_mm"], c="tab:blue", label="job")
    front = done[done["pareto"]].sort_values("val_collision_rate")
    ax.plot(front["val_collision_rate"] * 100, front["val_hole_mm"], "o-", color="tab:red", label="Pareto front")
    for _, row in done.iterrows():
        ax.annotate(row["overrides"], (row["val_collision_rate"] * 100, row["val_hole_mm"]), fontsize=7,
                    xytext=(3, 3), textcoords="offset points")
    failed = len(df) - len(done)
    ax.set_xlabel("collision rate on held-out holes (%)")
    ax.set_ylabel("mean hole-seeking error (mm)")
    ax.set_title("accuracy vs safety" + (f" ({failed} job(s) failed, not shown)" if failed else ""))
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout(pad=1.5)
    return fig



def sweep_front_figure(summary: pd.DataFrame, paper: dict, title: str):
    """A sweep's jobs: mean error against mean collision rate on the test groups, the seeds' sample std as bars,
    the Pareto front joined, and the paper's networks (``{method: {hole_mm_mean, collision_rate_pct}}``) as
    crosses. The collision axis is linear up to 1 % and logarithmic beyond, so 0.05 % and 17 % both read."""
    fig, ax = figure(figsize=(7, 4.8))
    ax.errorbar(summary["collision_rate_pct"], summary["mean_mm"], xerr=summary["collision_rate_pct_std"],
                yerr=summary["mean_mm_std"], fmt="o", color="tab:blue", capsize=3, label="job (mean, seed std)")
    front = summary[summary["pareto"]].sort_values("collision_rate_pct")
    ax.plot(front["collision_rate_pct"], front["mean_mm"], "-", color="tab:red", label="Pareto front")
    for _, row in summary.iterrows():
        ax.annotate(str(row["job"]), (row["collision_rate_pct"], row["mean_mm"]), fontsize=7, xytext=(4, 4),
                    textcoords="offset points")
    for method, figures in paper.items():
        if figures.get("hole_mm_mean") is None:
            continue  # the paper gives no error for it
        ax.plot(figures["collision_rate_pct"], figures["hole_mm_mean"], "x", color="k", ms=8)
        ax.annotate(f"Wu et al. 2024 {method.upper()}", (figures["collision_rate_pct"], figures["hole_mm_mean"]),
                    fontsize=7, xytext=(4, -10), textcoords="offset points")
    ax.set_xscale("symlog", linthresh=1.0)
    ax.set_yscale("log")
    ax.set_xlabel("collision rate on the five test groups (%)")
    ax.set_ylabel("mean hole-seeking error (mm)")
    ax.set_title(title, fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout(pad=1.5)
    return fig

STATUS_COLOURS = {"ok": "tab:green", "inexact": "tab:orange", "unsafe": "tab:red", "unreachable": "tab:purple",
                  "invalid": "tab:gray"}
VIEWS = (("side", 0, 2, "x (m)", "z (m)"), ("top", 0, 1, "x (m)", "y (m)"), ("front", 1, 2, "y (m)", "z (m)"))


def _stadium(a: np.ndarray, b: np.ndarray, r: float, n: int = 16) -> np.ndarray:
    """Outline (2-D) of a capsule's projection: segment a-b widened by r, round ends."""
    d = b - a
    angle = np.arctan2(d[1], d[0]) if np.linalg.norm(d) > 1e-12 else 0.0
    half = np.linspace(-np.pi / 2, np.pi / 2, n)
    end_b = b + r * np.stack([np.cos(angle + half), np.sin(angle + half)], -1)
    end_a = a + r * np.stack([np.cos(angle + np.pi + half), np.sin(angle + np.pi + half)], -1)
    return np.concatenate([end_b, end_a, end_b[:1]])


def _tunnel_outline(ax, view: str, tunnel: Tunnel, safety_wall: float, x_range: tuple[float, float]) -> None:
    if view == "front":
        ys, zs = tunnel.profile_polyline()
        ax.plot(ys, zs, color="k", lw=1)
        return
    lo, hi = x_range
    if view == "side":  # the floor's lowest and the roof's highest point (horseshoe: 0 and the crown)
        for z in tunnel.z_range:
            ax.plot([lo, hi], [z, z], color="k", lw=1)
    else:
        for y in tunnel.y_range:
            ax.plot([lo, hi], [y, y], color="k", lw=1)
            inner = y - np.sign(y) * safety_wall
            ax.plot([lo, hi], [inner, inner], color="k", lw=0.6, ls=":")


def solution_figure(table: pd.DataFrame, collars: np.ndarray, tunnel: Tunnel, boom_views: list[dict],
                    safety_wall: float = 0.5):
    """The face (holes on the profile, coloured by status, error of every hole that is not ok written
    beside it) and, below, the boom's capsules in side, top and front view at each hole of
    ``boom_views`` (``{"hole_id", "status", "title", "capsules": [(name, start, end, radius)]}``)."""
    fig = Figure(figsize=(13, 4.8 + 3.6 * len(boom_views)), layout="constrained")
    grid = fig.add_gridspec(1 + len(boom_views), 3, height_ratios=[1.4] + [1.0] * len(boom_views))
    face = fig.add_subplot(grid[0, :])
    ys, zs = tunnel.profile_polyline()
    face.plot(ys, zs, color="k", lw=1)
    solved = table["status"] != "invalid"
    for status, colour in STATUS_COLOURS.items():
        pick = (table.loc[solved, "status"] == status).to_numpy()
        if pick.any():
            face.scatter(collars[pick, 1], collars[pick, 2], c=colour, s=28, label=f"{status} ({int(pick.sum())})",
                         edgecolor="k", linewidth=0.4, zorder=3)
    for (_, row), (_, y, z) in zip(table[solved].iterrows(), collars, strict=True):
        if row["status"] != "ok":
            face.annotate(f"{row['hole_id']}: {row['hole_mm']:.3g} mm", (y, z), fontsize=7, xytext=(4, 4),
                          textcoords="offset points")
    invalid = int((~solved).sum())
    worst = table.loc[solved, "hole_mm"].max() if solved.any() else float("nan")
    face.set_title(f"drill plan: {int(solved.sum())} holes solved, max hole-seeking error {worst:.3g} mm"
                   + (f", {invalid} invalid row(s) not drawn" if invalid else ""))
    face.set(aspect="equal", xlabel="y (m)", ylabel="z (m)")
    face.legend(loc="upper right", fontsize=8)
    for i, view in enumerate(boom_views):
        pts = np.concatenate([np.stack([s, e]) for _, s, e, _ in view["capsules"]])
        x_range = (min(0.0, pts[:, 0].min()) - 0.5, pts[:, 0].max() + 0.5)
        for j, (name, a, b, xl, yl) in enumerate(VIEWS):
            ax = fig.add_subplot(grid[1 + i, j])
            _tunnel_outline(ax, name, tunnel, safety_wall, x_range)
            for body, start, end, radius in view["capsules"]:
                outline = _stadium(start[[a, b]], end[[a, b]], radius)
                ax.fill(outline[:, 0], outline[:, 1], alpha=0.5, label=body,
                        color="tab:blue" if body == "boom" else "tab:orange")
            ax.set(aspect="equal", xlabel=xl, ylabel=yl, title=f"{view['title']}: {name}")
            if j == 0:
                ax.legend(fontsize=7, loc="upper left")
    return fig


def collar_clouds(sets: dict[str, np.ndarray], tunnel: Tunnel, shares: dict[str, float] | None = None):
    """Paper 000 Fig. 5: the collar points of each hole set, front (y-z, with the profile) and side
    (x-z) projections; ``sets`` maps a name to its ``(n, 6)`` poses."""
    fig, axes = figure(2, len(sets), figsize=(5.2 * len(sets), 8.5), squeeze=False)
    ys, zs = tunnel.profile_polyline()
    for j, (name, pose) in enumerate(sets.items()):
        front, side = axes[0][j], axes[1][j]
        front.plot(ys, zs, color="k", lw=1)
        front.scatter(pose[:, 1], pose[:, 2], s=1, alpha=0.3)
        share = f", {100 * shares[name]:.0f} % in the face window" if shares and name in shares else ""
        front.set(aspect="equal", xlabel="y (m)", ylabel="z (m)", title=f"{name}: collars, front{share}",
                  xlim=(-6, 6), ylim=(-3, 9))
        side.scatter(pose[:, 0], pose[:, 2], s=1, alpha=0.3)
        for z in tunnel.z_range:
            side.axhline(z, color="k", lw=1)
        side.set(xlabel="x (m)", ylabel="z (m)", title=f"{name}: collars, side", xlim=(-2, 10), ylim=(-3, 9))
    fig.tight_layout()
    return fig


def calibration_figure(df: pd.DataFrame):
    """Residual collar and direction error against measurements, per method, one column per level."""
    levels = list(dict.fromkeys(df["level"]))
    fig, axes = figure(2, len(levels), figsize=(5.5 * len(levels), 7.5), squeeze=False)
    for j, level in enumerate(levels):
        sub = df[df["level"] == level]
        for method in dict.fromkeys(sub["method"]):
            m = sub[sub["method"] == method].dropna(subset=["collar_mm_mean"])
            style = {"ls": "--", "color": "k"} if method == "uncompensated" else {"marker": "o"}
            axes[0, j].plot(m["n_measurements"], m["collar_mm_mean"], label=method, **style)
            axes[1, j].plot(m["n_measurements"], m["direction_deg_mean"], label=method, **style)
        axes[0, j].set(title=f"level: {level}", ylabel="mean collar error (mm)")
        axes[1, j].set(xlabel="measured poses", ylabel="mean direction error (deg)")
        for ax in axes[:, j]:
            ax.set(xscale="log", yscale="log")
            ax.grid(True, which="both", alpha=0.3)
    axes[0, 0].legend(fontsize=8)
    fig.suptitle("Residual error on held-out face holes, executed on the true boom")
    fig.tight_layout()
    return fig


def deviation_figure(face: np.ndarray, table: pd.DataFrame, title: str):
    """The face as the plan has it (``face (n, 2)``: across, up) with each hole coloured by how far its drilled
    collar landed from the planned one (mm); holes outside the tolerance ringed in red, holes not drilled as
    grey crosses, each of those two kinds named beside it."""
    fig = Figure(figsize=(9, 7), layout="constrained")
    ax = fig.add_subplot(1, 1, 1)
    drilled = table["collar_dev_m"].notna().to_numpy()
    dev_mm = 1000 * table["collar_dev_m"].to_numpy(float)
    if drilled.any():
        sc = ax.scatter(face[drilled, 0], face[drilled, 1], c=dev_mm[drilled], cmap="viridis", s=45,
                        vmin=0.0, vmax=max(float(np.nanmax(dev_mm[drilled])), 1e-3), edgecolor="k", linewidth=0.3)
        fig.colorbar(sc, ax=ax, shrink=0.8, label="collar deviation (mm)")
    out = drilled & ~table["within"].to_numpy(bool)
    ax.scatter(face[out, 0], face[out, 1], s=140, facecolor="none", edgecolor="tab:red", linewidth=1.2,
               label=f"outside tolerance ({int(out.sum())})")
    missing = ~drilled
    ax.scatter(face[missing, 0], face[missing, 1], marker="x", c="grey", s=45,
               label=f"not drilled ({int(missing.sum())})")
    for k in np.flatnonzero(out | missing):
        ax.annotate(str(table["hole_id"].iloc[k]), face[k], fontsize=7, xytext=(4, 4), textcoords="offset points")
    ax.set(aspect="equal", xlabel="across the face (m, plan frame, seen along the holes)", ylabel="up (m)", title=title)
    ax.legend(loc="upper right", fontsize=8)
    return fig
