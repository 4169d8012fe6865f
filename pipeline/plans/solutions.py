"""Solution tables: the joints, errors, clearances and status of every hole of a drill plan.

One row per hole of the plan, in the plan's order; rows the reader could not use are kept with
status ``invalid`` and their problem, so a rig engineer never loses a hole silently.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from pipeline.geometry.collision import SAFETY_KINDS
from pipeline.plans.model import COORDS, DrillPlan
from pipeline.solvers.base import SolveResult

INVALID = "invalid"
ERROR_COLUMNS = ["start_mm", "preview_mm", "hole_mm", "direction_deg"]
CLEARANCE_COLUMNS = [f"clearance_{k}_m" for k in SAFETY_KINDS]


def solution_frame(plan: DrillPlan, result: SolveResult, joint_names: list[str], method: str) -> pd.DataFrame:
    """``hole_id``, the joints (SI: rad, m), start / preview / hole-seeking error (mm), direction
    error (deg), the four clearances (m, negative = violated), ``status``, ``method``, ``problem``,
    then the plan's own extra columns (``hole_type``, ...), carried through."""
    holes = plan.holes
    err = {k: v.detach().cpu().numpy() for k, v in result.errors.items()}
    df = pd.DataFrame({"hole_id": holes["hole_id"].to_numpy()})
    df[joint_names] = result.q.detach().cpu().numpy()
    df["start_mm"], df["preview_mm"] = 1000 * err["position"], 1000 * err["preview"]
    df["hole_mm"], df["direction_deg"] = 1000 * err["hole"], np.degrees(err["orientation"])
    for kind, col in zip(SAFETY_KINDS, CLEARANCE_COLUMNS, strict=True):
        df[col] = result.clearances[kind].detach().cpu().numpy()
    df["status"], df["method"], df["problem"] = result.status, method, ""
    extras = holes[[c for c in holes.columns if c not in ("hole_id", *COORDS)]].reset_index(drop=True)
    df = pd.concat([df, extras], axis=1)
    if plan.problems:
        bad = pd.DataFrame(plan.problems_frame().groupby(["row", "hole_id"], sort=False)["message"]
                           .agg(lambda m: "; ".join(m)).reset_index())
        invalid = pd.DataFrame({"hole_id": bad["hole_id"], "status": INVALID, "method": method,
                                "problem": [f"row {r}: {m}" for r, m in zip(bad["row"], bad["message"], strict=True)]})
        df = pd.concat([df, invalid], ignore_index=True)
    return df


def status_counts(table: pd.DataFrame) -> dict[str, int]:
    from pipeline.solvers.hybrid import STATUSES

    counts = table["status"].value_counts()
    return {s: int(counts.get(s, 0)) for s in (*STATUSES, INVALID)}
