"""The round benchmark (issue 20): faces x rigs, every figure of the round in one run.

Faces: the demo face and generated faces (:func:`pipeline.plans.faces.generated_face`, seeded) of
about the requested hole counts, each designed for the rig's own drift (trio: the 8 m x 7 m one).
Rigs: any of conf/rig/. Per cell: makespan, lower bound and ratio, naive and nearest, moving and
waiting seconds, planning seconds, smallest boom-boom clearance, waits, fallback, moves not clear.
Every cell uses :func:`pipeline.round.from_plan.schedule_round`, as the stage does.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from pipeline.core.io import write_csv
from pipeline.data.holes import joint_box
from pipeline.geometry.collision import SafetyModel
from pipeline.geometry.rig import Rig
from pipeline.motion.timing import MotionModel
from pipeline.plans.demo_face import demo_face
from pipeline.plans.faces import generated_face
from pipeline.plans.reach import reach_table, rig_solvers
from pipeline.round.from_plan import schedule_round
from pipeline.round.settings import RoundSettings
from pipeline.solvers.hybrid import HybridSettings


@dataclass(frozen=True)
class BenchRig:
    """One rig of the benchmark, built by the stage from the composed config: the rig (its drift, its
    booms), the safety model the faces are designed on (that drift), one motion model per boom."""

    rig: Rig
    safety: SafetyModel
    motions: list[MotionModel]


def round_benchmark(faces: Sequence, rigs: Sequence[BenchRig], hybrid: HybridSettings, settings: RoundSettings,
                    first_start: Callable, seed: int = 0, say=print, trajectories: Path | None = None,
                    box: dict | None = None) -> pd.DataFrame:
    """One row per (face, rig); ``faces``: "demo" or hole counts; ``trajectories``: a folder to write
    each cell's trajectory file into (``<face>_<rig>_trajectory.csv``); ``box``: the reach table's
    joint box (``holes.sup.box``, as the stage passes it: None is the full ranges)."""
    rows = []
    for case in rigs:
        rig, safety, motions, rig_name = case.rig, case.safety, case.motions, case.rig.name
        for face in faces:
            plan = demo_face(safety=safety) if face == "demo" else generated_face(int(face), seed, safety)
            started = time.perf_counter()
            solvers = rig_solvers(rig, first_start, hybrid, joint_box(rig.booms[0].boom, box))
            reach = reach_table(plan, rig, solvers, "hybrid")
            reach_s = time.perf_counter() - started
            res = schedule_round(rig, plan, reach, motions, settings, True, True)
            s = res.summary
            row = {"face": f"demo ({len(plan)})" if face == "demo" else f"gen {face} ({len(plan)})",
                   "rig": rig_name, "holes": len(plan), "drilled": s["holes_drilled"],
                   "makespan_s": s["makespan_s"], "lower_bound_s": s["lower_bound_s"],
                   "ratio": s["makespan_over_bound"], "naive_s": s["naive_makespan_s"],
                   "nearest_s": s["nearest_makespan_s"], "moving_s": s["moving_s"], "waiting_s": s["waiting_s"],
                   "naive_move_wait_s": s["naive_round"]["moving_s"] + s["naive_round"]["waiting_s"],
                   "planning_s": res.timings["planning_s"], "reach_s": reach_s,
                   "min_boom_clearance_m": s["min_boom_clearance_m"] if len(rig) > 1 else float("nan"),
                   "waits": s["waits_inserted"], "sequential": s["sequential_fallback"],
                   "conflicts_left": s["conflicts_left"],
                   "detours": s["moves"].get("retract", 0) + s["moves"].get("planned", 0),
                   "moves_failed": s["moves"].get("failed", 0), "seed": s.get("seed"), "stopped": s.get("stopped"),
                   "baselines_s": res.timings["baselines_s"]}
            rows.append(row)
            if trajectories is not None:  # for the independent check (scripts/check_round.py)
                tag = "demo" if face == "demo" else f"gen{face}"
                write_csv(res.trajectory, trajectories / f"{tag}_{rig_name}_trajectory.csv")
            say(f"{row['face']} x {rig_name}: makespan {row['makespan_s']:.0f} s, bound {row['lower_bound_s']:.0f} s, "
                f"naive {row['naive_s']:.0f} s, nearest {row['nearest_s']:.0f} s, planned in {row['planning_s']:.1f} s")
    return pd.DataFrame(rows)


def markdown(table: pd.DataFrame) -> str:
    cols = ["face", "rig", "drilled", "makespan_s", "lower_bound_s", "ratio", "naive_s", "nearest_s", "moving_s",
            "waiting_s", "planning_s", "min_boom_clearance_m", "waits", "sequential", "detours", "moves_failed"]
    out = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for _, r in table.iterrows():
        cells = [f"{r[c]:.3f}" if c in ("ratio", "min_boom_clearance_m") else
                 f"{r[c]:.0f}" if isinstance(r[c], float) and c != "planning_s" else
                 f"{r[c]:.1f}" if c == "planning_s" else str(r[c]) for c in cols]
        out.append("| " + " | ".join(cells) + " |")
    return "\n".join(out) + "\n"
