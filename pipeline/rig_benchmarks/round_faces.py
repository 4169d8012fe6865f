"""The round benchmark: faces x rigs, every figure of the round in one run.

Faces: the demo face and generated faces (:func:`pipeline.plans.faces.generated_face`, seeded) of
about the requested hole counts, each designed for the rig's own drift (trio: the 8 m x 7 m one).
Rigs: any of conf/rig/. Per cell: makespan, lower bound and ratio, naive and nearest, moving and
waiting seconds, planning seconds, smallest boom-boom clearance, waits, fallback, moves not clear.
Every cell uses :func:`pipeline.round.from_plan.schedule_round`, as the stage does, and (given the
``draws`` settings, as the stage passes them) the round made robust as the stage makes it
(:func:`pipeline.events.robust_round.robust_finish`): the clock-timed plan's makespan, the nominal one with
interlocks (the price of robustness), the interlocks, and the draws' makespan ratios and standing shares.
With a ``trajectories`` folder every cell's set is written there as the stage writes a round (plan, round
table, JSON, trajectory, actions, interlocks, zones), so the independent checker can execute each one.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from pipeline.core.io import write_csv
from pipeline.events.draws import STANDING_CAUSES, DrawSettings
from pipeline.events.robust_round import robust_hooks
from pipeline.events.zone_choice import ZoneSettings
from pipeline.geometry.collision import SafetyModel
from pipeline.geometry.rig import Rig
from pipeline.motion.timing import MotionModel
from pipeline.plans.csv_plan import write_csv_plan
from pipeline.plans.demo_face import demo_face
from pipeline.plans.faces import generated_face
from pipeline.plans.reach import solved_reach
from pipeline.round.from_plan import schedule_round
from pipeline.round.output import round_paths, write_round_set
from pipeline.round.postures import round_postures
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
                    box: dict | None = None, draw_settings: DrawSettings | None = None,
                    zone_settings: ZoneSettings | None = None) -> pd.DataFrame:
    """One row per (face, rig); ``faces``: "demo" or hole counts; ``trajectories``: a folder to write
    each cell's set into (``<face>_<rig>.csv``, the plan, and its ``_round.csv``, ``_round.json``,
    ``_trajectory.csv``, ``_actions.csv``, ``_interlocks.csv``, ``_zones.csv``); ``box``: the reach table's joint box
    (``holes.sup.box``, as the stage passes it: None is the full ranges); ``draw_settings``: the round made
    robust and its draws (module docstring), None for the clock-timed round alone; ``zone_settings``: how
    its zones are chosen (None: the defaults)."""
    rows = []
    for case in rigs:
        rig, safety, motions, rig_name = case.rig, case.safety, case.motions, case.rig.name
        for face in faces:
            plan = demo_face(safety=safety) if face == "demo" else generated_face(int(face), seed, safety)
            started = time.perf_counter()
            solvers, reach = solved_reach(plan, rig, first_start, hybrid, box, "hybrid")
            postures = round_postures(plan, rig, solvers, reach, motions, settings)
            reach_s = time.perf_counter() - started
            finish, choose = ((None, None) if draw_settings is None else
                              robust_hooks(draw_settings, zone_settings, settings.robust_candidates,
                                           settings.robust_slack, settings.robust_min_gain))
            res = schedule_round(rig, plan, reach, motions, settings, True, True, finish=finish, postures=postures,
                                 choose=choose)
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
                   "robust_choice": _choice(s.get("robust_choice")),
                   "baselines_s": res.timings["baselines_s"], "finish_s": res.timings["finish_s"],
                   **_executed(res.finished)}
            rows.append(row)
            if trajectories is not None:  # for the independent check (scripts/check_round.py)
                _write_set(trajectories / f"{'demo' if face == 'demo' else f'gen{face}'}_{rig_name}.csv", plan, res)
            say(f"{row['face']} x {rig_name}: makespan {row['makespan_s']:.0f} s, bound {row['lower_bound_s']:.0f} s, "
                f"naive {row['naive_s']:.0f} s, nearest {row['nearest_s']:.0f} s, planned in {row['planning_s']:.1f} s")
    return pd.DataFrame(rows)


def _choice(record: dict | None) -> str:
    """The benchmark's cell: which of how many candidates the robust choice kept."""
    if not record:
        return "-"
    return f"{record['chosen']} of {len(record['candidates'])}"


def _write_set(plan_file: Path, plan, res) -> None:
    """The cell's plan, then its round's set as the stage publishes one (:func:`write_round_set`: staged,
    the JSON last with each file's MD5), named after the plan."""
    write_csv_plan(plan, plan_file)
    summary = {"plan": str(plan_file.resolve()), **res.summary}
    writers = {"round": lambda p: write_csv(res.round, p), "trajectory": lambda p: write_csv(res.trajectory, p)}
    if res.finished is not None:
        summary["execution"] = res.finished.summary
        writers["actions"] = lambda p: write_csv(res.finished.actions, p)
        writers["interlocks"] = lambda p: write_csv(res.finished.interlocks, p)
        writers["zones"] = lambda p: write_csv(res.finished.zones, p)
    write_round_set(round_paths(plan_file, None), summary, writers)


def _executed(ex) -> dict:
    """The robust round's columns (NaN where the round was not made robust)."""
    nan = float("nan")
    if ex is None:
        return {"plan_makespan_s": nan, "robust_price_pct": nan, "interlocks": nan, "zones": nan, "robust": nan,
                "deadlocks": nan, "exec_p50": nan, "exec_p95": nan, "standing_p95_pct": nan,
                **{f"{c}_p{q}_pct": nan for c in STANDING_CAUSES for q in (50, 95)}}
    s, r = ex.summary, ex.summary["random"] or {}
    return {"plan_makespan_s": s["plan_makespan_s"],
            "robust_price_pct": 100.0 * (s["nominal_makespan_s"] / s["plan_makespan_s"] - 1.0),
            "interlocks": s["interlocks"]["interlocks"], "zones": s["interlocks"].get("zones", 0),
            "robust": bool(s["robust"]), "deadlocks": s["deadlocks"],
            "exec_p50": r.get("makespan_ratio_p50", nan), "exec_p95": r.get("makespan_ratio_p95", nan),
            "standing_p95_pct": 100.0 * r.get("standing_share_p95", nan),
            **{f"{c}_p{q}_pct": 100.0 * r.get(f"{c}_share_p{q}", nan) for c in STANDING_CAUSES for q in (50, 95)}}


def markdown(table: pd.DataFrame) -> str:
    cols = ["face", "rig", "drilled", "makespan_s", "lower_bound_s", "ratio", "naive_s", "nearest_s", "moving_s",
            "waiting_s", "planning_s", "min_boom_clearance_m", "waits", "sequential", "detours", "moves_failed",
            "plan_makespan_s", "robust_price_pct", "interlocks", "zones", "robust_choice", "finish_s", "exec_p95",
            "standing_p95_pct",
            *(f"{c}_p{q}_pct" for c in STANDING_CAUSES for q in (50, 95))]
    out = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for _, r in table.iterrows():
        cells = [f"{r[c]:.3f}" if c in ("ratio", "min_boom_clearance_m", "exec_p95") else
                 f"{r[c]:.2f}" if c in ("robust_price_pct", "standing_p95_pct") or c.endswith("_pct") else
                 f"{r[c]:.0f}" if isinstance(r[c], float) and c != "planning_s" else
                 f"{r[c]:.1f}" if c == "planning_s" else str(r[c]) for c in cols]
        out.append("| " + " | ".join(cells) + " |")
    return "\n".join(out) + "\n"
