"""An interrupted round (docs/reference.md, section 8): a hole that cannot be finished, and the round handed on.

**What happens when hole X is interrupted** ``at_s`` seconds into its drilling (decided here, in
``docs/round.md``): X's boom stops drilling there (X's drill action ends then: the hole is *left*,
reported, never drilled again); no action starts any more; every boom finishes the action it is in
(a move ends at its hole, a drill at its end), and stands. These actions, the **prefix**, are those
that started before the interruption: a set closed under the interlocks (an action that started had
every action it waits for ended), so the prefix is a part of an execution of the robust round (one
where X drills very long) and is clear at every instant, standing included.

Then, when the last of them ends (``t_hand``), the round is **handed on**: the holes not yet started
are planned again (:func:`pipeline.round.planner.plan_round` on the instance with each boom starting where
it stands, ``Instance.start``; a boom standing at a hole it has not drilled drills it first), made
robust (:func:`pipeline.events.interlocks.robust_round`) and executed from ``t_hand``. Every boom's
first new action waits for every other boom's last prefix action (a barrier: the new plan was made for
the booms standing where they stand). With ``replan: false`` the round instead goes on with its own
actions and interlocks (X's drill merely shorter: a robust round is clear for any duration), nothing
re-planned.

:func:`splice` joins the two: the executed prefix and the new plan, one actions list (each boom's
actions numbered on), the interlocks (the prefix's own, the new plan's, the barrier) and each action's
trajectory rows, so the handed-on round is one section-7 trajectory file and one actions file.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field

import numpy as np

from pipeline.core.errors import ConfigError, Deadlock
from pipeline.events.actions import Actions
from pipeline.events.rule import execute
from pipeline.events.trajectory import Rows


@dataclass(frozen=True)
class Standing:
    """The round when it is handed on: the prefix (actions started before the interruption), its
    executed times (the interrupted drill cut), the hand-on instant, each boom's node (H: park)."""

    prefix: np.ndarray  # (K,) bool
    start: np.ndarray  # (K,) s, executed (inf outside the prefix)
    end: np.ndarray  # (K,) s
    t_hand: float
    t_interrupt: float
    node: tuple[int, ...]
    drilled: tuple[int, ...]  # holes drilled to their end
    left: int  # the interrupted hole
    interrupted: int  # its drill action


def standing(acts: Actions, interlocks: np.ndarray, drill_s: np.ndarray, hole: int, at_s: float) -> Standing:
    """Execute the round with drilling durations ``drill_s (H,)`` up to hole ``hole``'s interruption
    ``at_s`` seconds into its drilling (module docstring)."""
    drills = np.flatnonzero(acts.is_drill & (acts.hole == hole))
    if not len(drills):
        raise ConfigError(f"interrupt.hole = {acts.hole_ids[hole]!r}: no boom drills it in this round")
    k = int(drills[0])
    ex = execute(acts, interlocks, drill_s)
    if ex.deadlock is not None:
        raise Deadlock("interrupt: the round deadlocks before the interruption: "
                       + ", ".join(map(acts.name, ex.deadlock)))
    duration = float(ex.end[0, k] - ex.start[0, k])
    if not (0 < at_s < duration):
        raise ConfigError(f"interrupt.at_s = {at_s}: hole {acts.hole_ids[hole]} drills for {duration:.3f} s in this "
                          "execution; an interruption is after its start and before its end (0 < at_s < that)")
    t_i = float(ex.start[0, k]) + at_s
    prefix = ex.start[0] < t_i
    start = np.where(prefix, ex.start[0], np.inf)
    end = np.where(prefix, ex.end[0], np.inf)
    end[k] = t_i
    H = len(acts.hole_ids)
    node = []
    for b in range(len(acts.booms)):  # a few booms
        mine = np.flatnonzero((acts.boom == b) & prefix)
        node.append(int(acts.dst[mine[-1]]) if len(mine) else H)
    drilled = tuple(int(h) for h in acts.hole[prefix & acts.is_drill] if h != hole)
    return Standing(prefix, start, end, float(end[prefix].max()), t_i, tuple(node), drilled, hole, k)


def handed_on_instance(inst, st: Standing):
    """The instance of the holes still to drill, each boom starting where it stands: holes drilled and
    the interrupted one out of every boom's reach (their reasons say why); a boom standing at a hole it
    has not drilled keeps that hole to itself (the routing makes it its first). Precedence pairs whose
    first hole is done are met; one whose first hole is the interrupted one cannot be, and is dropped
    (returned, to be reported)."""
    H = inst.n_holes
    reach = inst.reach.copy()
    done = list(st.drilled) + [st.left]
    reach[:, done] = False
    for b, n in enumerate(st.node):
        if n < H and reach[b, n]:  # arrived, not drilled: nobody else may take it
            reach[:, n] = False
            reach[b, n] = True
    reasons = list(inst.reasons or [""] * H)
    for h in st.drilled:
        reasons[h] = "drilled before the round was handed on"
    reasons[st.left] = "interrupted: left undrilled"
    kept, dropped = [], []
    done_set = set(st.drilled)
    for i, j in inst.precedence:
        if i == st.left and j not in done_set:
            dropped.append((i, j))
        elif i not in done_set and j not in done_set and j != st.left:
            kept.append((i, j))
    sub = dataclasses.replace(inst, reach=reach, start=st.node, precedence=tuple(kept), reasons=tuple(reasons))
    return sub, dropped


@dataclass
class HandedOn:
    """The new plan from where the booms stand: its instance, plan, robust round, and the seconds the
    re-planning took (wall clock, for the log and MLflow)."""

    inst: object
    plan: object
    robust: object
    replan_s: float
    dropped_precedence: list
    timings: dict = field(default_factory=dict)  # wall-clock seconds: planning, moves looked at, interlocks


def hand_on(inst, oracle, settings, st: Standing, say=None, book=None, planned_order=None) -> HandedOn:
    """Plan the holes still to drill from where the booms stand, and make the plan robust. ``book``:
    the planner's move book of the planned round (:mod:`pipeline.round.move_file`): its moves are not
    looked at again. ``planned_order``: per boom the holes left in the planned round's order: a seed of
    the new plan beside the sweeps, and the first candidate tried when the new plan cannot be made
    robust (then the sweeps)."""
    from pipeline.events.interlocks import robust_round
    from pipeline.round.planner import SEEDS, first_where_standing, plan_round, seed_routes, timed_routes

    t0 = time.perf_counter()
    sub, dropped = handed_on_instance(inst, st)
    cands = {"planned order": planned_order} if planned_order is not None else None
    rp = plan_round(sub, oracle, settings, progress=say, baselines=False, book=book, candidates=cands)
    sub_inst = rp.inst if rp.book is None else rp.book.apply(rp.inst)
    rr = robust_round(sub_inst, rp.timeline, oracle)
    # A plan whose conflicts no order of actions can part (a move that passes every place the other boom
    # can be) is not handed on while another candidate is robust: the sweeps, then the slower of them
    fallbacks = ([("planned order", planned_order)] if planned_order is not None else []) + [
        (kind, seed_routes(sub_inst, kind, settings.sweep_band_m)) for kind in SEEDS]
    for kind, routes in fallbacks if rr.problem is not None else ():
        routes = first_where_standing(sub_inst, routes)
        if routes == rp.timeline.routes:  # the plan already found not robust (a seed that won)
            continue
        tl = timed_routes(sub_inst, oracle, settings, rp.book, routes)
        if tl.conflicts_left:
            continue
        cand_inst = sub_inst if rp.book is None else rp.book.apply(sub_inst)
        alt = robust_round(cand_inst, tl, oracle)
        if say:
            say(f"{kind}: {'robust' if alt.problem is None else 'not robust'}, nominal makespan "
                f"{alt.timeline.makespan:.1f} s")
        if alt.problem is None:
            rr, sub_inst = alt, cand_inst
            rp.timeline = tl
            break
    ho = HandedOn(sub_inst, rp, rr, time.perf_counter() - t0, dropped)
    ho.timings = {"plan_s": rp.planning_s, "moves_s": rp.book.seconds if rp.book is not None else 0.0,
                  "interlocks_s": float(rr.stats.get("build_s", 0.0)), "total_s": ho.replan_s}
    return ho


@dataclass(frozen=True)
class Spliced:
    """The handed-on round as one: actions (``t_start``/``t_end``: the times each action's rows were
    planned at, for :func:`pipeline.events.trajectory.retimed`), the interlocks, each action's rows,
    and which actions are the prefix's."""

    actions: Actions
    interlocks: np.ndarray
    rows: list[Rows]
    prefix: np.ndarray


def _unwrap_to(q_new: np.ndarray, q_prev: np.ndarray, wrap: np.ndarray) -> np.ndarray:
    """The full turns (q4, q7) that make ``q_new`` continue from ``q_prev`` (the file keeps them continuous)."""
    turns = np.round((q_prev - q_new) / (2 * math.pi)) * 2 * math.pi
    return np.where(wrap, turns, 0.0)


def splice(planned: Actions, planned_rows: list[Rows], planned_edges: np.ndarray, st: Standing,
           new: Actions, new_rows: list[Rows], new_edges: np.ndarray, wrap: list[np.ndarray]) -> Spliced:
    """The prefix of ``planned`` then ``new`` (times shifted by ``st.t_hand``), per boom (module docstring).
    ``wrap``: per boom, its full-turn joints. A leading move of ``new`` that goes nowhere (a boom standing
    at the hole it drills first) is dropped, its interlocks passed to the boom's next action."""
    B = len(planned.booms)
    cols = {k: [] for k in ("boom", "index", "kind", "hole", "src", "dst", "t_start", "t_end")}
    rows: list[Rows] = []
    origin: list[tuple[str, int]] = []  # ("old" | "new", action number there)
    new_of: dict[int, int] = {}  # new action -> spliced number (dropped moves: their next action's)
    old_of: dict[int, int] = {}
    first_new: list[int] = []
    last_old: list[int] = []
    # each boom's first new action when it goes nowhere in no time (it stands at the hole it drills first)
    skipped = {int(k) for k in np.flatnonzero(new.index == 0)
               if not new.is_drill[k] and new.src[k] == new.dst[k] and new.t_end[k] - new.t_start[k] <= 0}
    n = 0
    for b in range(B):
        i = 0
        old = np.flatnonzero((planned.boom == b) & st.prefix)
        for k in old:
            for c, v in zip(cols, (b, i, planned.kind[k], planned.hole[k], planned.src[k], planned.dst[k],
                                   planned.t_start[k], planned.t_end[k]), strict=True):
                cols[c].append(v)
            rows.append(planned_rows[k])
            origin.append(("old", int(k)))
            old_of[int(k)] = n
            n, i = n + 1, i + 1
        last_old.append(n - 1 if len(old) else -1)
        mine = np.flatnonzero(new.boom == b)
        skip = [int(k) for k in mine[:1] if int(k) in skipped]
        shift = None
        first_new.append(n if len(mine) > len(skip) else -1)
        for k in mine:
            if int(k) in skip:
                continue
            r = new_rows[k]
            if shift is None:  # continue the prefix's full turns
                prev = planned_rows[old[-1]].q_end if len(old) else r.q[0] if len(r.q) else r.q_end
                shift = _unwrap_to(r.q[0] if len(r.q) else r.q_end, prev, wrap[b])
            rows.append(Rows(r.t, r.q + shift, r.event, r.hole, r.q_end + shift))
            for c, v in zip(cols, (b, i, new.kind[k], new.hole[k], new.src[k], new.dst[k],
                                   new.t_start[k] + st.t_hand, new.t_end[k] + st.t_hand), strict=True):
                cols[c].append(v)
            origin.append(("new", int(k)))
            new_of[int(k)] = n
            n, i = n + 1, i + 1
        for k in skip:
            new_of[int(k)] = first_new[-1]
    arr = {k: np.asarray(v, dtype=float if k.startswith("t_") else (str if k == "kind" else int))
           for k, v in cols.items()}
    acts = Actions(planned.booms, planned.hole_ids, **arr)
    edges = []
    pre = set(np.flatnonzero(st.prefix).tolist())
    for u, v in np.asarray(planned_edges, int).reshape(-1, 2):
        if int(u) in pre and int(v) in pre:
            edges.append((old_of[int(u)], old_of[int(v)]))
    succ: dict[int, list[int]] = {}
    for u, v in np.asarray(new_edges, int).reshape(-1, 2):
        succ.setdefault(int(u), []).append(int(v))
    for u, v in np.asarray(new_edges, int).reshape(-1, 2):
        u, v = int(u), int(v)
        if u in skipped:  # a move of no time ends when it may start: its followers wait for what it waits for
            continue
        targets = [v] if v not in skipped else [v, *succ.get(v, [])]
        for w in targets:
            a, c = new_of.get(u, -1), new_of.get(w, -1)
            if a >= 0 and c >= 0 and a != c:
                edges.append((a, c))
    for b in range(B):  # the barrier: the new plan starts once every boom stands
        if first_new[b] < 0:
            continue
        for c in range(B):
            if c != b and last_old[c] >= 0:
                edges.append((last_old[c], first_new[b]))
    e = np.array(sorted(set(edges)), int).reshape(-1, 2)
    prefix = np.array([o == "old" for o, _ in origin], bool)
    return Spliced(acts, e, rows, prefix)


@dataclass
class Interrupted:
    """An interrupted round handed on and executed: the standing, the new plan, the spliced round, its
    execution (one draw), the cut drill's action number, and what to report of the new plan."""

    standing: Standing
    handed: HandedOn
    spliced: Spliced
    execution: object
    cut: int
    report: dict


def interrupted_round(acts: Actions, edges: np.ndarray, rows: list[Rows], st: Standing, drill_s: np.ndarray,
                      factor: np.ndarray, inst, oracle, settings, joint_names, say=None, book=None) -> Interrupted:
    """The round of ``acts`` (its rows from the planned trajectory file) interrupted as ``st`` says,
    handed on (:func:`hand_on`) and executed: the prefix at its executed times (``drill_s``), the new
    plan's holes at ``factor`` times their planned drilling. The prefix is re-checked to reproduce."""
    from pipeline.events.trajectory import action_rows
    from pipeline.round.tables import trajectory_table

    left = [[int(acts.hole[k]) for k in np.flatnonzero((acts.boom == b) & acts.is_drill & ~st.prefix)]
            for b in range(len(acts.booms))]
    ho = hand_on(inst, oracle, settings, st, say, book, left)
    rr = ho.robust
    failed = ho.plan.book.kinds(rr.timeline.routes, ho.inst.starts)[1] if ho.plan.book is not None else []
    sub_traj = trajectory_table(ho.inst, rr.timeline, oracle, joint_names, failed)
    sub_rows = action_rows(sub_traj, rr.actions, joint_names, "the handed-on plan")
    wrap = [np.asarray(oracle.limits[b].wrap, bool) for b in range(len(acts.booms))]
    sp = splice(acts, rows, edges, st, rr.actions, sub_rows, rr.interlocks, wrap)
    H = len(acts.hole_ids)
    durations = np.where(np.isin(np.arange(H), st.drilled), drill_s, factor * ho.inst.drill_s)
    durations[st.left] = st.end[st.interrupted] - st.start[st.interrupted]
    ex = execute(sp.actions, sp.interlocks, durations)
    cut = int(np.flatnonzero(sp.prefix & sp.actions.is_drill & (sp.actions.hole == st.left))[0])
    pre = np.flatnonzero(sp.prefix)
    if ex.deadlock is not None or not np.allclose(ex.start[0, pre], st.start[st.prefix], atol=1e-6):
        raise RuntimeError("interrupted_round: the spliced round does not reproduce its executed prefix")
    report = {"holes": int(sum(len(r) for r in rr.timeline.routes)), "makespan_s": rr.timeline.makespan,
              "robust": rr.problem is None, "problem": rr.problem, "interlocks": int(len(rr.interlocks)),
              "conflicts_left": int(rr.stats["conflicts_left"]), "moves_failed": len(failed),
              "routing_solves": ho.plan.rounds, "stopped": ho.plan.stopped}
    return Interrupted(st, ho, sp, ex, cut, report)
