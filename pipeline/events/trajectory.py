"""A trajectory file (docs/reference.md, section 7) for a round executed by events, from the planned trajectory's rows.

The planned trajectory file holds, per boom, the rows of every action at its planned times. An
executed round runs the same actions at other times: a move's rows are the planned ones shifted to its
executed start (its motion and duration do not change), a drill's collar / drill / retract rows are
stretched by one factor (its executed duration over the planned one), and a boom that stands between
two actions (at an interlock) gets a ``wait`` row where it stands. So the realised file is made from
the planned *file*, not from the planner's state: a round read back from disk can be executed, and a
round handed on after an interruption splices the rows of two planned files
(:mod:`pipeline.events.interrupt`).

:func:`action_rows` cuts a trajectory table into each action's rows (times relative to the action's
start); :func:`retimed` lays them out at executed times.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from pipeline.core.errors import InputError
from pipeline.events.actions import Actions

TIME_TOL = 1e-6  # s: the actions file's times are the trajectory's, written from the same floats


@dataclass(frozen=True)
class Rows:
    """One action's rows: times from the action's start, joints, events and hole ids (the rows that
    begin inside ``[t_start, t_end)``; the joints at its end are the next action's first row)."""

    t: np.ndarray
    q: np.ndarray
    event: np.ndarray
    hole: np.ndarray
    q_end: np.ndarray


def _boom_rows(traj: pd.DataFrame, boom: str, joints: list[str], source: str):
    r = traj[traj["boom"] == boom]
    if r.empty:
        raise InputError(f"{source}: no rows for boom {boom!r}, which the actions file names")
    t = r["t"].to_numpy(float)
    if np.any(np.diff(t) < 0):
        raise InputError(f"{source}: boom {boom!r}: times go back")
    return (t, r[joints].to_numpy(float), r["event"].astype(str).to_numpy(),
            r["hole_id"].fillna("").astype(str).to_numpy())


def action_rows(traj: pd.DataFrame, acts: Actions, joints: list[str], source: str = "trajectory") -> list[Rows]:
    """Each action's rows of ``traj`` (the trajectory table the actions were planned with), checked:
    every move's rows lie inside its planned window and every drill's are its hole's collar, drill and
    retract rows at the hole's joints. An :class:`InputError` names the boom and the action."""
    out: list[Rows | None] = [None] * len(acts)
    for b, boom in enumerate(acts.booms):
        mine = np.flatnonzero(acts.boom == b)
        if not len(mine):
            continue
        t, q, ev, hole = _boom_rows(traj, boom, joints, source)
        for k in mine:
            t0, t1 = float(acts.t_start[k]), float(acts.t_end[k])
            lo = int(np.searchsorted(t, t0 - TIME_TOL, side="left"))
            hi = int(np.searchsorted(t, t1 - TIME_TOL, side="left"))  # rows starting before the end
            end = min(hi, len(t) - 1)  # the row at the action's end: its joints there
            name = acts.name(k)
            if acts.is_drill[k]:
                h = acts.hole_ids[acts.hole[k]]
                if hi <= lo or abs(t[lo] - t0) > TIME_TOL or ev[lo] != "collar" or np.any(hole[lo:hi] != h):
                    raise InputError(f"{source}: boom {boom!r}, {name}: no collar row of hole {h} at "
                                     f"t = {t0:.6f} s, or rows of another hole inside the drilling")
            elif hi > lo and np.any(~np.isin(ev[lo:hi], ["move", "move_unclear", "park", "wait"])):
                raise InputError(f"{source}: boom {boom!r}, {name}: rows of events "
                                 f"{sorted(set(ev[lo:hi]) - {'move', 'move_unclear', 'park', 'wait'})} inside the move")
            keep = slice(lo, hi)
            ev_k = ev[keep].copy()
            ev_k[np.isin(ev_k, ["park", "wait"])] = "move"  # a move's first row (the park row is re-made)
            out[k] = Rows(t[keep] - t0, q[keep], ev_k, hole[keep], q[end])
    return out  # type: ignore[return-value]


def retimed(acts: Actions, rows: list[Rows], start: np.ndarray, end: np.ndarray, joints: list[str],
            first_q: list[np.ndarray] | None = None) -> pd.DataFrame:
    """The trajectory table of the actions executed at ``start`` / ``end`` (one draw). ``first_q``: per
    boom its joints before its first action (default: that action's first row); a boom with no action
    is left out (it stands at park throughout, as in the planned file)."""
    frames = []
    for b, boom in enumerate(acts.booms):
        mine = np.flatnonzero(acts.boom == b)
        if not len(mine):
            continue
        q0 = rows[mine[0]].q[0] if first_q is None or first_q[b] is None else first_q[b]
        ts, qs, ev, hid = [np.zeros(1)], [q0[None]], [np.array(["park"])], [np.array([""])]
        ready, q_cur = 0.0, q0
        for k in mine:
            r = rows[k]
            t0, t1 = float(start[k]), float(end[k])
            if t0 > ready + TIME_TOL and k != mine[0]:
                ts.append(np.array([ready])), qs.append(q_cur[None]), ev.append(np.array(["wait"]))
                hid.append(np.array([""]))
            planned = float(acts.t_end[k] - acts.t_start[k])
            scale = (t1 - t0) / planned if acts.is_drill[k] and planned > 0 else 1.0
            if len(r.t):
                ts.append(t0 + r.t * scale), qs.append(r.q), ev.append(r.event), hid.append(r.hole)
            ready, q_cur = t1, r.q_end
        ts.append(np.array([ready])), qs.append(q_cur[None]), ev.append(np.array(["done"])), hid.append(np.array([""]))
        df = pd.DataFrame(np.concatenate(qs), columns=joints)
        df.insert(0, "t", np.concatenate(ts))
        df.insert(0, "boom", boom)
        df["event"], df["hole_id"] = np.concatenate(ev), np.concatenate(hid)
        # equal instants (a move starting at 0, a phase of 0 s): the first row of the instant names it,
        # as in the planned file (pipeline.round.tables.trajectory_table)
        frames.append(df[~df["t"].duplicated(keep="first")].reset_index(drop=True))
    return pd.concat(frames, ignore_index=True)
