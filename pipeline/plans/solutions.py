"""Solution tables: the joints, errors, clearances and status of every hole of a drill plan.

One row per hole of the plan, in the plan's order; rows the reader could not use are kept with
status ``invalid`` and their problem, so a rig engineer never loses a hole silently.
"""

from __future__ import annotations

import re

import numpy as np
import pandas as pd
import torch

from pipeline.geometry.collision import SAFETY_KINDS
from pipeline.plans.model import COORDS, DrillPlan
from pipeline.solvers.base import SolveResult

INVALID = "invalid"
ERROR_COLUMNS = ["start_mm", "preview_mm", "hole_mm", "direction_deg"]
CLEARANCE_COLUMNS = [f"clearance_{k}_m" for k in SAFETY_KINDS]
SOLVED_COLUMNS = [f"solved_{c}" for c in COORDS]  # the hole the joints drill, in the plan's frame


def solved_holes(plan: DrillPlan, collar: torch.Tensor, direction: torch.Tensor) -> np.ndarray:
    """``(n, 6)``: the collar and toe the solved joints drill (the tool point, and the planned length along
    the drilling direction), from rig-frame ``collar`` and ``direction`` ``(n, 3)``, in the plan's frame
    (:attr:`DrillPlan.navigation`)."""
    xyz = plan.holes[COORDS].to_numpy(dtype=np.float64)
    length = np.linalg.norm(xyz[:, 3:] - xyz[:, :3], axis=1, keepdims=True)
    p, z = collar.detach().cpu().double().numpy(), direction.detach().cpu().double().numpy()
    rig = np.concatenate([p, p + length * z], axis=1)
    return rig if plan.navigation is None else plan.navigation.to_plan(rig)


def solution_frame(plan: DrillPlan, result: SolveResult, joint_names: list[str], method: str,
                   solved: np.ndarray | None = None) -> pd.DataFrame:
    """``hole_id``, the joints (SI: rad, m), start / preview / hole-seeking error (mm), direction
    error (deg), the four clearances (m, negative = violated), ``status``, ``method``, ``problem``,
    the collar and toe the joints drill in the plan's frame (``solved``, :func:`solved_holes`; columns
    :data:`SOLVED_COLUMNS`), then the plan's own extra columns (``hole_type``, ...), carried through.

    One row per row of the plan, in the plan's order (by line in the file): an invalid row stands
    where it stood, with its own columns and a problem naming its line and column(s)."""
    holes = plan.holes
    err = {k: v.detach().cpu().numpy() for k, v in result.errors.items()}
    df = pd.DataFrame({"hole_id": holes["hole_id"].to_numpy()})
    df[joint_names] = result.q.detach().cpu().numpy()
    df["start_mm"], df["preview_mm"] = 1000 * err["position"], 1000 * err["preview"]
    df["hole_mm"], df["direction_deg"] = 1000 * err["hole"], np.degrees(err["orientation"])
    for kind, col in zip(SAFETY_KINDS, CLEARANCE_COLUMNS, strict=True):
        df[col] = result.clearances[kind].detach().cpu().numpy()
    df["status"], df["method"], df["problem"] = result.status, method, ""
    if solved is not None:
        df[SOLVED_COLUMNS] = solved
    extras = holes[[c for c in holes.columns if c not in ("hole_id", *COORDS)]].reset_index(drop=True)
    df = pd.concat([df, extras], axis=1)
    if not plan.problems:
        return df
    lines = np.arange(len(df)) if plan.lines is None else np.asarray(plan.lines)
    by_row: dict[int, list[str]] = {}
    for p in plan.problems:
        by_row.setdefault(p.row, []).append(f"{p.column}: {p.message}")
    if plan.rejected is not None:
        rejected = plan.rejected.reset_index(drop=True)
    else:  # a plan built by hand: only the problems are known
        rejected = pd.DataFrame({"hole_id": [p.hole_id for p in plan.problems], "line": [p.row for p in plan.problems]})
        rejected = rejected.drop_duplicates("line")
    invalid = rejected.drop(columns="line").assign(
        status=INVALID, method=method,
        problem=[f"row {r}: " + "; ".join(by_row.get(int(r), [])) for r in rejected["line"]])
    order = np.argsort(np.concatenate([lines, rejected["line"].to_numpy()]), kind="stable")
    return pd.concat([df, invalid], ignore_index=True).iloc[order].reset_index(drop=True)[list(df.columns)]


_FORMULA = re.compile(r"^[=+\-@\t\r]")
_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$")
_CONTROL = re.compile(r"[\x00-\x08\x0b-\x1f\x7f-\x9f]")


def spreadsheet_safe(table: pd.DataFrame) -> pd.DataFrame:
    """The table as it is written to CSV: a text cell a spreadsheet would evaluate (``=``, ``+``, ``-``,
    ``@`` first, unless a plain number) gets a leading ``'`` and control characters are written as
    ``\\xNN``, so opening the solution runs nothing. Solved rows never need it (such ids are row
    problems); invalid rows and carried text columns may."""
    out = table.copy()
    for col in out.columns:
        if not (out[col].dtype == object or pd.api.types.is_string_dtype(out[col].dtype)):
            continue
        text = out[col].map(lambda v: v if not isinstance(v, str) else _CONTROL.sub(
            lambda m: f"\\x{ord(m.group()):02x}", v))
        out[col] = text.map(lambda v: f"'{v}" if isinstance(v, str) and _FORMULA.match(v) and not _NUMBER.match(v)
                            else v)
    return out


def status_counts(table: pd.DataFrame) -> dict[str, int]:
    from pipeline.solvers.hybrid import STATUSES

    counts = table["status"].value_counts()
    return {s: int(counts.get(s, 0)) for s in (*STATUSES, INVALID)}
