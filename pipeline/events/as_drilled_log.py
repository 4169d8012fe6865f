"""The executed round's as-drilled log: each hole the round started, where the rig really drilled it.

"As drilled" is through the rig's real kinematics (docs/reference.md, "The as-drilled log"): the collar is the
tool point of the joints the boom held while drilling, computed by the boom the rig really has
(``execute.true_boom`` / ``execute.true_boom_model``: a boom config or a calibrated model file; by default
the model the round was planned with), the toe is at the hole's drilled length along that boom's drilling
direction. A hole stopped early is logged ``Interrupted``, its toe at the depth its drilling had reached (its
time at the drill, less collaring, at its penetration rate, both scaled by how slow its rock was). Points go
to the plan frame by the navigation the plan was read with; times are ISO 8601 from the round's start
(``execute.start_time``). Batched per boom: one forward kinematics call for all its holes.
"""

from __future__ import annotations

from datetime import datetime, timedelta

import numpy as np
import pandas as pd
import torch

from pipeline.events.actions import Actions
from pipeline.geometry.kinematics import Boom
from pipeline.plans.drpqual import LOG_COLUMNS
from pipeline.plans.model import COORDS, DrillPlan


def drilled_holes(acts: Actions, rows, start: np.ndarray, end: np.ndarray, plan: DrillPlan, bases: np.ndarray,
                  true_booms: list[Boom], interrupted: set[int], factor: np.ndarray, collaring_s: float,
                  rate_m_per_s: float, start_time: datetime) -> pd.DataFrame:
    """``LOG_COLUMNS`` rows, one per drill action of ``acts`` (in the order they started), in the plan frame.

    ``rows``: each action's trajectory rows (a drill's joints are constant); ``start``, ``end``: the executed
    times; ``bases (booms, 3)``: each boom's base in the rig frame; ``true_booms``: the boom each rig boom really
    is; ``interrupted``: drill actions stopped early; ``factor (holes,)``: each hole's drilling-time factor."""
    drills = np.flatnonzero(acts.is_drill)
    drills = drills[np.argsort(start[drills], kind="stable")]
    xyz = plan.holes[COORDS].to_numpy(np.float64)
    length = np.linalg.norm(xyz[:, 3:] - xyz[:, :3], axis=1)  # the plan's lengths (rig frame: the same)
    collar, direction = np.zeros((len(drills), 3)), np.zeros((len(drills), 3))
    for b, boom in enumerate(true_booms):  # a loop over booms; each boom's holes in one batch
        mine = np.flatnonzero(acts.boom[drills] == b)
        if not len(mine):
            continue
        q = torch.tensor(np.stack([rows[k].q[0] for k in drills[mine]]), dtype=torch.float64)
        with torch.no_grad():
            p, z = boom.tool_pose(q)
        collar[mine] = p.numpy() + bases[b]
        direction[mine] = z.numpy()
    holes = acts.hole[drills]
    stopped = np.isin(drills, sorted(interrupted))
    took = end[drills] - start[drills]
    reached = np.clip((took / factor[holes] - collaring_s) * rate_m_per_s, 0.0, length[holes])
    depth = np.where(stopped, reached, length[holes])
    rig_points = np.concatenate([collar, collar + depth[:, None] * direction], axis=1)
    points = rig_points if plan.navigation is None else plan.navigation.to_plan(rig_points)
    ids = np.asarray(acts.hole_ids, dtype=object)[holes]
    stamp = lambda t: [(start_time + timedelta(seconds=float(s))).isoformat(timespec="milliseconds")  # noqa: E731
                       for s in t]
    booms = np.asarray(acts.booms, dtype=object)[acts.boom[drills]]
    out = pd.DataFrame({"hole_id": ids, "hole_name": ids, "boom": booms,
                        "status": np.where(stopped, "Interrupted", "Drilled")})
    out[COORDS] = points
    out["start_time"], out["end_time"] = stamp(start[drills]), stamp(end[drills])
    return out[LOG_COLUMNS]
