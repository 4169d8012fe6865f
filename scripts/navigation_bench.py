"""Benchmark (docs/plans_to_rig.md, "How good a measured pose is"): how far a navigation fitted to 3-5
measured points puts the face's holes from where the true pose puts them, and how long the fit takes.

    python scripts/navigation_bench.py [draws] [hydra overrides ...]     # default: 1000 draws per row

For each prism layout, number of points (the layout's first 3, 4 or 5) and noise model (3 mm rms of each
point's 3-D error, i.e. 1.73 mm per axis; and 3 mm per axis), ``draws`` noise draws: the points are
written as the reference-point CSV a surveyor hands over and fitted by ``pipeline.plans.navigation.fit_pose``
(read and fit, timed); a grid of collars and toes over the face (x 6-11 m, y +-2.2 m, z 0.3-4.8 m: the
5 x 5 m drift's face and its holes' toes) is taken into the rig frame by the fitted pose and by the true one.
A row gives the largest of those distances per draw (every hole of the round), as p50 / p95 / max over the
draws, and the fit's median and p99 time. The pose: the rig in mine coordinates (478 100, 6 771 700, 240 m),
turned 37.5 deg. One MLflow run (``navigation-benchmark``) holds the table.
"""

from __future__ import annotations

import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.core.config import compose
from pipeline.plans.navigation import fit_pose, pose_from_angles
from pipeline.tracking.runs import TrackingSettings, stage_run

TRUE = [478_100.0, 6_771_700.0, 240.0, 37.5, 1.2, -0.8]
LAYOUTS = {
    # both walls and the roof, from 10 m behind the rig to the last round's markers 1.5 m short of the face
    "walls, -10 to +5 m": [[-10.0, 2.4, 1.5], [5.0, -2.4, 3.0], [4.5, 2.4, 1.2], [-10.0, -2.4, 3.2], [-2.0, 0.5, 4.8]],
    # every prism behind the rig's front: the face is 6-11 m beyond them
    "behind the rig, -8 to +1 m": [[-8.0, 2.4, 1.8], [-2.0, -2.4, 2.6], [-6.0, -2.3, 1.2], [1.0, 2.4, 3.0],
                                   [-4.0, 0.3, 4.8]],
}
NOISE = {"3 mm rms (1.73 mm per axis)": 0.003 / math.sqrt(3), "3 mm per axis": 0.003}
FACE = np.stack(np.meshgrid([6.0, 8.5, 11.0], [-2.2, 0.0, 2.2], [0.3, 2.5, 4.8]), -1).reshape(-1, 3)


def write_points(path: Path, plan: np.ndarray, rig: np.ndarray) -> Path:
    names = [f"P{i + 1}" for i in range(len(plan))]
    df = pd.DataFrame({"point": names, **{f"plan_{a}": plan[:, i] for i, a in enumerate("xyz")},
                       **{f"rig_{a}": rig[:, i] for i, a in enumerate("xyz")}})
    df.to_csv(path, index=False, float_format="%.6f")  # a survey's millimetre-and-better digits
    return path


def row(layout: str, n: int, noise: str, draws: int, folder: Path) -> dict:
    true = pose_from_angles(TRUE)
    prisms = np.asarray(LAYOUTS[layout])[:n]
    plan = true.to_plan(prisms)
    truth = true.to_plan(FACE)
    g = np.random.default_rng(n)
    worst, spent = [], []
    for k in range(draws):
        path = write_points(folder / f"p{k}.csv", plan, prisms + g.normal(0, NOISE[noise], prisms.shape))
        start = time.perf_counter()
        fitted = fit_pose(path)
        spent.append(time.perf_counter() - start)
        worst.append(float(np.linalg.norm(fitted.to_rig(truth) - FACE, axis=1).max()))
    worst_mm, spent_ms = 1000 * np.array(worst), 1000 * np.array(spent)
    return {"layout": layout, "points": n, "noise": noise, "draws": draws,
            "face_p50_mm": float(np.median(worst_mm)), "face_p95_mm": float(np.percentile(worst_mm, 95)),
            "face_max_mm": float(worst_mm.max()), "within_10mm_pct": float(100 * np.mean(worst_mm <= 10.0)),
            "fit_p50_ms": float(np.median(spent_ms)), "fit_p99_ms": float(np.percentile(spent_ms, 99))}


def main(argv: list[str]) -> None:
    draws = int(argv[0]) if argv else 1000
    cfg = compose(argv[1:])
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for layout in LAYOUTS:
            for noise in NOISE:
                for n in (3, 4, 5):
                    rows.append(row(layout, n, noise, draws, Path(tmp)))
                    print(rows[-1], flush=True)
    table = pd.DataFrame(rows)
    print(table.to_markdown(index=False, floatfmt=".1f"))
    with stage_run(TrackingSettings.from_config(cfg.tracking), "navigation-benchmark",
                   {"stage": "script", "mode": "benchmark"}) as run:
        run.log_params({"draws": draws, "pose": TRUE})
        run.log_table(table, "navigation.json")
        run.log_metrics({"fit_p99_ms_max": float(table["fit_p99_ms"].max()),
                         "face_max_mm_rms3_walls": float(table[(table["layout"] == "walls, -10 to +5 m")
                                                               & (table["noise"].str.startswith("3 mm rms"))]
                                                         ["face_max_mm"].max())})


if __name__ == "__main__":
    main(sys.argv[1:])
