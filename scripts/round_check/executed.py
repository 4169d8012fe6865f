"""The executed rounds: the draws run by the checker's execution rule, each checked for deadlock, for
reproducing the trajectory file under the model durations, and for d_boom at every instant.

Self and tunnel clearances do not depend on timing (every action's motion is fixed, a pause stands
where an action left the boom), so they are checked once, on the trajectory file. Boom-boom: per pair
of booms, the episode floors (:mod:`round_check.episodes`) are computed once; per draw, the episode
pairs whose floor is below d_boom and whose executed windows overlap (open intervals: every instant
lies in some pair of episodes of positive length, closed at their ends) are candidates, each confirmed
or cleared by a dense certified sweep of the two booms over the overlap, each action's rows shifted to
its executed start. Identical windows (same episodes, same relative timing) are swept once; once the
messages are full, a draw already shown broken is not swept further (``windows_confirmed`` then
counts the sweeps run).
"""

from __future__ import annotations

import dataclasses
import time
from itertools import combinations

import numpy as np

from . import episodes as ep
from .actions import TIME_TOL, Actions, Interlocks, Zones
from .execute import Draws, Graph, execute, execute_zones
from .files import BoomRows
from .settings import Settings
from .sweep import Sweep

MAKESPAN_TOL = 1.0  # s: docs/reference.md section 8, "same makespan within 1 s"
MAX_MESSAGES = 20


def durations(acts: Actions, spec_s: dict[str, float], dr: Draws) -> np.ndarray:
    """``(draws, n)``: moves as planned, a drill its model time times the draw's factor for its hole."""
    dur = np.broadcast_to(acts.t_end - acts.t_start, (len(dr.labels), len(acts))).copy()
    drill = np.flatnonzero(acts.kind == "drill")
    col = {h: i for i, h in enumerate(dr.holes)}
    nominal = np.array([spec_s.get(h, acts.t_end[k] - acts.t_start[k]) for h, k in zip(acts.hole[drill], drill,
                                                                                       strict=True)])
    dur[:, drill] = dr.factor[:, [col[h] for h in acts.hole[drill]]] * nominal
    return dur


def _window_rows(r: BoomRows, planned: np.ndarray, episode: int, s_exec: float, w0: float, w1: float,
                 still: bool = False) -> BoomRows:
    """A boom's rows over executed [w0, w1]: a move's rows shifted to its executed start (a move keeps
    its planned duration), a pause or a drill (``still``: at constant joints, docs/reference.md section 8, checked when
    the actions are read) standing still. A drill lasts what the draw says, not what the plan did: its
    rows shifted by its start would run past its planned end into the boom's next action."""
    if episode % 2 == 0 or still:
        t = np.array([w0, w1]) if w1 > w0 else np.array([w0])
        q = np.repeat(np.stack([np.interp(planned[episode, 0], r.t, r.q[:, j]) for j in range(r.q.shape[1])])[None],
                      len(t), 0)
    else:
        shift = s_exec - planned[episode, 0]
        a, b = w0 - shift, w1 - shift
        inner = (r.t > a) & (r.t < b)
        tp = np.concatenate([[a], r.t[inner], [b]]) if b > a else np.array([a])
        q = np.stack([np.interp(tp, r.t, r.q[:, j]) for j in range(r.q.shape[1])], -1)
        t = tp + shift
    n = len(t)
    return BoomRows(t, q, np.full(n, "move"), np.full(n, ""), np.zeros(n, np.int64))


def _drill(acts: Actions, b: int, episode: int) -> bool:
    """Whether episode ``episode`` of boom b (odd: action ``episode // 2``) is a drill."""
    return episode % 2 == 1 and acts.kind[acts.first[b] + episode // 2] == "drill"


def episode_floors(st: Settings, rows: dict[str, BoomRows], acts: Actions):
    """Per boom (index in ``acts.booms``) its planned episode windows and time cells, and per pair of booms
    ``(a, b)``, a < b, the certified floors of every pair of their episodes (:func:`round_check.episodes.floors`):
    computed once, for the certification (:mod:`round_check.certify`) and the draws alike."""
    names = [b.name for b in st.booms]
    planned, cells = {}, {}
    for b, name in enumerate(acts.booms):
        planned[b] = ep.episode_windows(acts, b, rows[name])
        cells[b] = ep.Cells(st.booms[names.index(name)], rows[name], planned[b])
    floors = {(a, b): ep.floors(cells[a], cells[b], st.d_boom) for a, b in combinations(range(len(acts.booms)), 2)}
    return planned, cells, floors


def check(st: Settings, rows: dict[str, BoomRows], acts: Actions, locks: Interlocks, g: Graph, dr: Draws,
          spec_s: dict[str, float], spacing_m: float, levels: int, zones: Zones | None = None,
          floors=None) -> dict:
    """The draws executed and checked (module docstring); ``zones``: the rule with zones
    (:func:`round_check.execute.execute_zones`); ``floors``: :func:`episode_floors`' answer, if made already."""
    t_begin = time.perf_counter()
    out = {"actions": str(acts.path), "interlocks": str(locks.path), "draws": len(dr.labels),
           "draws_by_kind": {"nominal": 1, "random": sum(lb.startswith("random") for lb in dr.labels),
                             "hole_at_3x": sum(lb.startswith("hole") for lb in dr.labels),
                             "boom_slow": sum(lb.startswith("boom") for lb in dr.labels),
                             "file": sum(1 for k in dr.kinds if k)},
           "actions_per_boom": {b: int(n) for b, n in zip(acts.booms, np.diff(acts.first), strict=True)},
           "interlock_rows": int(len(locks.after)),
           "self_and_tunnel": "unchanged by timing (each action's motion is fixed): checked once on the trajectory "
                              "file (booms above)",
           "holes": "each draw drills the drill actions' holes, each once: checked once (the actions agree with the "
                    "trajectory file, whose holes are checked above)"}
    violations: list[str] = []
    if g.cycle is not None:
        names = " -> ".join(acts.name(k) for k in [*g.cycle, g.cycle[0]])
        out.update({"deadlocks": 1, "deadlock_cycle": names, "violations": 1})
        return {**out, "messages": [f"deadlock: {names} (each waits for the next; {locks.path})"], "unclear": []}
    out["zones"] = 0 if zones is None else len(zones)
    if zones is not None and len(zones):
        start, end, stuck = execute_zones(acts, g, zones, durations(acts, spec_s, dr))
        dead = [i for i, s in enumerate(stuck) if s is not None]
        for i in dead[:MAX_MESSAGES]:
            waiting = ", ".join(acts.name(k) for k in stuck[i])
            violations.append(f"deadlock in draw {i} ({dr.labels[i]}): no boom can go on; they stand before "
                              f"{waiting} (interlocks and zones: {locks.path}, {zones.path})")
        if len(dead) > MAX_MESSAGES:
            violations.append(f"{len(dead) - MAX_MESSAGES} more draws deadlock")
        out["deadlocks"] = len(dead)
        if dead:  # what a deadlocked draw did is not a round: the rest are checked
            keep = np.array([s is None for s in stuck])
            dr = Draws([lb for lb, k in zip(dr.labels, keep, strict=True) if k], dr.factor[keep], dr.holes,
                       [kd for kd, k in zip(dr.kinds, keep, strict=True) if k])
            start, end = start[keep], end[keep]
            if not keep.any():
                out.update({"violations": len(violations)})
                return {**out, "messages": violations, "unclear": []}
    else:
        start, end = execute(g, durations(acts, spec_s, dr))
        out["deadlocks"] = 0
    if dr.labels[0].startswith("nominal"):
        violations += _nominal(acts, rows, start[0], end[0])
    span = np.zeros(len(dr.labels))
    per_boom = {}
    for b in range(len(acts.booms)):
        k = np.arange(acts.first[b], acts.first[b + 1])
        if len(k):
            span = np.maximum(span, end[:, k[-1]])
        ready = np.concatenate([np.zeros((len(span), 1)), end[:, k[:-1]]], 1)[:, :len(k)]  # previous end, or t = 0
        per_boom[acts.booms[b]] = (start[:, k] - ready).sum(1)
    standing = np.sum(list(per_boom.values()), 0)
    t_exec = time.perf_counter() - t_begin
    pair_msgs, unclear, stats = _boom_boom(st, rows, acts, dr, start, end, spacing_m, levels, floors)
    violations += pair_msgs
    share = standing / np.where(span > 0, span, 1.0)
    bad_draws = stats.pop("_violating")
    if any(dr.kinds):
        out["draws_file_by_kind"] = _by_kind(dr, span, bad_draws)
    out.update({
        **stats,
        "makespan_s": {"trajectory": max(float(r.t[-1]) for r in rows.values()), "nominal": float(span[0]),
                       "p50": float(np.percentile(span, 50)), "p95": float(np.percentile(span, 95)),
                       "max": float(span.max()), "max_draw": dr.labels[int(span.argmax())]},
        "standing_at_interlocks_s": {"max": float(standing.max()), "p95": float(np.percentile(standing, 95)),
                                     "p95_share_of_makespan": float(np.percentile(share, 95)),
                                     "max_share_of_makespan": float(share.max()),
                                     "max_per_boom": {b: float(v.max()) for b, v in per_boom.items()}},
        "time_s": {"execute": t_exec, "total": time.perf_counter() - t_begin},
        "violations": len(violations),
    })
    out["time_s"]["episodes_and_dense"] = out["time_s"]["total"] - t_exec
    return {**out, "messages": violations, "unclear": unclear}


def _by_kind(dr: Draws, span: np.ndarray, bad: set[int]) -> dict:
    """A draws file's draws summed up per label kind: their number, makespans, violating draws."""
    out = {}
    for kind in dict.fromkeys(k for k in dr.kinds if k):
        d = np.array([i for i, k in enumerate(dr.kinds) if k == kind])
        worst = int(d[span[d].argmax()])
        out[kind] = {"draws": int(len(d)), "violating_draws": sum(1 for i in d if int(i) in bad),
                     "makespan_s": {"p50": float(np.percentile(span[d], 50)), "p95": float(np.percentile(span[d], 95)),
                                    "max": float(span[d].max()), "max_draw": dr.labels[worst],
                                    "over_nominal_max": float(span[d].max() / span[0]) if span[0] > 0 else None}}
    return out


def _nominal(acts: Actions, rows: dict[str, BoomRows], s: np.ndarray, e: np.ndarray) -> list[str]:
    msgs = []
    mk, want = float(e.max()) if len(e) else 0.0, max(float(r.t[-1]) for r in rows.values())
    if abs(mk - want) > MAKESPAN_TOL:
        msgs.append(f"execution with the model durations: makespan {mk:.3f} s, the trajectory file's {want:.3f} s "
                    f"(more than {MAKESPAN_TOL:g} s apart)")
    off = (np.abs(s - acts.t_start) > TIME_TOL) | (np.abs(e - acts.t_end) > TIME_TOL)
    for k in np.flatnonzero(off)[:MAX_MESSAGES]:
        why = " (an interlock it waits for holds it longer)" if s[k] > acts.t_start[k] else (
            " (no interlock holds it until its planned start)")
        msgs.append(f"execution with the model durations: {acts.name(k)} runs {s[k]:.6f}..{e[k]:.6f} s, planned "
                    f"{acts.t_start[k]:.6f}..{acts.t_end[k]:.6f} s{why}")
    if off.sum() > MAX_MESSAGES:
        msgs.append(f"execution with the model durations: {int(off.sum()) - MAX_MESSAGES} more actions off their "
                    "planned times")
    return msgs


def _name(acts: Actions, b: int, e: int) -> str:
    if e % 2:
        return acts.name(acts.first[b] + e // 2)
    n = acts.first[b + 1] - acts.first[b]
    p = e // 2
    where = "at park, before its first action" if p == 0 else ("at park, after its last action" if p == n
                                                              else f"standing between actions {p - 1} and {p}")
    return f"{acts.booms[b]} {where}"


def _boom_boom(st, rows, acts, dr, start, end, spacing_m, levels, floors=None):
    t0 = time.perf_counter()
    names = [b.name for b in st.booms]
    if floors is None:
        floors = episode_floors(st, rows, acts)
    planned, _, fls = floors
    t_floor = time.perf_counter() - t0
    exec_w = {}
    for b in range(len(acts.booms)):
        k = np.arange(acts.first[b], acts.first[b + 1])
        exec_w[b] = ep.executed_windows(start[:, k], end[:, k])
    msgs, unclear, close, measured, cands = [], [], 0, 0, 0
    swept, confirmed_draws, least, least_at = {}, set(), np.inf, None
    for a, b in combinations(range(len(acts.booms)), 2):
        fl = fls[(a, b)]
        measured += fl.pairs_measured
        ea, eb = np.nonzero(fl.floor < st.d_boom)
        close += len(ea)
        Sa, Ea = exec_w[a][0][:, ea], exec_w[a][1][:, ea]
        Sb, Eb = exec_w[b][0][:, eb], exec_w[b][1][:, eb]
        over = (Sa < Eb) & (Sb < Ea)
        cands += int(over.sum())
        for d, p in np.argwhere(over):  # candidates: each swept unless its window was swept already
            if int(d) in confirmed_draws and len(msgs) >= MAX_MESSAGES:
                continue  # this draw is broken and said so: the sweep would only add a message not shown
            i, j = int(ea[p]), int(eb[p])
            w0, w1 = max(Sa[d, p], Sb[d, p]), min(Ea[d, p], Eb[d, p])
            w1 = w0 if not np.isfinite(w1) else w1  # two final pauses: both stand still
            key = (a, b, i, j, round(w0 - Sa[d, p], 9) if i % 2 and not _drill(acts, a, i) else 0.0,
                   round(w0 - Sb[d, p], 9) if j % 2 and not _drill(acts, b, j) else 0.0, round(w1 - w0, 9))
            if key not in swept:
                ra = _window_rows(rows[acts.booms[a]], planned[a], i, Sa[d, p], w0, w1, _drill(acts, a, i))
                rb = _window_rows(rows[acts.booms[b]], planned[b], j, Sb[d, p], w0, w1, _drill(acts, b, j))
                pair = dataclasses.replace(st, booms=[st.booms[names.index(acts.booms[a])],
                                                      st.booms[names.index(acts.booms[b])]])
                res = Sweep(pair, {acts.booms[a]: ra, acts.booms[b]: rb}, spacing_m, levels=levels,
                            pairs_only=True).run()
                swept[key] = (float(res.sampled[0]), float(res.sampled_at[0]), bool(res.unclear),
                              float(res.certified[0]))
            low, at, not_cert, cert = swept[key]
            if low + st.d_boom < least:
                least, least_at = low + st.d_boom, dr.labels[d]
            who = (f"draw {d} ({dr.labels[d]}): booms {acts.booms[a]} and {acts.booms[b]}, "
                   f"{_name(acts, a, i)} and {_name(acts, b, j)}")
            if low < 0:
                confirmed_draws.add(int(d))
                if len(msgs) < MAX_MESSAGES:
                    msgs.append(f"executed {who}: distance {low + st.d_boom:.5f} m < d_boom {st.d_boom:g} m at "
                                f"t={at:.4f} s (executed clock)")
            elif not_cert and len(unclear) < MAX_MESSAGES:
                unclear.append(f"executed {who}: distance not certified over t={w0:.4f}..{w1:.4f} s: its floor is "
                               f"{cert + st.d_boom:.5f} m, though every sample is clear")
    n_conf = sum(1 for v in swept.values() if v[0] < 0)
    if n_conf and len(msgs) >= MAX_MESSAGES:
        msgs.append(f"executed: {len(confirmed_draws)} draw(s) break d_boom in all")
    stats = {"close_episode_pairs": int(close), "episode_cell_pairs_measured": int(measured),
             "candidates": int(cands), "windows_swept": len(swept), "windows_confirmed": int(n_conf),
             "violating_draws": len(confirmed_draws),
             "min_executed_candidate_distance_m": None if not np.isfinite(least) else float(least),
             "min_executed_candidate_draw": least_at,
             "time_floors_s": t_floor, "time_dense_s": time.perf_counter() - t0 - t_floor,
             "_violating": confirmed_draws}
    return msgs, unclear, stats
