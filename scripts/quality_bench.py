"""Benchmark (docs/calibration.md, "The loop"): the quality stage's work on a large as-drilled log.

    python scripts/quality_bench.py [holes] [hydra overrides ...]      # default: 10 000 holes

Writes a plan of ``holes`` holes (a grid over a 5 x 5 m face, 3.5 m deep) and its quality log (each hole drilled
a few millimetres off, seeded), then runs ``pipeline.quality.run`` on them in this process, three times: the
median seconds of the whole stage (reading the plan and the log, the deviations, the set written with its face
figure, the MLflow run), and of its parts. One MLflow run (``quality-benchmark``) holds them.
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline import quality
from pipeline.core.config import compose
from pipeline.plans.deviations import deviations
from pipeline.plans.drpqual import LOG_COLUMNS, read_quality_log, write_quality_log
from pipeline.plans.model import COORDS
from pipeline.plans.read import read_plan
from pipeline.tracking.runs import TrackingSettings, stage_run


def files(folder: Path, n: int) -> tuple[Path, Path]:
    g = np.random.default_rng(0)
    side = int(np.ceil(np.sqrt(n)))
    y, z = np.meshgrid(np.linspace(-2.3, 2.3, side), np.linspace(0.3, 4.8, side))
    collar = np.stack([np.full(side * side, 6.5), y.ravel(), z.ravel()], 1)[:n]
    plan = pd.DataFrame({"hole_id": [f"H{k:05d}" for k in range(n)]})
    plan[COORDS] = np.concatenate([collar, collar + [3.5, 0.0, 0.0]], 1)
    plan.to_csv(folder / "plan.csv", index=False)
    log = plan.assign(hole_name=plan["hole_id"], boom="L", status="Drilled", start_time="2026-01-01T07:00:00",
                      end_time="2026-01-01T07:02:00")
    log[COORDS] = plan[COORDS].to_numpy() + np.repeat(g.normal(0, 0.005, (n, 3)), 2, axis=0).reshape(n, 6)
    write_quality_log(log[LOG_COLUMNS], folder / "log.xml", plan_id="plan", plan_name="plan",
                      created="2026-01-01T07:00:00")
    return folder / "plan.csv", folder / "log.xml"


def main(argv: list[str]) -> None:
    n = int(argv[0]) if argv else 10_000
    # The store for the benchmark's own run, resolved before the stage's runs point MLflow at the temporary one.
    tracking = TrackingSettings.from_config(compose(argv[1:]).tracking)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        plan, log = files(folder, n)
        cfg = compose([f"plan={plan}", f"log={log}", f"tracking.uri=sqlite:///{folder}/mlflow.db",
                       f"tracking.artifact_root={folder}/artifacts", *argv[1:]])
        quality.run(cfg)  # warm: imports, the store's tables
        for _ in range(3):
            t0 = time.perf_counter()
            holes = read_plan(plan).holes
            t1 = time.perf_counter()
            logged = read_quality_log(log).holes
            t2 = time.perf_counter()
            deviations(holes, logged)
            t3 = time.perf_counter()
            quality.run(cfg)
            t4 = time.perf_counter()
            rows.append({"read_plan_s": t1 - t0, "read_log_s": t2 - t1, "deviations_s": t3 - t2, "stage_s": t4 - t3})
    table = pd.DataFrame(rows)
    med = {k: statistics.median(table[k]) for k in table}
    print(f"{n} holes: the quality stage in {med['stage_s']:.2f} s (median of 3; reading the plan "
          f"{med['read_plan_s']:.2f} s, the log {med['read_log_s']:.2f} s, the deviations {med['deviations_s']:.3f} s)")
    with stage_run(tracking, "quality-benchmark",
                   {"stage": "script", "mode": "benchmark"}) as run:
        run.log_params({"holes": n})
        run.log_metrics({f"{k}_median": v for k, v in med.items()})


if __name__ == "__main__":
    main(sys.argv[1:])
