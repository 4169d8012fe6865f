"""What was drilled against what was planned: per hole, how far the rig's collar and toe landed from the plan's.

Both in the plan frame (a quality log reports there, :mod:`pipeline.plans.drpqual`), matched by hole id. Per
hole (docs/reference.md, "The as-drilled log"): the collar deviation (m), the toe deviation (m), the direction
error (degrees, between the planned and the drilled collar-to-toe vectors), the length error (m, drilled less
planned: negative is short), and **within** tolerance when the collar is at most ``collar_tol_m`` (0.1 m) off and
the toe at most ``toe_tol_share`` (6 %) of the planned length. A planned hole missing from the log is reported
``not drilled`` (never within); a logged hole not in the plan is listed, never silently dropped. Vectorised over
holes.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from pipeline.plans.model import COLLAR, TOE

QUALITY_COLUMNS = ["hole_id", "boom", "status", "collar_dev_m", "toe_dev_m", "direction_err_deg", "length_err_m",
                   "within"]
NOT_DRILLED = "not drilled"


def deviations(plan_holes: pd.DataFrame, log_holes: pd.DataFrame, collar_tol_m: float = 0.1,
               toe_tol_share: float = 0.06) -> tuple[pd.DataFrame, dict]:
    """The per-hole table (``QUALITY_COLUMNS``, in the plan's order) and the summary: holes planned, logged,
    drilled within tolerance (count and share of the plan), mean and p95 of the deviations over the holes
    both name, the plan's holes missing from the log and the log's holes the plan does not have."""
    plan = plan_holes.reset_index(drop=True)
    ids = plan["hole_id"].astype(str)
    log = log_holes.assign(hole_id=log_holes["hole_id"].astype(str)).set_index("hole_id")
    found = ids.isin(log.index).to_numpy()
    got = log.reindex(ids)
    p_col, p_toe = plan[COLLAR].to_numpy(float), plan[TOE].to_numpy(float)
    d_col, d_toe = got[COLLAR].to_numpy(float), got[TOE].to_numpy(float)
    planned, drilled = p_toe - p_col, d_toe - d_col
    p_len, d_len = np.linalg.norm(planned, axis=1), np.linalg.norm(drilled, axis=1)
    cos = np.einsum("ij,ij->i", planned, drilled) / np.maximum(p_len * d_len, 1e-300)
    collar_dev = np.linalg.norm(d_col - p_col, axis=1)
    toe_dev = np.linalg.norm(d_toe - p_toe, axis=1)
    table = pd.DataFrame({
        "hole_id": ids, "boom": got["boom"].fillna("").to_numpy(),
        "status": np.where(found, got["status"].fillna("").to_numpy(), NOT_DRILLED),
        "collar_dev_m": collar_dev, "toe_dev_m": toe_dev,
        "direction_err_deg": np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))), "length_err_m": d_len - p_len,
        "within": found & (collar_dev <= collar_tol_m) & (toe_dev <= toe_tol_share * p_len)})
    extra = sorted(set(log.index) - set(ids))
    both = table[found]

    def stats(col: str) -> dict:
        v = both[col].to_numpy(float)
        return {"mean": float(v.mean()), "p95": float(np.percentile(v, 95)), "max": float(v.max())} if len(v) else \
            {"mean": None, "p95": None, "max": None}

    summary = {
        "holes_planned": len(plan), "holes_logged": int(len(log)), "holes_matched": int(found.sum()),
        "within": int(table["within"].sum()), "within_share": float(table["within"].mean()) if len(plan) else 0.0,
        "collar_tol_m": collar_tol_m, "toe_tol_share": toe_tol_share,
        **{f"{k}_{s}": v for k in ("collar_dev_m", "toe_dev_m", "direction_err_deg", "length_err_m")
           for s, v in stats(k).items()},
        "missing_from_log": ids[~found].tolist(), "not_in_plan": extra,
    }
    return table[QUALITY_COLUMNS], summary


def face_coordinates(plan_holes: pd.DataFrame) -> np.ndarray:
    """``(n, 2)`` collars seen along the plan's mean hole direction (across, up): a face view in any plan frame
    with z up, a mine grid included."""
    collar, toe = plan_holes[COLLAR].to_numpy(float), plan_holes[TOE].to_numpy(float)
    ahead = (toe - collar).mean(axis=0)
    ahead /= np.linalg.norm(ahead)
    across = np.cross([0.0, 0.0, 1.0], ahead)
    across = across / np.linalg.norm(across) if np.linalg.norm(across) > 1e-9 else np.array([0.0, 1.0, 0.0])
    up = np.cross(ahead, across)
    centred = collar - collar.mean(axis=0)
    return np.stack([centred @ across, centred @ up], axis=1)
