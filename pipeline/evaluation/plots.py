"""Figures of training and evaluation (paper 000 Figs. 9-11), drawn with matplotlib."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")  # files only, no display needed

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from pipeline.geometry.collision import KINDS  # noqa: E402
from pipeline.geometry.tunnel import Horseshoe  # noqa: E402


def training_curves(histories: dict[str, pd.DataFrame]):
    """Held-out start and preview error against training step (Fig. 9)."""
    fig, axes = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
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
    fig, axes = plt.subplots(1, n, figsize=(4.6 * n, 4.4), squeeze=False)
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
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4))
    ax1.bar(x - 0.2, [metrics[m]["hole_mm_mean"] for m in methods], 0.4, label="mean")
    ax1.bar(x + 0.2, [metrics[m]["hole_mm_p95"] for m in methods], 0.4, label="p95")
    ax1.set_yscale("log")
    ax1.set_xticks(x, methods)
    ax1.set_ylabel("hole-seeking error (mm)")
    ax1.legend()
    bottom = np.zeros(len(methods))
    for kind in KINDS:
        counts = np.array([metrics[m][f"collisions_{kind}"] for m in methods], dtype=float)
        ax2.bar(x, counts, 0.6, bottom=bottom, label=kind)
        bottom += counts
    ax2.set_xticks(x, methods)
    ax2.set_ylabel("violations over all test groups")
    ax2.legend()
    fig.tight_layout()
    return fig
