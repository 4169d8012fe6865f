"""Hole and joint tables on disk: column names, validation, atomic writes."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from pipeline.core.errors import InputError

POSE_COLUMNS = ["collar_x", "collar_y", "collar_z", "preview_x", "preview_y", "preview_z"]
COLLAR_COLUMNS = ["collar_x", "collar_y", "collar_z"]
TOE_COLUMNS = ["toe_x", "toe_y", "toe_z"]  # a hole's end point, in tables that give one (drill plans)


def holes_frame(poses: torch.Tensor, hole_ids: Sequence[int] | None = None) -> pd.DataFrame:
    """``hole_id`` plus the six pose columns (metres, base frame)."""
    arr = poses.detach().cpu().double().numpy()
    ids = np.arange(len(arr), dtype=np.int64) if hole_ids is None else np.asarray(hole_ids, dtype=np.int64)
    df = pd.DataFrame(arr, columns=POSE_COLUMNS)
    df.insert(0, "hole_id", ids)
    return df


def joints_frame(q: torch.Tensor, names: Sequence[str]) -> pd.DataFrame:
    return pd.DataFrame(q.detach().cpu().double().numpy(), columns=list(names))


def check_table(df: pd.DataFrame, columns: Sequence[str], source: str) -> None:
    """Raise :class:`InputError` naming the file, column and row of the first problem."""
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise InputError(f"{source}: missing column(s) {missing}; found {list(df.columns)}")
    for col in columns:
        values = pd.to_numeric(df[col], errors="coerce").to_numpy(dtype=float)
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            row = int(bad[0])
            value = df[col].iloc[row]
            value = value.item() if isinstance(value, np.generic) else value  # nan, not np.float64(nan)
            raise InputError(
                f"{source}: column '{col}' has {bad.size} non-finite or non-numeric value(s), "
                f"first at row {row} (value {value!r})"
            )


def read_poses(path: str | Path) -> tuple[pd.DataFrame, torch.Tensor]:
    """Read a hole table and return it with its ``(n, 6)`` float64 pose tensor."""
    df = read_table(path, POSE_COLUMNS)
    return df, torch.tensor(df[POSE_COLUMNS].to_numpy(dtype=np.float64))


def read_table(path: str | Path, numeric: Sequence[str]) -> pd.DataFrame:
    """A hole table (Parquet or CSV) whose ``numeric`` columns are present and finite."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such hole table")
    df = pd.read_parquet(path) if path.suffix == ".parquet" else pd.read_csv(path)
    check_table(df, numeric, str(path))
    return df



def collar_toe_poses(collar: np.ndarray, toe: np.ndarray, depth: float) -> torch.Tensor:
    """``(n, 6)`` float64 hole poses ``[p, p + depth * unit(toe - collar)]`` (paper 000 eq. 4): the
    preview point lies ``depth`` along the hole, whatever the hole's own length. Callers check
    ``depth`` and that no hole has zero length."""
    collar = np.asarray(collar, dtype=np.float64)
    axis = np.asarray(toe, dtype=np.float64) - collar
    length = np.linalg.norm(axis, axis=1, keepdims=True)
    return torch.from_numpy(np.concatenate([collar, collar + depth * axis / length], axis=1))
