"""A round from a plan and its reach table: the instance, the plan, the baselines, the tables, the moves.

What the stage (``python -m pipeline.schedule``) and the round benchmark share, so that both time the
same moves with the same conflict handling:

1. each boom's joint solution of each hole is the reach table's (the hybrid's answer with the other
   booms at park); a boom can drill a hole when its row is ``ok``;
2. move costs start as the time model's synchronised straight-line moves between those solutions
   (:func:`pipeline.round.rig_problem.kinematic_round`);
3. the planner (:func:`pipeline.round.planner.plan_round`) and the baselines share one oracle (the real
   boom-boom clearances) and one move book (:mod:`pipeline.round.detours`): every move a candidate
   uses is checked for the boom's own self and tunnel clearances at 1 cm of point travel before it
   is timed, and one that is not clear is re-planned (retract, or OMPL) and its detour's duration,
   motion and rows used from then on; a move nothing made clear is reported (``moves.failed``,
   ``moves_not_clear`` with the reasons), never hidden;
4. given the posture alternatives (:mod:`pipeline.round.postures`), the first planning times the seeds
   alone, and the round is planned again on the postures chosen along the best round's routes (each
   planning with its own oracle and book, the previous book's answers carried); the reference's baselines keep
   the reach table's postures.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd
import torch

from pipeline.core.errors import InputError
from pipeline.geometry.rig import Rig
from pipeline.plans.model import COLLAR, DrillPlan
from pipeline.plans.reach import Reach
from pipeline.plans.solutions import INVALID
from pipeline.round.oracle import KinematicOracle
from pipeline.round.planner import RoundPlan, baseline, better, make_book, near_best, plan_round, time_more_sweeps
from pipeline.round.postures import Postures, choose_postures, posture_bound
from pipeline.round.problem import precedence_indices
from pipeline.round.problem_file import RoundProblem
from pipeline.round.rig_problem import kinematic_round
from pipeline.round.settings import RoundSettings
from pipeline.round.tables import boom_floor, round_table, summary, trajectory_table
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
    timings: dict = field(default_factory=dict)  # wall-clock seconds: not in the summary (it reproduces)
    timeline: Timeline | None = None  # the round written: the plan's, or what ``finish`` made of it
    finished: object = None  # ``finish``'s extra (the executed round's tables and draws)


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


def move_report(inst, rp: RoundPlan, rig: Rig) -> tuple[dict, list[dict]]:
    """The round's moves by kind (straight, retract, planned, failed) and every failed one with its
    reason (:mod:`pipeline.round.detours`: the planner looked at each before timing it)."""
    if rp.book is None:
        return {}, []
    counts, failed = rp.book.kinds(rp.timeline.routes)
    H = inst.n_holes
    name = lambda n: "park" if n == H else inst.hole_ids[n]  # noqa: E731
    rows = [{"boom": rig.names[b], "from": name(u), "to": name(v), "reason": rp.book.reason.get((b, u, v), "")}
            for b, u, v in failed]
    return counts, rows


def planned_joints(rig: Rig, plan: DrillPlan, reach: Reach, table: pd.DataFrame, joint_names) -> list[torch.Tensor]:
    """Per boom ``(H, n)``: the reach table's solutions, with each hole of a planned round table at the
    joints the round drills it with (the posture it chose, :mod:`pipeline.round.postures`): the
    instance a round was planned on, rebuilt for a round handed on (``pipeline.execute``)."""
    ids = plan.holes["hole_id"].astype(str).tolist()
    joints = [_joints(reach, rig, b, len(ids)).clone() for b in range(len(rig))]
    index = {h: k for k, h in enumerate(ids)}
    drilled = table[table["boom"].isin(rig.names) & (table["status"] == "ok")]
    for row in drilled.itertuples(index=False):
        h = index.get(str(row.hole_id))
        if h is None:
            raise InputError(f"planned round table: hole {row.hole_id!r} is not in the plan")
        q = torch.tensor([float(getattr(row, n)) for n in joint_names], dtype=D)
        if not torch.isfinite(q).all():
            raise InputError(f"planned round table: hole {row.hole_id!r} has no joints ({joint_names})")
        joints[rig.names.index(str(row.boom))][h] = q
    return joints


def _reach_ok(reach: Reach, rig: Rig, ids) -> np.ndarray:
    t = reach.table[reach.table["status"] != INVALID]
    ok = t.assign(ok=t["status"] == "ok").pivot_table(index="boom", columns="hole_id", values="ok", aggfunc="any")
    return np.stack([ok.loc[name, ids].to_numpy(bool) if name in ok.index else np.zeros(len(ids), bool)
                     for name in rig.names])


def _plan_round_instance(rig: Rig, plan: DrillPlan, ids, joints, reach_ok, reasons, motions, settings: RoundSettings):
    collars = plan.holes[COLLAR].to_numpy(float)
    toes = plan.holes[["toe_x", "toe_y", "toe_z"]].to_numpy(float)
    lengths = np.linalg.norm(toes - collars, axis=1)
    prec = precedence_indices(settings.precedence, ids)
    return kinematic_round(rig, ids, joints, reach_ok, lengths, motions, collars, prec, settings, reasons)


def round_instance(rig: Rig, plan: DrillPlan, reach: Reach, motions, settings: RoundSettings, joints=None):
    """The instance, its oracle and each boom's joint solutions ``(H, n)`` of ``plan`` from its reach table
    (or ``joints``, per boom ``(H, n)``: the postures a round chose, :mod:`pipeline.round.postures`)."""
    ids = plan.holes["hole_id"].astype(str).tolist()
    joints = [_joints(reach, rig, b, len(ids)) for b in range(len(rig))] if joints is None else \
        [torch.as_tensor(q, dtype=D) for q in joints]
    inst, oracle = _plan_round_instance(rig, plan, ids, joints, _reach_ok(reach, rig, ids), _reasons(reach, ids, rig),
                                        motions, settings)
    return inst, oracle, joints


def round_problem(rig: Rig, plan: DrillPlan, reach: Reach, table: pd.DataFrame, joint_names) -> RoundProblem:
    """What a planned round was planned on (:mod:`pipeline.round.problem_file`), each hole of the round
    table ``table`` at the joints the round drills it with."""
    ids = plan.holes["hole_id"].astype(str).tolist()
    joints = np.stack([q.numpy() for q in planned_joints(rig, plan, reach, table, joint_names)])
    return RoundProblem(tuple(rig.names), tuple(ids), tuple(joint_names), _reach_ok(reach, rig, ids), joints,
                        _reasons(reach, ids, rig))


def problem_instance(rig: Rig, plan: DrillPlan, problem: RoundProblem, motions, settings: RoundSettings):
    """The instance and oracle of a round's problem as :func:`round_instance` builds them from the reach
    table, without solving it again: what a round handed on is planned on (``pipeline.execute``)."""
    ids = plan.holes["hole_id"].astype(str).tolist()
    joints = [torch.as_tensor(q, dtype=D) for q in problem.joints]
    return _plan_round_instance(rig, plan, ids, joints, problem.reach, problem.reasons, motions, settings)


def schedule_round(rig: Rig, plan: DrillPlan, reach: Reach, motions, settings: RoundSettings,
                   baselines: bool = True, moves: bool = True, say=None, finish=None,
                   postures: Postures | None = None, choose=None) -> RoundResult:
    """Plan the round of ``plan`` on ``rig`` from its reach table (module docstring). ``finish``:
    ``(instance, timeline, oracle) -> (timeline, extra)``, called on the planned round; the tables and
    the summary are written from the timeline it returns (the execution layer's robust round, re-timed
    by events: :func:`pipeline.events.robust_round.robust_finish`), ``extra`` kept as ``RoundResult.finished``.
    ``postures``: more ok solutions per hole and boom (:func:`pipeline.round.postures.round_postures`):
    the round is planned again from the postures chosen along the best round's routes while that is
    better (``round.posture_rounds``); the lower bound is then the least over every alternative.
    ``choose``: ``[extra, ...] -> (index, record)``; given with ``finish`` (and two booms or more), sweeps
    in the bands ``round.robust_bands_m`` are timed too, and the best round and the other candidates of
    about its makespan (:func:`pipeline.round.planner.near_best`: ``round.robust_candidates`` within
    ``round.robust_slack``) are each finished and ``choose`` keeps one (the execution layer's: the
    one whose booms stand least under drawn drilling times); ``record`` goes to the summary as
    ``robust_choice``."""
    say = say or (lambda _m: None)
    inst, oracle, joints = round_instance(rig, plan, reach, motions, settings)
    first_oracle = oracle  # the reference's baselines drill the reach table's postures
    started = time.perf_counter()
    choosing = postures is not None and postures.k > 1 and inst.start is None and isinstance(oracle, KinematicOracle)
    # with postures to choose, the first planning times the seeds alone: the routing runs on the chosen
    # postures, whose rounds replace this one (docs/round.md, "Postures")
    rp = plan_round(inst, oracle, replace(settings, routing=False) if choosing else settings,
                    progress=say, baselines=baselines)
    say(f"planned in {rp.planning_s:.1f} s: makespan {rp.timeline.makespan:.1f} s")
    first = rp
    if choosing and rp.book is not None:
        rp, oracle, joints = _plan_postures(rig, plan, reach, motions, settings, postures, rp, oracle, joints, say)
    naive = nearest = None
    if baselines:
        naive = first.baselines.get("naive") or baseline(first.inst, first_oracle, "naive", settings, first.book)
        nearest = first.baselines.get("nearest") or baseline(first.inst, first_oracle, "nearest", settings, first.book)
    # one boom never stands: nothing to choose
    comparing = finish is not None and choose is not None and settings.robust_candidates > 1 and rp.inst.n_booms > 1
    t_finish = time.perf_counter()
    if comparing:  # more rounds to choose from (docs/round.md, "Choosing the round that stands least")
        timed = time_more_sweeps(rp, oracle, settings, settings.robust_bands_m)
        say(f"robust choice: {timed} more sweeps timed")
    inst = rp.inst if rp.book is None else rp.book.apply(rp.inst)  # the baselines' detours too
    names = rig.booms[0].boom.joint_names
    final, finished, choice = rp.timeline, None, None
    if finish is not None:
        final, finished, choice = _finish_chosen(inst, rp, oracle, finish, choose if comparing else None, settings,
                                                 say)
    finish_s = time.perf_counter() - t_finish
    kinds, not_clear = move_report(inst, rp, rig) if moves else (None, [])
    table = round_table(inst, final, [j.numpy() for j in joints], names)
    failed = rp.book.kinds(final.routes)[1] if rp.book is not None else []
    traj = trajectory_table(inst, final, oracle, names, failed)

    base = first.inst if first.book is None else first.book.apply(first.inst)

    def extra(tl):
        return None if tl is None else {"waits": len(tl.repairs), "conflicts_left": tl.conflicts_left,
                                        "moving_s": sum(_times(base, tl, b)["moving_s"] for b in range(len(rig))),
                                        "waiting_s": sum(_times(base, tl, b)["waiting_s"] for b in range(len(rig)))}

    s = summary(inst, final, rp.lower_bound_s, naive, nearest, [m.base for m in rig.booms], rig.d_boom, kinds,
                rig=rig.name, stopped=rp.stopped,
                routing_solves=rp.rounds, seed=rp.seed, kept_seed=rp.kept_seed,
                naive_round=extra(naive),
                nearest_round=extra(nearest), moves_failed=len(failed), moves_not_clear=not_clear,
                certified_floor_m={**(rp.book.floors(final.routes) if rp.book is not None else
                                      {"self": None, "tunnel": None}),
                                   "boom": boom_floor(final, oracle.floor)},
                margin_m={**({k: rp.book.margin[k] for k in ("self", "tunnel")} if rp.book is not None else
                             {"self": None, "tunnel": None}), "boom": 0.0},
                reproducible=settings.reproducible, postures=rp.postures)
    if choice is not None:
        s["robust_choice"] = choice
    s["moving_s"] = sum(v["moving_s"] for v in s["booms"].values())
    s["waiting_s"] = sum(v["waiting_s"] for v in s["booms"].values())
    timings = {"planning_s": rp.planning_s, "baselines_s": rp.baselines_s, "total_s": time.perf_counter() - started,
               "moves_s": rp.book.seconds if rp.book is not None else 0.0, "finish_s": finish_s}
    return RoundResult(inst, oracle, rp, naive, nearest, table, traj, s, not_clear, timings, final, finished)


def _finish_chosen(inst, rp: RoundPlan, oracle, finish, choose, settings: RoundSettings, say):
    """``finish`` on the best round or, given ``choose``, on each candidate of about its makespan, one
    kept (``schedule_round``); ``rp`` then holds the kept round's timeline and where it came from."""
    if choose is None:
        return (*finish(inst, rp.timeline, oracle), None)
    cands = near_best(rp, settings.robust_slack, settings.robust_candidates)
    done = [finish(inst, tl, oracle) for _, tl in cands]
    k, record = choose([extra for _, extra in done]) if len(done) > 1 else (0, {})
    label, tl = cands[k]
    record = {"candidates": [lab for lab, _ in cands], "chosen": label,
              "plan_makespans_s": [float(t.makespan) for _, t in cands], **record}
    if k:
        say(f"robust choice: {label} (makespan {tl.makespan:.1f} s) over the best's {rp.timeline.makespan:.1f} s")
        rp.timeline, rp.seed, rp.kept_seed = tl, label, not label.startswith("routing")
    return (*done[k], record)


def _plan_postures(rig: Rig, plan: DrillPlan, reach: Reach, motions, settings: RoundSettings, postures: Postures,
                   rp: RoundPlan, oracle, joints, say) -> tuple[RoundPlan, object, list[torch.Tensor]]:
    """The round planned again from the postures chosen along the best round's routes
    (:mod:`pipeline.round.postures`), up to ``round.posture_rounds`` times while each is better; the
    best plan, its oracle and joints. Each planning takes the previous book's answers for the moves whose
    ends kept their joints; the bound is the least over every alternative; the reference's baselines stay
    those of the reach table's postures (the first plan's)."""
    limits = [m.joints for m in motions]
    first, best = rp, (rp, oracle, joints)
    changed, total_s, bound = 0, rp.planning_s, rp.lower_bound_s
    for k in range(settings.posture_rounds):
        cur, cur_oracle, cur_joints = best
        chosen = choose_postures(cur.inst, cur.timeline, postures, cur_joints, rig, limits, settings.posture_conflict_s,
                                 settings.posture_unclear_s, settings.blocked_screen_m)
        moved = sum(int((~_same_rows(a, c)).sum()) for a, c in zip(cur_joints, chosen, strict=True))
        if moved == 0:
            say(f"postures, round {k + 1}: the routes' postures are already the chosen ones")
            break
        inst2, oracle2, joints2 = round_instance(rig, plan, reach, motions, settings, chosen)
        book = make_book(inst2, oracle2, settings)
        book.carry(cur.book, np.stack([_same_rows(a, c).numpy() for a, c in zip(cur_oracle.joints, oracle2.joints,
                                                                                 strict=True)]))
        say(f"postures, round {k + 1}: {moved} (boom, hole) solutions changed along the routes; planning again")
        rp2 = plan_round(inst2, oracle2, settings, progress=say, baselines=False, book=book,
                         candidates={"the previous round's routes": cur.timeline.routes})
        total_s += rp2.planning_s
        bound = min(bound, rp2.lower_bound_s)
        if not better(rp2.timeline, cur.timeline):
            say(f"postures, round {k + 1}: makespan {rp2.timeline.makespan:.1f} s, not better; kept "
                f"{cur.timeline.makespan:.1f} s")
            break
        say(f"postures, round {k + 1}: makespan {rp2.timeline.makespan:.1f} s (was {cur.timeline.makespan:.1f} s)")
        changed += moved
        best = (rp2, oracle2, joints2)
    rp = best[0]
    if rp is first:
        rp.stopped = f"the best seed on the reach table's postures: no planning on chosen postures was better ({k + 1})"
    rp.baselines, rp.baselines_s = first.baselines, first.baselines_s
    rp.planning_s = total_s
    rp.lower_bound_s = min(bound, posture_bound(first.inst, postures, limits, rig))
    rp.postures = {"k": postures.k, "rounds": k + 1, "changed": changed, "chosen": rp is not first,
                   "alternatives": {rig.names[b]: c for b, c in postures.counts().items()}}
    return best


def _same_rows(a: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
    """Rows of two joint tables that are exactly the same (NaN equal to NaN)."""
    return ((a == c) | (a.isnan() & c.isnan())).all(dim=1)


def _times(inst, tl, b):
    from pipeline.round.timeline import boom_times

    return boom_times(inst, tl, b)
