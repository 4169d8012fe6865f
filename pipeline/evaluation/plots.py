"""Figures of training, evaluation, benchmarks and sweeps (paper 000 Figs. 9-11), drawn with matplotlib.

Figures are made with matplotlib's object API (``Figure``), not pyplot: no backend is chosen, no
process-wide state is touched, and a figure is freed like any object once saved or logged.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from pipeline.geometry.collision import SAFETY_KINDS
from pipeline.geometry.tunnel import Horseshoe


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


def face_projection(projections: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]], tunnel: Horseshoe):
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
