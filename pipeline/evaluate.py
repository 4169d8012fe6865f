"""Stage ``evaluate``: solve the test groups with every trained network; tables, figures, MLflow.

    python -m pipeline.evaluate                    # methods of eval.methods
    python -m pipeline.evaluate eval.methods=[cuikm]

Writes under ``paths.data/eval/``: ``predictions/<method>_group<k>.parquet``,
``metrics.json``, ``collisions.csv`` (paper 000 Table 3 layout) and ``figures/``.
"""

from __future__ import annotations

import logging
import statistics
import time
from pathlib import Path

import hydra
import matplotlib.pyplot as plt
import pandas as pd
import torch
from omegaconf import DictConfig

from pipeline.core.build import build_safety
from pipeline.core.config import project_path
from pipeline.core.errors import InputError
from pipeline.core.io import atomic_write, write_json
from pipeline.data.tables import holes_frame, joints_frame, read_poses, write_csv, write_parquet
from pipeline.evaluation.metrics import collision_table, solution_table, summarize
from pipeline.evaluation.plots import face_projection, method_comparison, training_curves
from pipeline.geometry.collision import SafetyModel
from pipeline.learning.models import IKNet, load_checkpoint

log = logging.getLogger(__name__)


def test_groups(holes_dir: Path) -> dict[int, tuple[pd.DataFrame, torch.Tensor]]:
    """Every ``test_group_<k>.parquet`` under ``holes_dir``, by k."""
    files = sorted(holes_dir.glob("test_group_*.parquet"), key=lambda p: int(p.stem.rsplit("_", 1)[1]))
    if not files:
        raise InputError(f"{holes_dir}: no test_group_<k>.parquet files; run python -m pipeline.generate first")
    return {int(p.stem.rsplit("_", 1)[1]): read_poses(p) for p in files}


@torch.no_grad()
def solve_time_per_1000(model: IKNet, pose: torch.Tensor, repeats: int) -> float:
    """Median wall time (ms) of one batched forward pass, scaled to 1 000 holes."""
    x = pose.float()
    model(x)  # warm-up
    times = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        model(x)
        times.append(time.perf_counter() - t0)
    return 1000 * statistics.median(times) * 1000 / len(x)


def evaluate_method(
    model: IKNet,
    safety: SafetyModel,
    groups: dict[int, tuple[pd.DataFrame, torch.Tensor]],
    all_pose: torch.Tensor,
    repeats: int,
) -> tuple[dict[int, pd.DataFrame], dict[int, torch.Tensor], float]:
    """Per-group solution tables and joints, and the solve time per 1 000 holes (ms)."""
    tables, joints = {}, {}
    with torch.no_grad():
        for k, (_, pose) in groups.items():
            joints[k] = model(pose.float()).double()
            tables[k] = solution_table(pose, joints[k], safety)
    return tables, joints, solve_time_per_1000(model, all_pose, repeats)


def run(cfg: DictConfig) -> dict:
    from pipeline.tracking import runs as tracking

    safety = build_safety(cfg.boom, cfg.tunnel, cfg.safety)
    data = project_path(cfg.paths.data)
    groups = test_groups(data / "holes")
    out = data / "eval"
    methods = list(cfg.eval.methods)
    all_pose = torch.cat([p for _, p in groups.values()])  # every test hole, in group order
    models = {m: load_checkpoint(data / "models" / f"{m}.pt") for m in methods}  # fail before writing
    metrics, per_group, histories, projections = {}, {}, {}, {}
    for method, (model, meta) in models.items():
        if model.n_out != safety.boom.n_joints:
            raise InputError(f"{method}.pt outputs {model.n_out} joints; boom '{safety.boom.name}' has "
                             f"{safety.boom.n_joints}")
        tables, joints, ms = evaluate_method(model, safety, groups, all_pose, int(cfg.eval.timing_repeats))
        for k, (df, pose) in groups.items():
            pred = pd.concat([holes_frame(pose, df["hole_id"].to_numpy()),
                              joints_frame(joints[k], safety.boom.joint_names)], axis=1)
            write_parquet(pred, out / "predictions" / f"{method}_group{k}.parquet")
            per_group[(k, method)] = tables[k]
        allt = pd.concat(tables.values(), ignore_index=True)
        metrics[method] = {**summarize(allt), "solve_ms_per_1000": ms,
                           "per_group_hole_mm_mean": {k: float(t["hole_mm"].mean()) for k, t in tables.items()}}
        histories[method] = pd.DataFrame(meta.get("history", []))
        projections[method] = (all_pose[:, 1].numpy(), all_pose[:, 2].numpy(), allt["hole_mm"].to_numpy())
    collisions = collision_table(per_group)
    write_json(metrics, out / "metrics.json")
    write_csv(collisions, out / "collisions.csv")
    figures = {
        "training_curves.png": training_curves({m: h for m, h in histories.items() if len(h)}),
        "face_projection.png": face_projection(projections, safety.tunnel),
        "method_comparison.png": method_comparison(metrics),
    }
    for name, fig in figures.items():
        atomic_write(out / "figures" / name, lambda tmp, fig=fig: fig.savefig(tmp, dpi=120, format="png"))
    if cfg.tracking.enabled:
        tracking.setup(cfg.tracking.uri, cfg.tracking.experiment, cfg.tracking.artifact_root)
        with tracking.start(run_name="evaluate", tags={"stage": "evaluate"}):
            tracking.log_params(tracking.flatten({"eval": dict(cfg.eval), "safety": dict(cfg.safety)}))
            for method, m in metrics.items():
                tracking.log_metrics({k: v for k, v in m.items() if not isinstance(v, dict)}, prefix=f"{method}.")
            import mlflow

            mlflow.log_table(collisions, "tables/collisions.json")
            summary = pd.DataFrame([{"method": m, **{k: v for k, v in d.items() if not isinstance(v, dict)}}
                                    for m, d in metrics.items()])
            mlflow.log_table(summary, "tables/metrics.json")
            for name, fig in figures.items():
                mlflow.log_figure(fig, f"figures/{name}")
            tracking.log_artifact(out / "metrics.json")
    for fig in figures.values():
        plt.close(fig)
    for method, m in metrics.items():
        log.info("%s: hole-seeking error mean %.2f mm (p95 %.2f), collision rate %.2f %%, %.2f ms / 1000 holes",
                 method, m["hole_mm_mean"], m["hole_mm_p95"], 100 * m["collision_rate_paper"],
                 m["solve_ms_per_1000"])
    return metrics


@hydra.main(version_base="1.3", config_path="../conf", config_name="config")
def main(cfg: DictConfig) -> None:
    run(cfg)


if __name__ == "__main__":
    main()
