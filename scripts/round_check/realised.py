"""A realised round (``--realised``): the files of a round as it was executed, judged as written.

The executed trajectory is checked like a planned one (limits, speeds, park, clearances at every
instant, holes at their joints), but its drills last what the rock took (:func:`round_check.rules.holes`
with ``realised``). With its actions and interlocks files, the execution itself: each boom's rows
follow its actions in order at the actions file's (realised) times (:func:`round_check.actions.agree`:
moves start at their t_start, drills at theirs, the boom still between them), each drill action lasts
the trajectory's drilling of its hole, and every interlock held in those times (the waiting action
starts no earlier than the one it waits for ends); with a zones file, no two booms were inside one zone
at once (two sections of one zone, of two booms, overlap by more than the time tolerance). Nothing is
re-executed with model durations: the times are the rock's, not the model's. A disagreement is a
violation (exit 1) here, not an input error: the realised set is what is judged, and an execute stage that
writes its times wrong has failed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .actions import TIME_TOL, Actions, Interlocks, Zones, agree
from .errors import InputError
from .files import BoomRows

MAX_MESSAGES = 20


def follow(acts: Actions, locks: Interlocks, zones: Zones, rows: dict[str, BoomRows], trajectory: Path,
           interrupted: frozenset) -> tuple[list[str], dict]:
    """Violations of the realised execution, and its summary for the JSON."""
    msgs = _drill_durations(acts, rows, trajectory)
    try:
        agree(acts, rows, trajectory, uncollared=interrupted)
    except InputError as e:  # the first place the rows leave the actions: one message says where
        msgs.append(f"the boom's rows do not follow its actions: {e}")
    wait = acts.t_start[locks.after] - acts.t_end[locks.before]  # >= 0: the interlock held
    broken = np.flatnonzero(wait < -TIME_TOL)
    for i in broken[:MAX_MESSAGES]:
        a, b = locks.after[i], locks.before[i]
        msgs.append(f"interlock {locks.path} row {locks.line[i]}: {acts.name(a)} starts at {acts.t_start[a]:.6f} s, "
                    f"{-wait[i]:.6f} s before {acts.name(b)} ends ({acts.t_end[b]:.6f} s; {acts.path} rows "
                    f"{acts.line[a]}, {acts.line[b]})")
    if len(broken) > MAX_MESSAGES:
        msgs.append(f"{len(broken) - MAX_MESSAGES} more interlocks broken by the realised times ({locks.path})")
    shared = 0
    for i in range(len(zones)):
        for j in range(i + 1, len(zones)):
            if zones.zone[i] != zones.zone[j] or zones.boom[i] == zones.boom[j]:
                continue
            lo = max(acts.t_start[zones.first[i]], acts.t_start[zones.first[j]])
            hi = min(acts.t_end[zones.last[i]], acts.t_end[zones.last[j]])
            if hi - lo > TIME_TOL:
                shared += 1
                if shared <= MAX_MESSAGES:
                    msgs.append(f"zone {zones.zone[i]!r}: booms {acts.booms[zones.boom[i]]} and "
                                f"{acts.booms[zones.boom[j]]} both inside it over t={lo:.6f}..{hi:.6f} s "
                                f"({zones.path} rows {zones.line[i]}, {zones.line[j]})")
    return msgs, {
        "checked": True, "mode": "realised: the actions' times held against the trajectory and the interlocks; "
                                 "no re-execution with model durations",
        "actions": str(acts.path), "interlocks": str(locks.path),
        "actions_per_boom": {b: int(n) for b, n in zip(acts.booms, np.diff(acts.first), strict=True)},
        "interlock_rows": int(len(locks.after)), "interlocks_broken": int(len(broken)),
        "least_interlock_slack_s": float(wait.min()) if len(wait) else None,
        "zone_sections": len(zones), "zones_shared": shared,
        "violations": len(msgs)}


def _drill_durations(acts: Actions, rows: dict[str, BoomRows], trajectory: Path) -> list[str]:
    """Each drill action lasts its hole's drilling in the trajectory (collar row to the end of the
    retraction, three rows on); a hole its boom never collars is left to :func:`agree`."""
    msgs = []
    for b, name in enumerate(acts.booms):
        r = rows[name]
        k = np.arange(acts.first[b], acts.first[b + 1])
        k = k[acts.kind[k] == "drill"]
        collars = np.flatnonzero((r.event == "collar") & (np.arange(len(r.t)) + 3 < len(r.t)))
        at = dict(zip(r.hole[collars], collars, strict=False))
        for i in k:
            c = at.get(acts.hole[i])
            if c is None:
                continue
            traj_s, act_s = r.t[c + 3] - r.t[c], acts.t_end[i] - acts.t_start[i]
            if abs(traj_s - act_s) > TIME_TOL:
                msgs.append(f"boom {name}, hole {acts.hole[i]}: its drill action ({acts.path} row {acts.line[i]}) "
                            f"lasts {act_s:.6f} s, its drilling in {trajectory} {traj_s:.6f} s (rows "
                            f"{r.line[c]}-{r.line[c + 3]}, t={r.t[c]:.6f}..{r.t[c + 3]:.6f} s)")
    return msgs
