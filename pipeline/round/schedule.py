"""A round from a plan and its reach table: the instance, the plan, the baselines, the tables, the moves.

What the stage (``python -m pipeline.schedule``) and the round benchmark share, so that both time the
same moves with the same conflict handling:

1. each boom's joint solution of each hole is the reach table's (the hybrid's answer with the other
   booms at park); a boom can drill a hole when its row is ``ok``;
2. move costs are the time model's synchronised straight-line moves between those solutions
   (:func:`pipeline.round.kinematic.kinematic_round`): the routing cost, the timeline's durations
   and the trajectory rows all use them;
3. the conflict loop (:func:`pipeline.round.plan.plan_round`) and the baselines
   (:func:`pipeline.round.plan.baseline`) share one oracle, the real boom-boom clearances;
4. afterwards every move of the optimised round is checked for the boom's own self and tunnel
   clearances at 1 cm of point travel (:func:`pipeline.motion.checks.check_path`); a move that is not
   clear is counted under ``moves.straight_not_clear`` with its reason, never hidden (the boom-boom
   side of every move is the oracle's, at every instant).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
import torch

from pipeline.geometry.rig import Rig
from pipeline.plans.model import COLLAR, DrillPlan
from pipeline.plans.reach import Reach
from pipeline.plans.solutions import INVALID
from pipeline.round.instance import RoundSettings, precedence_indices
from pipeline.round.kinematic import kinematic_round
from pipeline.round.plan import RoundPlan, baseline, plan_round
from pipeline.round.tables import round_table, summary, trajectory_table
from pipeline.round.timeline import Timeline

D = torch.float64


@dataclass
class RoundResult:
    inst: object
    oracle: object
    plan: RoundPlan
    naive: Timeline | None
    nearest: Timeline | None
    round: pd.DataFrame
    trajectory: pd.DataFrame
    summary: dict
    moves: list[dict] = field(default_factory=list)


def _joints(reach: Reach, rig: Rig, b: int, n_holes: int) -> torch.Tensor:
    q = reach.results[rig.names[b]].q.detach().to(D).cpu()
    if q.shape[0] != n_holes:
        raise ValueError(f"reach table of boom {rig.names[b]}: {q.shape[0]} solutions for {n_holes} holes")
    return q


def _reasons(reach: Reach, ids, rig: Rig) -> tuple[str, ...]:
    t = reach.table[reach.table["status"] != INVALID]
    status = t.set_index(["hole_id", "boom"])["status"]
    out = []
    for h in ids:
        s = {b: status.get((h, b), "?") for b in rig.names}
        out.append("" if "ok" in s.values() else "no boom can drill it ok: " +
                   ", ".join(f"{b} {v}" for b, v in s.items()))
    return tuple(out)


def check_moves(inst, oracle, tl: Timeline, rig: Rig) -> tuple[dict, list[dict]]:
    """Each move of the timeline (straight line, the boom's own self and tunnel clearances at 1 cm)."""
    from pipeline.motion.checks import check_path
    from pipeline.motion.path import Path

    H, kinds, rows = inst.n_holes, {"straight": 0, "straight_not_clear": 0}, []
    for b, route in enumerate(tl.routes):
        nodes = [H, *route, H]
        for k in range(len(nodes) - 1):
            qa, qb = oracle.joints[b][nodes[k]], oracle.joints[b][nodes[k + 1]]
            if float(inst.move_s[b, nodes[k], nodes[k + 1]]) <= 0:
                continue
            path = Path.through(torch.stack([qa, qb]), oracle.limits[b])
            c = check_path(rig, b, path, {j: rig.booms[j].park for j in range(len(rig)) if j != b})
            ok = c.self >= 0 and c.tunnel >= 0
            kinds["straight" if ok else "straight_not_clear"] += 1
            if not ok:
                name = lambda n: "park" if n == H else inst.hole_ids[n]  # noqa: E731
                rows.append({"boom": rig.names[b], "from": name(nodes[k]), "to": name(nodes[k + 1]),
                             "self_m": c.self, "tunnel_m": c.tunnel})
    return kinds, rows


def schedule_round(rig: Rig, plan: DrillPlan, reach: Reach, motions, settings: RoundSettings,
                   baselines: bool = True, moves: bool = True, say=None) -> RoundResult:
    """Plan the round of ``plan`` on ``rig`` from its reach table (module docstring)."""
    say = say or (lambda _m: None)
    ids = plan.holes["hole_id"].astype(str).tolist()
    H = len(ids)
    t = reach.table[reach.table["status"] != INVALID]
    ok = t.assign(ok=t["status"] == "ok").pivot_table(index="boom", columns="hole_id", values="ok", aggfunc="any")
    reach_ok = np.stack([ok.loc[name, ids].to_numpy(bool) if name in ok.index else np.zeros(H, bool)
                         for name in rig.names])
    joints = [_joints(reach, rig, b, H) for b in range(len(rig))]
    collars = plan.holes[COLLAR].to_numpy(float)
    toes = plan.holes[["toe_x", "toe_y", "toe_z"]].to_numpy(float)
    lengths = np.linalg.norm(toes - collars, axis=1)
    prec = precedence_indices(settings.precedence, ids)
    inst, oracle = kinematic_round(rig, ids, joints, reach_ok, lengths, motions, collars, prec, settings,
                                   _reasons(reach, ids, rig))
    started = time.perf_counter()
    rp = plan_round(inst, oracle, settings, progress=say)
    say(f"planned in {rp.planning_s:.1f} s: makespan {rp.timeline.makespan:.1f} s")
    naive = nearest = None
    if baselines:
        naive = rp.baselines.get("naive") or baseline(inst, oracle, "naive", settings)
        nearest = rp.baselines.get("nearest") or baseline(inst, oracle, "nearest", settings)
    names = rig.booms[0].boom.joint_names
    kinds, not_clear = check_moves(inst, oracle, rp.timeline, rig) if moves else (None, [])
    table = round_table(inst, rp.timeline, [j.numpy() for j in joints], names)
    traj = trajectory_table(inst, rp.timeline, oracle, names)

    def extra(tl):
        return None if tl is None else {"waits": len(tl.repairs), "conflicts_left": tl.conflicts_left,
                                        "moving_s": sum(_times(inst, tl, b)["moving_s"] for b in range(len(rig))),
                                        "waiting_s": sum(_times(inst, tl, b)["waiting_s"] for b in range(len(rig)))}

    s = summary(inst, rp.timeline, rp.lower_bound_s, naive, nearest, [m.base for m in rig.booms], rig.d_boom, kinds,
                rig=rig.name, planning_s=rp.planning_s, routing_solves=rp.rounds, seed=rp.seed, kept_seed=rp.kept_seed,
                naive_round=extra(naive),
                nearest_round=extra(nearest), moves_not_clear=not_clear,
                total_s=time.perf_counter() - started)
    s["moving_s"] = sum(v["moving_s"] for v in s["booms"].values())
    s["waiting_s"] = sum(v["waiting_s"] for v in s["booms"].values())
    return RoundResult(inst, oracle, rp, naive, nearest, table, traj, s, not_clear)


def _times(inst, tl, b):
    from pipeline.round.timeline import boom_times

    return boom_times(inst, tl, b)
