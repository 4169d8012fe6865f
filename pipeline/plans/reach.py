"""The reach table of a rig: every hole of a plan solved by every boom, each with its status and joints.

One hybrid solver per boom (:func:`rig_solvers`), in the rig frame: the boom's ``base`` moves its frames
there, so its tunnel clearances are seen from its base and the plan (given in the rig frame) is its
target; its joints stay in its own base frame. While one boom is solved every other boom stands at its
park configuration, as an obstacle (boom-boom clearance rows in the LM, and in the ok rule): the reach
table says which boom *can* drill a hole, not in which order (the round planner decides that).

:func:`solved_reach` is the one way a product stage or benchmark builds it: the solvers from a first
start and the working box, then the table. The table (:func:`reach_table`) has one row per hole and
boom, hole-major in the plan's order and the rig's boom order, with a ``boom`` column (the rig config's
names) beside the solution columns and ``clearance_boom_m`` (the nearest standing boom, less d_boom).
Rows the plan reader could not use are kept once per boom with status ``invalid``. :func:`reach_figure`
draws the face: which boom or booms can drill each hole (ok), and the holes no boom can drill with
every boom's status.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd
import torch
from matplotlib.figure import Figure

from pipeline.data.holes import joint_box
from pipeline.geometry.boom_pair import BoomPair
from pipeline.geometry.kinematics import Boom
from pipeline.geometry.rig import Rig
from pipeline.plans.model import COLLAR, DrillPlan
from pipeline.plans.solutions import CLEARANCE_COLUMNS, INVALID, solution_frame, solved_holes, status_counts
from pipeline.solvers.base import HoleTargets, Solver, SolveResult
from pipeline.solvers.hybrid import BoomObstacle, HybridSettings, HybridSolver

BOOM_CLEARANCE = "clearance_boom_m"


def rig_solvers(rig: Rig, init_for: Callable[[Boom], Solver | None], settings: HybridSettings,
                start_box: tuple[torch.Tensor, torch.Tensor] | None = None) -> list[HybridSolver]:
    """A hybrid solver per boom of ``rig`` at its base; ``init_for(boom)`` gives its first start (a network)."""
    return [HybridSolver(m.boom, m.safety, init_for(m.boom), settings, f"hybrid[{m.name}]", start_box, base=m.base)
            for m in rig.booms]


def parked_others(rig: Rig, index: int) -> list[BoomObstacle]:
    """Every boom of ``rig`` but ``index``, standing at its park, as obstacles of boom ``index``."""
    me = rig.booms[index]
    return [BoomObstacle(BoomPair(me.boom, b.boom, rig.d_boom), b.frames(b.park), b.name)
            for j, b in enumerate(rig.booms) if j != index]


@dataclass
class Reach:
    """The reach table and each boom's solve result (joints ``(holes, n)``, own base frame)."""

    table: pd.DataFrame
    results: dict[str, SolveResult]

    def summary(self) -> dict:
        """Counts per boom, holes ok by at least one boom and by none, solve time."""
        t = self.table[self.table["status"] != INVALID]
        ok_by = t[t["status"] == "ok"].groupby("hole_id", sort=False)["boom"].apply(list)
        holes = t["hole_id"].drop_duplicates()
        nobody = [h for h in holes if h not in ok_by.index]
        out = {"holes": int(len(holes)), "ok_by_any": int(len(holes) - len(nobody)), "ok_by_none": len(nobody),
               "ok_by_every": int(sum(len(v) == len(self.results) for v in ok_by)),
               "solve_s": float(sum(r.wall_s for r in self.results.values()))}
        for name in self.results:
            out.update({f"{name}.{k}": v for k, v in status_counts(self.table[self.table["boom"] == name]).items()})
        out["holes_ok_by_none"] = nobody
        return out

    def ok_by(self) -> dict[str, list[str]]:
        """hole_id -> the booms that can drill it (ok), in the rig's order; ``[]`` when none can."""
        t = self.table[self.table["status"] != INVALID]
        return {h: list(g.loc[g["status"] == "ok", "boom"]) for h, g in t.groupby("hole_id", sort=False)}


def reach_table(plan: DrillPlan, rig: Rig, solvers: list[HybridSolver], method: str) -> Reach:
    """Solve every hole of ``plan`` (rig frame) by every boom, the others standing at park."""
    tables, results = [], {}
    for i, (mount, solver) in enumerate(zip(rig.booms, solvers, strict=True)):
        targets = HoleTargets(plan.poses(mount.boom.preview_depth), mount.boom.preview_depth)
        result = solver.solve(targets, obstacles=parked_others(rig, i))
        results[mount.name] = result
        t = solution_frame(plan, result, mount.boom.joint_names, method, solved_holes(plan, *mount.tool_pose(result.q)))
        t.insert(1, "boom", mount.name)
        boom_c = result.clearances["boom"].detach().cpu().numpy() if "boom" in result.clearances else np.inf
        solved = t["status"] != INVALID
        t.insert(t.columns.get_loc(CLEARANCE_COLUMNS[-1]) + 1, BOOM_CLEARANCE, np.nan)
        t.loc[solved, BOOM_CLEARANCE] = boom_c
        t["_order"] = np.arange(len(t)) * len(rig) + i  # hole-major, then the rig's boom order
        tables.append(t)
    table = pd.concat(tables, ignore_index=True).sort_values("_order", kind="stable").drop(columns="_order")
    return Reach(table.reset_index(drop=True), results)


def solved_reach(plan: DrillPlan, rig: Rig, first_start: Callable[[Boom], Solver | None], settings: HybridSettings,
                 box: Mapping | None, method: str) -> tuple[list[HybridSolver], Reach]:
    """Each boom's hybrid solver and the reach table of ``plan``: ``first_start(boom)`` gives a boom's first
    start (:func:`pipeline.solvers.network_start.first_starts`), ``box`` the working box its other starts
    are drawn in (``holes.sup.box``, per joint; None: the full ranges); ``method`` names it in the table."""
    solvers = rig_solvers(rig, first_start, settings, joint_box(rig.booms[0].boom, box))
    return solvers, reach_table(plan, rig, solvers, method)


CATEGORY_STYLE = {"none": ("tab:red", "x")}
BOOM_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:purple")


def reach_figure(reach: Reach, plan: DrillPlan, rig: Rig) -> Figure:
    """The face (y-z, rig frame) with each hole marked by the boom or booms that can drill it (ok), the
    booms' bases, and each hole no boom can drill labelled with every boom's status."""
    ok_by = reach.ok_by()
    collars = plan.holes[COLLAR].to_numpy()
    ids = plan.holes["hole_id"].tolist()
    fig = Figure(figsize=(11, 8), layout="constrained")
    ax = fig.add_subplot(1, 1, 1)
    ys, zs = rig.tunnel.profile_polyline()
    ax.plot(ys, zs, color="k", lw=1)
    groups: dict[str, list[int]] = {}
    for k, h in enumerate(ids):
        booms = ok_by.get(h, [])
        groups.setdefault(" + ".join(booms) if booms else "none", []).append(k)
    colours = dict(zip(rig.names, BOOM_COLOURS, strict=False))
    for label, ks in sorted(groups.items(), key=lambda kv: (kv[0] == "none", -len(kv[0]), kv[0])):
        pts = collars[ks]
        if label == "none":
            ax.scatter(pts[:, 1], pts[:, 2], c="tab:red", marker="X", s=70, zorder=4, label=f"no boom ({len(ks)})")
            continue
        booms = label.split(" + ")
        if len(booms) == 1:
            ax.scatter(pts[:, 1], pts[:, 2], c=colours[booms[0]], s=40, edgecolor="k", lw=0.4, zorder=3,
                       label=f"{label} only ({len(ks)})")
        else:  # a ring per extra boom around the first boom's dot
            ax.scatter(pts[:, 1], pts[:, 2], c=colours[booms[0]], s=40, edgecolor="k", lw=0.4, zorder=3,
                       label=f"{label} ({len(ks)})")
            for r, b in enumerate(booms[1:], start=1):
                ax.scatter(pts[:, 1], pts[:, 2], facecolors="none", edgecolors=colours[b], s=40 + 70 * r, lw=1.6,
                           zorder=2)
    status = reach.table.set_index(["hole_id", "boom"])["status"]
    for k in groups.get("none", []):
        text = ", ".join(f"{b} {status.get((ids[k], b), '?')}" for b in rig.names)
        ax.annotate(f"{ids[k]}: {text}", (collars[k, 1], collars[k, 2]), fontsize=7, xytext=(5, 4),
                    textcoords="offset points")
    for m in rig.booms:
        ax.scatter([m.base[1]], [m.base[2]], marker="s", s=60, c=colours[m.name], edgecolor="k", zorder=5)
        ax.annotate(f"base {m.name}", (m.base[1], m.base[2]), fontsize=8, xytext=(4, -12), textcoords="offset points")
    s = reach.summary()
    ax.set_title(f"rig '{rig.name}': which boom can drill each hole (ok, the other booms at park); "
                 f"{s['ok_by_any']} of {s['holes']} holes by at least one boom, {s['ok_by_every']} by every boom")
    ax.set(aspect="equal", xlabel="y (m, rig frame)", ylabel="z (m)")
    ax.legend(loc="upper right", fontsize=8)
    return fig
