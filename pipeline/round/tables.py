"""The round's tables: the round table, the reference's trajectory table, and the summary.

- round table: ``hole_id, boom, order, t_start, t_end, q1 .. qn, status, reason``, one row per plan
  hole in plan order; ``t_start``/``t_end`` bound the drilling (collaring to the end of retraction);
  a hole no boom can drill keeps its row (``status = unreachable``, its reason, no boom, no times);
- trajectory table (docs/reference.md, section 7): ``boom, t, q1 .. qn, event, hole_id``, every boom from park to
  park; a row's event names what starts there (park, move, collar, drill, retract, wait, done;
  ``move_unclear``: a move no attempt made certified clear, kept as its straight line: an extension of
  the reference's events, so that no reader takes it for a checked move).
  Moves are the oracle's (the synchronised straight line, or the move's detour: retract or planned,
  stopping at each waypoint), sampled by :meth:`pipeline.round.oracle.KinematicOracle.rows` within
  ``traj_tol_m`` of the planned motion; full-turn
  joints stay continuous along the file (they may leave [-180, 180] degrees). A boom done before the
  makespan stays at its last row.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import torch

from pipeline.round.problem import Instance
from pipeline.round.timeline import Timeline, boom_times


def round_table(inst: Instance, tl: Timeline, joints, joint_names) -> pd.DataFrame:
    H = inst.n_holes
    rows = {h: {"hole_id": inst.hole_ids[h], "boom": "", "order": np.nan, "t_start": np.nan, "t_end": np.nan,
                **{n: np.nan for n in joint_names}, "status": "unreachable", "reason": inst.reason(h)}
            for h in range(H)}
    for b, route in enumerate(tl.routes):
        q = np.asarray(joints[b])
        for k, h in enumerate(route):
            start = tl.drill_at(b, k)
            rows[h].update({"boom": inst.booms[b], "order": k + 1, "t_start": start,
                            "t_end": start + float(inst.drill_s[h]), "status": "ok", "reason": ""})
            rows[h].update(dict(zip(joint_names, q[h].tolist(), strict=True)))
    out = pd.DataFrame([rows[h] for h in range(H)])
    out["order"] = out["order"].astype("Int64")
    return out


def trajectory_table(inst: Instance, tl: Timeline, oracle, joint_names, unclear=()) -> pd.DataFrame:
    """``unclear``: moves ``(boom, from, to)`` whose rows are marked ``move_unclear`` (node H: park)."""
    H, frames = inst.n_holes, []
    unclear = {(int(b), int(u), int(v)) for b, u, v in unclear}
    for b, route in enumerate(tl.routes):
        node = tl.start_node(b)  # park, or where the boom stood when the round was handed on
        q_cur = oracle.joints[b][node].clone()
        ts, qs, ev, hid = [0.0], [q_cur.numpy()], ["park" if node == H else "wait"], [""]
        ready = 0.0
        for k, tgt in enumerate([*route, H]):
            ms, ar = float(tl.move_start[b][k]), float(tl.arrive[b][k])
            if ms > ready + 1e-9 and k > 0:  # a wait, not the rounding of a re-timed round
                ts.append(ready), qs.append(q_cur.numpy()), ev.append("wait"), hid.append("")
            if ar > ms:
                rt, rq = oracle.rows(b, node, tgt, q_cur)
                event = "move_unclear" if (b, node, tgt) in unclear else "move"
                for t, q in zip(rt[:-1], rq[:-1], strict=True):
                    ts.append(ms + float(t)), qs.append(q), ev.append(event), hid.append("")
                q_cur = torch.as_tensor(rq[-1])
            if tgt == H:
                ts.append(ar), qs.append(q_cur.numpy()), ev.append("done"), hid.append("")
                break
            t, name = tl.drill_at(b, k), inst.hole_ids[tgt]
            if t > ar + 1e-9:  # standing at the hole before drilling it (an interlock)
                ts.append(ar), qs.append(q_cur.numpy()), ev.append("wait"), hid.append("")
            for phase, dur in zip(("collar", "drill", "retract"), inst.phases[tgt], strict=True):
                ts.append(t), qs.append(q_cur.numpy()), ev.append(phase), hid.append(name)
                t += float(dur)
            ready, node = t, tgt
        df = pd.DataFrame(np.asarray(qs), columns=list(joint_names))
        df.insert(0, "t", ts)
        df.insert(0, "boom", inst.booms[b])
        df["event"], df["hole_id"] = ev, hid
        # equal instants (a move starting at 0, a phase of 0 s): the first row of the instant names it;
        # a round handed on to a boom that drills first where it stands starts with that collar row
        keep = ~df["t"].duplicated(keep="first")
        if tl.start_node(b) != H and len(df) > 1 and df["t"].iloc[1] == df["t"].iloc[0]:
            keep.iloc[0], keep.iloc[1] = False, True
        frames.append(df[keep])
    return pd.concat(frames, ignore_index=True)


def round_status(inst: Instance, tl: Timeline) -> str:
    """``complete``: every hole of the plan drilled; ``partial``: some no boom can drill (their rows say
    why); ``none drillable``: no boom can drill any hole, so there is no round (every boom stays at park)."""
    drilled = sum(len(r) for r in tl.routes)
    if drilled == 0:
        return "none drillable"
    return "complete" if drilled == inst.n_holes else "partial"


def boom_floor(tl: Timeline, oracle_floor: float) -> float | None:
    """The certified floor of boom-boom clearance (m, less d_boom) over the timeline, or None (one boom,
    or conflicts left: nothing certified). Wherever a boom moves the oracle proves at least its floor
    (2 traj_tol_m) at every instant; a pair standing still is exact (no motion, rows exact) and was
    measured: so with no conflict left, every sample below the floor is a standing pair's exact value."""
    if not np.isfinite(tl.min_clearance) or tl.conflicts_left:
        return None
    return float(min(oracle_floor, tl.min_clearance))


def summary(inst: Instance, tl: Timeline, lower_bound_s: float, naive: Timeline | None, nearest: Timeline | None,
            bases, d_boom: float, move_kinds: dict | None = None, **extra) -> dict:
    booms = {}
    for b, name in enumerate(inst.booms):
        t = boom_times(inst, tl, b)
        booms[name] = {"base": [float(v) for v in bases[b]], "drilling_s": t["drilling_s"], "moving_s": t["moving_s"],
                       "waiting_s": t["waiting_s"], "holes": t["holes"]}
    n_moves = sum(len(r) + 1 for r in tl.routes)
    out = {
        "makespan_s": tl.makespan,
        "lower_bound_s": lower_bound_s,
        # None when no hole is drillable (no round: 0 / 0); JSON has no NaN
        "makespan_over_bound": tl.makespan / lower_bound_s if lower_bound_s > 0 else None,
        "status": round_status(inst, tl),
        "naive_makespan_s": naive.makespan if naive is not None else None,
        "nearest_makespan_s": nearest.makespan if nearest is not None else None,
        # None for one boom (no pair): JSON has no infinity
        "min_boom_clearance_m": tl.min_clearance + d_boom if np.isfinite(tl.min_clearance) else None,
        "d_boom_m": d_boom,
        "conflicts_left": tl.conflicts_left,
        "waits_inserted": len(tl.repairs),
        "sequential_fallback": tl.sequential,
        "holes_drilled": sum(len(r) for r in tl.routes),
        "holes_unreachable": int((~inst.drillable).sum()),
        "booms": booms,
        "moves": move_kinds if move_kinds is not None else {"straight": n_moves},
    }
    out.update(extra)
    return out
