"""Error and collision metrics of IK solutions (docs/reference.md, section 4; paper 000 Table 3)."""

from __future__ import annotations

import statistics
import time
from dataclasses import dataclass

import numpy as np
import pandas as pd
import torch

from pipeline.data.tables import holes_frame, joints_frame
from pipeline.geometry.collision import SAFETY_KINDS, SafetyModel
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
    cols.update({k: bad[k].cpu().numpy() for k in SAFETY_KINDS})
    cols["within_limits"] = boom.within_limits(q64).cpu().numpy()
    df = pd.DataFrame(cols)
    df["any_violation"] = df[list(SAFETY_KINDS)].any(axis=1)
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
    counts = {k: int(table[k].sum()) for k in SAFETY_KINDS}
    out.update({f"collisions_{k}": v for k, v in counts.items()})
    out["collision_rate_paper"] = sum(counts.values()) / len(table)
    out["any_violation_share"] = float(table["any_violation"].mean())
    out["within_limits_share"] = float(table["within_limits"].mean())
    out["solved_1mm_share"] = float((table["hole_mm"] <= 1.0).mean())
    return out


def collision_table(tables: dict[tuple[int, str], pd.DataFrame]) -> pd.DataFrame:
    """Paper 000 Table 3 layout: one row per (group, method) with self/wall/ground/arch counts."""
    rows = [{"group": g, "method": m, **{k: int(t[k].sum()) for k in SAFETY_KINDS}} for (g, m), t in tables.items()]
    return pd.DataFrame(rows).sort_values(["group", "method"], kind="stable").reset_index(drop=True)


def summary_frame(metrics: dict[str, dict]) -> pd.DataFrame:
    """One row per method with its scalar metrics (nested values left out)."""
    return pd.DataFrame([{"method": m, **{k: v for k, v in d.items() if not isinstance(v, dict)}}
                         for m, d in metrics.items()])


@torch.no_grad()
def solve_time_per_1000(model, pose: torch.Tensor, repeats: int) -> float:
    """Median wall time (ms) of one batched forward pass, scaled to 1 000 holes."""
    x = pose.float()
    model(x)  # warm-up
    times = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        model(x)
        times.append(time.perf_counter() - t0)
    return 1000 * statistics.median(times) * 1000 / len(x)


@dataclass
class MethodEvaluation:
    """One network on every test group: per-group solution tables and predictions, the metrics
    over all groups, and its training history (from the checkpoint)."""

    tables: dict[int, pd.DataFrame]
    predictions: dict[int, pd.DataFrame]
    metrics: dict
    history: pd.DataFrame

    def all_errors_mm(self) -> np.ndarray:
        return pd.concat(self.tables.values(), ignore_index=True)["hole_mm"].to_numpy()


@torch.no_grad()
def evaluate_network(model, meta: dict, safety: SafetyModel, groups: dict, repeats: int) -> MethodEvaluation:
    """Solve every test group in one forward pass each; score in float64. ``repeats = 0``: no timing."""
    tables, predictions = {}, {}
    for k, (df, pose) in groups.items():
        q = model(pose.float()).double()
        tables[k] = solution_table(pose, q, safety)
        predictions[k] = pd.concat([holes_frame(pose, df["hole_id"].to_numpy()),
                                    joints_frame(q, safety.boom.joint_names)], axis=1)
    all_pose = torch.cat([pose for _, pose in groups.values()])
    metrics = {**summarize(pd.concat(tables.values(), ignore_index=True)),
               **({"solve_ms_per_1000": solve_time_per_1000(model, all_pose, repeats)} if repeats > 0 else {}),
               "per_group_hole_mm_mean": {k: float(t["hole_mm"].mean()) for k, t in tables.items()}}
    return MethodEvaluation(tables, predictions, metrics, pd.DataFrame(meta.get("history", [])))
