"""The spread over seeds: each seed's network on the test groups, and the mean and std the report gives.

A method trained with ``train.seeds`` > 1 leaves one network per seed in ``models/<method>_seeds/<method>_seed<k>.pt``
beside the one the other stages use (``models/<method>.pt``: the seed with the best held-out error). One training
says little about a change of a few tenths of a millimetre; the std over seeds says how much it can move alone.
"""

from __future__ import annotations

import re
import statistics
from pathlib import Path

import pandas as pd

SEED_COLUMNS = ["method", "seed", "kept", "mean_mm", "p95_mm", "collision_rate_pct", "any_violation_pct"]


def seed_checkpoints(models_dir: Path, method: str) -> dict[int, Path]:
    """The per-seed networks of ``method`` by seed, in seed order (empty: trained without a seeds folder)."""
    folder = Path(models_dir) / f"{method}_seeds"
    name = re.compile(rf"{re.escape(method)}_seed(\d+)\.pt")
    found = {int(m.group(1)): p for p in folder.glob("*.pt") if (m := name.fullmatch(p.name))}
    return dict(sorted(found.items()))


def seed_table(metrics: dict[str, dict[int, dict]], kept: dict[str, int | None]) -> pd.DataFrame:
    """One row per (method, seed) from each seed's test-group metrics (``summarize``'s keys); ``kept``: the seed
    whose network is ``models/<method>.pt``."""
    rows = [{"method": m, "seed": seed, "kept": seed == kept.get(m), "mean_mm": s["hole_mm_mean"],
             "p95_mm": s["hole_mm_p95"], "collision_rate_pct": 100 * s["collision_rate_paper"],
             "any_violation_pct": 100 * s["any_violation_share"]}
            for m, by_seed in metrics.items() for seed, s in by_seed.items()]
    return pd.DataFrame(rows, columns=SEED_COLUMNS)


def mean_std(values) -> tuple[float, float]:
    """The mean and the sample std of a figure over seeds (std 0 for one seed)."""
    values = [float(v) for v in values]
    return statistics.fmean(values), (statistics.stdev(values) if len(values) > 1 else 0.0)


def seed_spread(table: pd.DataFrame) -> dict[str, dict[str, float]]:
    """Per method: how many seeds, and the mean and sample std of its mean error and collision rate over them
    (std 0 for one seed)."""
    out = {}
    for method, rows in table.groupby("method", sort=False):
        entry: dict[str, float] = {"seeds": int(len(rows))}
        for col in ("mean_mm", "collision_rate_pct"):
            entry[f"{col}_seed_mean"], entry[f"{col}_seed_std"] = mean_std(rows[col])
        out[method] = entry
    return out
