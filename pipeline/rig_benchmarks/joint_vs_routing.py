"""The joint CP-SAT model against today's planner, at equal wall time ("Measure, then choose").

Per face: the reach table and today's planner as the stage runs it
(:func:`pipeline.round.from_plan.schedule_round`, counts: its planning wall time is T); then the joint
model (:mod:`pipeline.rig_benchmarks.joint_cpsat`) on the same reach table with straight move times and the
oracle's standing conflicts, hinted with the better sweep, given ``factor * T`` seconds of wall time
(model building included); its routes are timed by the planner's own timeline with the planner's move
book (:func:`pipeline.round.planner.timed_routes`: every move certified, a detour where the straight line
breaks self or tunnel clearance, waits for every boom-boom conflict), and that makespan is compared.
docs/benchmarks.md, "Joint CP-SAT model against the routing".
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

import numpy as np
import pandas as pd

from pipeline.plans.demo_face import demo_face
from pipeline.plans.faces import generated_face
from pipeline.plans.reach import solved_reach
from pipeline.rig_benchmarks.joint_cpsat import JointSettings, hint_timeline, joint_round, standing_conflicts
from pipeline.round.from_plan import round_instance, schedule_round
from pipeline.round.planner import SEEDS, seed_routes, timed_routes
from pipeline.round.settings import RoundSettings
from pipeline.round.timeline import scan, simulate
from pipeline.solvers.hybrid import HybridSettings


def joint_vs_routing(faces: Sequence, case, hybrid: HybridSettings, settings: RoundSettings, first_start: Callable,
                     factors: Sequence[float] = (1.0, 2.0), seed: int = 0, box: dict | None = None,
                     random_seed: int = 0, say=print, done: Callable | None = None) -> pd.DataFrame:
    """One row per (face, wall-time factor); ``case``: a :class:`pipeline.rig_benchmarks.round_faces.BenchRig`;
    ``faces``: "demo" or hole counts (:func:`pipeline.plans.faces.generated_face` with ``seed``);
    ``done``: called with the table so far after each row (a long run keeps what it measured)."""
    rig, rows = case.rig, []
    for face in faces:
        plan = demo_face(safety=case.safety) if face == "demo" else generated_face(int(face), seed, case.safety)
        name = f"demo ({len(plan)})" if face == "demo" else f"gen {face} ({len(plan)})"
        _, reach = solved_reach(plan, rig, first_start, hybrid, box, "hybrid")
        res = schedule_round(rig, plan, reach, case.motions, settings, True, True, say)
        s, T = res.summary, res.timings["planning_s"]
        say(f"{name} x {rig.name}: planner {s['makespan_s']:.1f} s (bound {s['lower_bound_s']:.1f} s) in {T:.1f} s")
        straight, _, _ = round_instance(rig, plan, reach, case.motions, settings)  # straight moves, as the model sees
        conflicts = standing_conflicts(res.oracle, straight.reach)
        hints = {kind: hint_timeline(straight, seed_routes(straight, kind, settings.sweep_band_m), conflicts)
                 for kind in SEEDS}
        hint = min(hints, key=lambda k: hints[k].makespan)  # the better sweep in the model's own terms
        base = {"face": name, "rig": rig.name, "holes": len(plan), "drilled": s["holes_drilled"],
                "planner_s": s["makespan_s"], "bound_s": s["lower_bound_s"], "planner_ratio": s["makespan_over_bound"],
                "planning_s": T, "planner_seed": s.get("seed"), "kept_seed": s.get("kept_seed"),
                "hint": hint, "hint_model_s": hints[hint].makespan, "reopt_rounds": settings.reopt_rounds,
                "stopped": s.get("stopped")}
        for factor in factors:
            started = time.perf_counter()
            jr = joint_round(straight, conflicts, JointSettings(max_deterministic_time=None,
                                                                max_time_in_seconds=factor * T,
                                                                random_seed=random_seed), hints[hint].routes)
            solve_s = time.perf_counter() - started
            row = {**base, "factor": factor, "cpsat_s": jr.makespan_s, "cpsat_bound_s": jr.bound_s,
                   "status": jr.status, "cpsat_wall_s": solve_s, "deterministic_time": jr.deterministic_time,
                   "pairs": jr.pairs, "arcs": jr.arcs}
            if jr.routes is not None:
                t1 = time.perf_counter()
                tl = timed_routes(res.inst, res.oracle, settings, res.plan.book, jr.routes)
                row.update({"timed_s": tl.makespan, "timed_ratio": tl.makespan / s["lower_bound_s"],
                            "waits": len(tl.repairs), "sequential": tl.sequential,
                            "conflicts_left": tl.conflicts_left, "timing_s": time.perf_counter() - t1})
                own = own_timing(res.plan.book.apply(res.inst) if res.plan.book is not None else res.inst,
                                 straight, jr, res.oracle)
                row.update({"own_timing_s": own.makespan, "own_timing_conflicts": own.conflicts_left})
            rows.append(row)
            if done is not None:
                done(pd.DataFrame(rows))
            say(f"{name} x {rig.name}, CP-SAT {factor:g} T: objective {jr.makespan_s} s, bound {jr.bound_s:.1f} s, "
                f"{jr.status}, timed {row.get('timed_s', float('nan')):.1f} s in {solve_s:.1f} s")
    return pd.DataFrame(rows)


def own_timing(inst, straight, jr, oracle):
    """The model's own timing of its routes, checked: every move starts no earlier than the model has it
    (its waits kept; a detour longer than the straight move pushes what follows), then every pair of
    segments scanned by the oracle; ``conflicts_left`` counts the conflicts no wait resolved (during
    moves: the model knows standing conflicts only). A diagnostic, not a round."""
    nb = []
    for b, r in enumerate(jr.routes):
        first = [jr.start_s[r[0]] - straight.move_s[b, straight.starts[b], r[0]]] if r else []
        nb.append(np.array([*first, *jr.leave_s[r]] if r else [0.0]))
    tl = simulate(inst, jr.routes, nb)
    _, tl.conflicts_left, tl.min_clearance = scan(tl, oracle, full=True)
    return tl


def markdown(table: pd.DataFrame) -> str:
    cols = ["face", "holes", "planner_s", "bound_s", "planner_ratio", "planning_s", "factor", "cpsat_s",
            "cpsat_bound_s", "status", "timed_s", "timed_ratio", "cpsat_wall_s", "deterministic_time", "waits",
            "sequential"]
    out = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for _, r in table.iterrows():
        cells = [f"{r[c]:.3f}" if c.endswith("ratio") and pd.notna(r.get(c)) else
                 f"{r[c]:.1f}" if isinstance(r.get(c), float) and pd.notna(r.get(c)) else str(r.get(c, ""))
                 for c in cols]
        out.append("| " + " | ".join(cells) + " |")
    return "\n".join(out) + "\n"
