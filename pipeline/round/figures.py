"""Figures of a round: the face by boom and order, the Gantt chart, and the interactive replay.

Matplotlib's object API (no pyplot state, as pipeline/evaluation/plots.py); the replay is a plotly page
with plotly's JavaScript inlined, so it opens offline. Its frames are the trajectory file's rows,
linearly interpolated at ``frames`` instants (the file's own rule between rows).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import torch
from matplotlib.figure import Figure

BOOM_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:purple")
PLOTLY_COLOURS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#9467bd")
PHASE_COLOURS = {"drill": "tab:green", "move": "tab:blue", "wait": "tab:red"}


FACE_XLABEL = "y (m, rig frame), seen from the rig: y decreasing to the right, +y (boom L) on the left"


def face_figure(round_df: pd.DataFrame, collars: np.ndarray, rig, title: str = "") -> Figure:
    """The face (y-z, rig frame): holes coloured by boom, each boom's order drawn from its park."""
    fig = Figure(figsize=(10, 8), layout="constrained")
    ax = fig.add_subplot(1, 1, 1)
    ys, zs = rig.tunnel.profile_polyline()
    ax.plot(ys, zs, color="k", lw=1)
    with torch.inference_mode():
        parks = [m.tool_pose(m.park.to(torch.float64))[0].numpy() for m in rig.booms]
    for b, name in enumerate(rig.names):
        colour = BOOM_COLOURS[b % len(BOOM_COLOURS)]
        rows = round_df[round_df["boom"] == name].sort_values("order")
        idx = rows.index.to_numpy()
        pts = collars[idx]
        path = np.concatenate([parks[b][None], pts, parks[b][None]])
        ax.plot(path[:, 1], path[:, 2], color=colour, lw=0.9, alpha=0.7)
        ax.scatter(pts[:, 1], pts[:, 2], c=colour, s=36, edgecolor="k", lw=0.4, zorder=3,
                   label=f"{name}: {len(rows)} holes")
        for (_, r), p in zip(rows.iterrows(), pts, strict=True):
            ax.annotate(str(r["order"]), (p[1], p[2]), fontsize=6, xytext=(3, 3), textcoords="offset points")
        ax.scatter([parks[b][1]], [parks[b][2]], marker="s", s=50, c=colour, edgecolor="k", zorder=4)
    bad = round_df["status"] != "ok"
    if bad.any():
        pts = collars[np.flatnonzero(bad.to_numpy())]
        ax.scatter(pts[:, 1], pts[:, 2], marker="X", c="tab:red", s=70, zorder=5, label=f"not drilled ({len(pts)})")
    # As the operator sees the face from the rig (looking along +x, z up): +y (boom L) on the left.
    ax.set(aspect="equal", xlabel=FACE_XLABEL, ylabel="z (m)", title=title or f"round of rig '{rig.name}'")
    ax.invert_xaxis()
    ax.legend(loc="upper right", fontsize=8)
    return fig


def gantt_figure(trajectory: pd.DataFrame, booms, title: str = "") -> Figure:
    """Every boom's drilling (collar to retract), moves and waits along time, from the trajectory file."""
    fig = Figure(figsize=(12, 1.2 + 0.8 * len(booms)), layout="constrained")
    ax = fig.add_subplot(1, 1, 1)
    for k, name in enumerate(booms):
        t = trajectory[trajectory["boom"] == name].reset_index(drop=True)
        ev = t["event"].to_numpy()
        ts = t["t"].to_numpy()
        spans = {"drill": [], "move": [], "wait": []}
        for i in range(len(t) - 1):
            kind = {"collar": "drill", "drill": "drill", "retract": "drill", "move": "move", "move_unclear": "move",
                    "wait": "wait"}.get(ev[i])
            if kind:
                spans[kind].append((ts[i], ts[i + 1] - ts[i]))
        for kind, s in spans.items():
            ax.broken_barh(s, (k - 0.35, 0.7), facecolors=PHASE_COLOURS[kind], label=kind if k == 0 else None)
    ax.set_yticks(range(len(booms)), list(booms))
    ax.set(xlabel="t (s)", title=title or "round: drilling, moves and waits per boom")
    ax.legend(loc="upper right", fontsize=8, ncols=3)
    return fig


def _at(trajectory: pd.DataFrame, name: str, joint_names, t: np.ndarray) -> np.ndarray:
    rows = trajectory[trajectory["boom"] == name]
    ts = rows["t"].to_numpy()
    return np.stack([np.interp(t, ts, rows[j].to_numpy()) for j in joint_names], axis=-1)


def _capsule_lines(rig, b: int, q: np.ndarray):
    """x, y, z of every capsule of boom b at joints ``q (n,)`` (NaN between capsules), rig frame."""
    m = rig.booms[b]
    with torch.inference_mode():
        frames = m.frames(torch.as_tensor(q, dtype=torch.float64)[None])[0]
        xs, ys, zs = [], [], []
        for name in m.boom.bodies:
            p0, p1 = (p.numpy() for p in m.boom.capsule_ends(frames, name))
            xs += [p0[0], p1[0], None]
            ys += [p0[1], p1[1], None]
            zs += [p0[2], p1[2], None]
    return xs, ys, zs


def replay_html(trajectory: pd.DataFrame, rig, collars: np.ndarray, frames: int = 120, title: str = "") -> str:
    """An offline HTML page: the tunnel, the plan's collars and every boom's capsules, with a time slider."""
    import plotly.graph_objects as go

    names = rig.booms[0].boom.joint_names
    t_end = float(trajectory["t"].max())
    times = np.linspace(0.0, t_end, max(2, int(frames)))
    q = {m.name: _at(trajectory, m.name, names, times) for m in rig.booms}
    ys, zs = rig.tunnel.profile_polyline()
    x_face = float(np.nanmax(collars[:, 0])) if len(collars) else 6.5
    tunnel = []
    for x in (0.0, x_face):
        tunnel.append(go.Scatter3d(x=np.full(len(ys), x), y=ys, z=zs, mode="lines", line={"color": "grey"},
                                   showlegend=False, hoverinfo="skip"))
    holes = go.Scatter3d(x=collars[:, 0], y=collars[:, 1], z=collars[:, 2], mode="markers",
                         marker={"size": 2, "color": "black"}, name="collars")

    def booms_at(k):
        out = []
        for b, m in enumerate(rig.booms):
            x, y, z = _capsule_lines(rig, b, q[m.name][k])
            out.append(go.Scatter3d(x=x, y=y, z=z, mode="lines", name=f"boom {m.name}",
                                    line={"color": PLOTLY_COLOURS[b % len(PLOTLY_COLOURS)], "width": 8}))
        return out

    static = [*tunnel, holes]
    fig = go.Figure(data=[*static, *booms_at(0)])
    moving = list(range(len(static), len(static) + len(rig)))
    fig.frames = [go.Frame(data=booms_at(k), traces=moving, name=f"{t:.0f}") for k, t in enumerate(times)]
    steps = [{"method": "animate", "label": f"{t:.0f} s",
              "args": [[f"{t:.0f}"], {"mode": "immediate", "frame": {"duration": 0, "redraw": True},
                                       "transition": {"duration": 0}}]} for t in times]
    fig.update_layout(
        title=title or f"round of rig '{rig.name}': replay",
        scene={"aspectmode": "data", "xaxis_title": "x (m)", "yaxis_title": "y (m)", "zaxis_title": "z (m)",
               # from behind the rig, z up: +y (boom L) on the left, as the face figure and the operator see it
               "camera": {"eye": {"x": -1.6, "y": 0.9, "z": 0.7}, "up": {"x": 0, "y": 0, "z": 1}}},
        sliders=[{"active": 0, "steps": steps, "currentvalue": {"prefix": "t = "}}],
        updatemenus=[{"type": "buttons", "showactive": False, "buttons": [
            {"label": "play", "method": "animate",
             "args": [None, {"frame": {"duration": 80, "redraw": True}, "fromcurrent": True}]},
            {"label": "pause", "method": "animate",
             "args": [[None], {"mode": "immediate", "frame": {"duration": 0, "redraw": False}}]}]}],
        margin={"l": 0, "r": 0, "t": 40, "b": 0},
    )
    # a fixed div id: plotly draws a random one per call, and the page must reproduce byte for byte
    return fig.to_html(include_plotlyjs=True, full_html=True, auto_play=False, div_id="round-replay")
