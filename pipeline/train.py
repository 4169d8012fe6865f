"""Stage ``train``: fit one IK network (SIKM, UIKM or CUIKM) and log it to MLflow.

    python -m pipeline.train method=cuikm
    python -m pipeline.train -m method=cuikm method.mu=0.1,1,10,100     # Hydra multirun

Writes ``paths.data/models/<method>.pt`` (loads alone with ``pipeline.learning.models.load_checkpoint``)
and ``<method>_history.csv`` (the held-out training curves).
"""

from __future__ import annotations

import contextlib
import logging
import time

import hydra
import pandas as pd
import torch
from omegaconf import DictConfig, OmegaConf

from pipeline.core.build import build_safety
from pipeline.core.config import as_dict, project_path
from pipeline.core.device import resolve_device
from pipeline.core.errors import ConfigError
from pipeline.core.io import write_json
from pipeline.data.holes import HoleSampling, sample_holes
from pipeline.data.tables import read_poses, write_csv
from pipeline.evaluation.metrics import solution_table, summarize
from pipeline.geometry.collision import SafetyDistances
from pipeline.learning.models import build_model, save_checkpoint
from pipeline.learning.training import Objective, dataset_batches, fresh_hole_batches, train

log = logging.getLogger(__name__)


def objective_from(method: DictConfig) -> Objective:
    for key in ("lam", "mu"):
        if not float(method[key]) >= 0:
            raise ConfigError(f"method.{key} = {method[key]!r}: expected a non-negative weight")
    return Objective(bool(method.supervised), float(method.lam), float(method.mu), str(method.pose_loss))


def method_node(cfg: DictConfig) -> DictConfig:
    """The method to train: ``cfg.method``, or the node ``train.method_key`` names."""
    key = str(cfg.train.get("method_key") or "method")
    node = OmegaConf.select(cfg, key)
    if not isinstance(node, DictConfig) or "name" not in node:
        raise ConfigError(f"train.method_key = {key!r}: no method config at that key")
    return node


def sampling_from(holes: DictConfig) -> HoleSampling:
    return HoleSampling(tuple(holes.face_x), float(holes.cone_deg), float(holes.inset))


def run(cfg: DictConfig) -> dict:
    """Train the configured method; returns the final held-out metrics and the checkpoint path."""
    from pipeline.tracking import sweep

    if cfg.train.threads:
        torch.set_num_threads(int(cfg.train.threads))
    device = resolve_device(cfg.device)
    torch.manual_seed(int(cfg.train.seed))
    method = method_node(cfg)
    objective = objective_from(method)
    safety = build_safety(cfg.boom, cfg.tunnel, cfg.safety)
    boom = safety.boom
    train_safety = safety.with_distances(SafetyDistances.from_config(as_dict(method.train_safety)))
    sampling = sampling_from(cfg.holes)
    holes_dir = project_path(cfg.paths.data) / "holes"
    batch = int(cfg.train.batch_size)
    if objective.supervised:
        sup = pd.read_parquet(holes_dir / "sup.parquet")
        _, pose = read_poses(holes_dir / "sup.parquet")
        q = torch.tensor(sup[boom.joint_names].to_numpy())
        batches = dataset_batches(pose.float().to(device), q.float().to(device), batch, int(cfg.train.seed))
    else:
        _, pose = read_poses(holes_dir / "train.parquet")
        if cfg.train.fresh_holes:
            batches = fresh_hole_batches(safety, sampling, batch, int(cfg.train.seed), device)
        else:
            batches = dataset_batches(pose.float().to(device), None, batch, int(cfg.train.seed))
    model = build_model(boom, pose.mean(0), pose.std(0), int(cfg.model.width), int(cfg.model.depth),
                        str(cfg.model.activation)).to(device)
    val_pose, _ = sample_holes(int(cfg.train.val_size), safety, sampling, int(cfg.train.val_seed))
    val_pose = val_pose.float().to(device)

    name = str(method.name)
    # A sweep job keeps its model in its own job folder; a single run writes paths.data/models.
    models_dir = sweep.job_output_dir() or project_path(cfg.paths.data) / "models"
    ckpt = models_dir / f"{name}.pt"
    # What this run trained: its method under "method", without the other methods' configs.
    run_cfg = {**as_dict(cfg), "method": as_dict(method)}
    run_cfg.pop("baselines", None)
    tracking_on = bool(cfg.tracking.enabled)
    if tracking_on:  # imported only when used: a run without tracking needs no MLflow
        from pipeline.tracking import runs as tracking

        tracking.setup(cfg.tracking.uri, cfg.tracking.experiment, cfg.tracking.artifact_root)
    t0 = time.perf_counter()
    tags = {"stage": "train", "method": name, **sweep.child_tags()}
    run_ctx = tracking.start(run_name=f"train-{name}", tags=tags) if tracking_on else contextlib.nullcontext()
    with run_ctx:
        if tracking_on:
            tracking.log_params(tracking.flatten(run_cfg))
        history = train(
            model, boom, train_safety, objective, batches,
            int(cfg.train.steps), float(cfg.train.lr), val_pose, int(cfg.train.eval_every),
            cfg.train.grad_clip, progress=bool(cfg.train.progress),
        )
        train_s = time.perf_counter() - t0
        model = model.cpu()
        with torch.no_grad():
            val = summarize(solution_table(val_pose.cpu(), model(val_pose.cpu()), safety))
        final = {
            **{k: v for k, v in history[-1].items() if k.startswith("val_")},
            "val_hole_mm_p95": val["hole_mm_p95"],
            "val_collision_rate": val["collision_rate_paper"],
            "val_any_violation_share": val["any_violation_share"],
            "train_seconds": train_s,
        }
        save_checkpoint(ckpt, model, as_dict(cfg.boom), {
            "method": name, "history": history, "final": final,
            "config": run_cfg,
        })
        hist_df = pd.DataFrame(history)
        write_csv(hist_df, models_dir / f"{name}_history.csv")
        write_json({"method": name, "overrides": sweep.job_overrides(), **final}, models_dir / f"{name}_final.json")
        if tracking_on:
            tracking.log_history(history)
            tracking.log_metrics(final, prefix="final_")
            tracking.log_training_figure(hist_df, name)
            if cfg.train.log_model:
                tracking.log_network(model, val_pose[:4].cpu().numpy())
            tracking.log_artifact(ckpt)
    log.info("trained %s in %.0f s: held-out hole-seeking error %.2f mm -> %s",
             name, train_s, final["val_hole_mm"], ckpt)
    return {"checkpoint": str(ckpt), **final}


@hydra.main(version_base="1.3", config_path="../conf", config_name="config")
def main(cfg: DictConfig) -> float:
    return run(cfg)["val_hole_mm"]


if __name__ == "__main__":
    main()
