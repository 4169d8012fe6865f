"""The files of an executed round beyond the trajectory: its round table, its summary, the draws file.

- round table (the planned round table's columns): per plan hole its boom, order, the executed
  ``t_start`` / ``t_end`` of its drilling, the joints it was drilled at and its status: ``ok``,
  ``interrupted`` (stopped before its end: left undrilled, reported), or the planned table's own status
  and reason for a hole the round never drilled (unreachable, invalid rows);
- summary: the realised makespan against the nominal one, each boom's standing at interlocks, the holes
  that ran long (factor > 1), the holes left;
- draws file ``<stem>_draws.csv`` (``draw, label, hole_id, factor``, one row per draw and drilled hole):
  the factors the Monte Carlo executed, for the independent checker (``--draws``).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from pipeline.events.actions import Actions
from pipeline.events.draws import Draws
from pipeline.events.trajectory import Rows

LONG_SHOWN = 10  # the holes that ran longest, named in the summary


def executed_round_table(acts: Actions, start: np.ndarray, end: np.ndarray, rows: list[Rows],
                         planned: pd.DataFrame, joint_names: list[str], interrupted: set[int]) -> pd.DataFrame:
    """The round table of an executed round (module docstring); ``planned``: the planned round table
    (its rows give the holes never drilled their status); ``interrupted``: drill actions stopped early."""
    out = planned.copy()
    out["order"] = out["order"].astype("Int64")
    where = {h: i for i, h in enumerate(out["hole_id"].astype(str))}
    drills = np.flatnonzero(acts.is_drill)
    order = np.zeros(len(acts), int)
    for b in range(len(acts.booms)):  # a few booms
        mine = drills[acts.boom[drills] == b]
        order[mine] = np.arange(1, len(mine) + 1)
    drilled = set()
    for k in drills:  # one row per drilled hole
        h = acts.hole_ids[acts.hole[k]]
        i = where[h]
        drilled.add(i)
        out.loc[i, "boom"] = acts.booms[acts.boom[k]]
        out.loc[i, "order"] = int(order[k])
        out.loc[i, "t_start"], out.loc[i, "t_end"] = float(start[k]), float(end[k])
        out.loc[i, list(joint_names)] = rows[k].q[0]
        stopped = int(k) in interrupted
        out.loc[i, "status"] = "interrupted" if stopped else "ok"
        out.loc[i, "reason"] = (f"interrupted {end[k] - start[k]:.1f} s into its drilling: left undrilled"
                                if stopped else "")
    for i in range(len(out)):  # planned to be drilled, not drilled now: cannot happen (every hole is one action)
        if i not in drilled and out.loc[i, "status"] == "ok":
            out.loc[i, "status"], out.loc[i, "reason"] = "not drilled", "not in the executed round"
            out.loc[i, ["boom", "order", "t_start", "t_end"]] = ["", pd.NA, np.nan, np.nan]
    return out


def long_holes(acts: Actions, planned_s: np.ndarray, start: np.ndarray, end: np.ndarray,
               skip: set[int]) -> list[dict]:
    """The drills that took longer than planned, longest over-run first (at most ``LONG_SHOWN``)."""
    drills = [k for k in np.flatnonzero(acts.is_drill) if int(k) not in skip]
    k = np.array(drills, int)
    if not len(k):
        return []
    took = end[k] - start[k]
    plan = planned_s[acts.hole[k]]
    over = took - plan
    pick = np.argsort(-over, kind="stable")[:LONG_SHOWN]
    return [{"hole_id": acts.hole_ids[acts.hole[k[i]]], "boom": acts.booms[acts.boom[k[i]]],
             "factor": float(took[i] / plan[i]), "over_s": float(over[i])} for i in pick if over[i] > 1e-9]


def draws_table(acts: Actions, d: Draws) -> pd.DataFrame:
    """The draws file: one row per draw and drilled hole (module docstring)."""
    drilled = np.unique(acts.hole[acts.is_drill])
    D = len(d.labels)
    return pd.DataFrame({"draw": np.repeat(np.arange(D), len(drilled)),
                         "label": np.repeat(np.asarray(d.labels, dtype=object), len(drilled)),
                         "hole_id": np.tile(np.asarray(acts.hole_ids, dtype=object)[drilled], D),
                         "factor": d.factors[:, drilled].reshape(-1)})
