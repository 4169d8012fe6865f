"""Error and collision metrics of IK solutions (spec section 4, paper 000 Table 3)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import torch

from pipeline.geometry.collision import KINDS, SafetyModel
from pipeline.geometry.kinematics import pose_errors

ERROR_COLUMNS = {"start": "start_mm", "preview": "preview_mm", "hole": "hole_mm"}


@torch.no_grad()
def solution_table(pose: torch.Tensor, q: torch.Tensor, safety: SafetyModel) -> pd.DataFrame:
    """Per hole: start, preview and hole-seeking error (mm), direction error (deg), and
    whether the solution violates each safety distance. Evaluated in float64."""
    boom = safety.boom
    q64, pose64 = q.detach().double(), pose.detach().double()
    frames = boom.frames(q64)
    err = pose_errors(boom.pose6_from_frames(frames), pose64)
    bad = safety.violations(safety.clearances_from_frames(frames))
    cols = {col: 1000 * err[k].cpu().numpy() for k, col in ERROR_COLUMNS.items()}
    cols["direction_deg"] = np.degrees(err["direction"].cpu().numpy())
    cols.update({k: bad[k].cpu().numpy() for k in KINDS})
    cols["within_limits"] = boom.within_limits(q64).cpu().numpy()
    df = pd.DataFrame(cols)
    df["any_violation"] = df[list(KINDS)].any(axis=1)
    return df


def _stats(values: np.ndarray, prefix: str) -> dict[str, float]:
    return {
        f"{prefix}_mean": float(np.mean(values)),
        f"{prefix}_median": float(np.median(values)),
        f"{prefix}_p95": float(np.percentile(values, 95)),
        f"{prefix}_max": float(np.max(values)),
    }


def summarize(table: pd.DataFrame) -> dict[str, float]:
    """Error statistics, collision counts per kind, paper 000's average collision rate
    (sum of the four counts over all holes: a hole violating two kinds counts twice) and
    the share of holes with any violation."""
    out: dict[str, float] = {"holes": int(len(table))}
    for col in (*ERROR_COLUMNS.values(), "direction_deg"):
        out.update(_stats(table[col].to_numpy(), col))
    counts = {k: int(table[k].sum()) for k in KINDS}
    out.update({f"collisions_{k}": v for k, v in counts.items()})
    out["collision_rate_paper"] = sum(counts.values()) / len(table)
    out["any_violation_share"] = float(table["any_violation"].mean())
    out["within_limits_share"] = float(table["within_limits"].mean())
    out["solved_1mm_share"] = float((table["hole_mm"] <= 1.0).mean())
    return out


def collision_table(tables: dict[tuple[int, str], pd.DataFrame]) -> pd.DataFrame:
    """Paper 000 Table 3 layout: one row per (group, method) with self/wall/ground/arch counts."""
    rows = [{"group": g, "method": m, **{k: int(t[k].sum()) for k in KINDS}} for (g, m), t in tables.items()]
    return pd.DataFrame(rows).sort_values(["group", "method"], kind="stable").reset_index(drop=True)
