"""Stage ``train``: fit one IK network (SIKM, UIKM or CUIKM) and log it to MLflow.

    python -m pipeline.train method=cuikm
    python -m pipeline.train -m method=cuikm method.mu=0.1,1,10,100     # Hydra multirun

Writes ``paths.data/models/<method>.pt`` (loads alone with ``pipeline.learning.models.load_checkpoint``),
``<method>_history.csv`` (the held-out training curves) and ``<method>_final.json``. The three are
written in a private folder first, logged to MLflow from there, and only then moved into place
together: what a run logged is always its own model, whatever other trainings run beside it.
"""

from __future__ import annotations

import logging
import tempfile
import time
from pathlib import Path

import hydra
import pandas as pd
import torch
from omegaconf import DictConfig, OmegaConf

from pipeline.assembly.build import build_safety, hole_sampling
from pipeline.core.config import as_dict, project_path
from pipeline.core.device import configure_process, resolve_device
from pipeline.core.io import publish, require_writable, write_csv, write_json
from pipeline.core.settings import RuntimeSettings
from pipeline.evaluation.metrics import solution_table, summarize
from pipeline.geometry.collision import SafetyDistances
from pipeline.learning.models import IKNet, ModelSettings, build_model, save_checkpoint
from pipeline.learning.training import (
    MethodSettings,
    TrainSettings,
    check_method_key,
    final_metrics,
    fit,
    load_training_data,
    training_batches,
)
from pipeline.tracking import sweep
from pipeline.tracking.runs import StageRun, TrackingSettings, log_training_progress, stage_run

log = logging.getLogger(__name__)


def run(cfg: DictConfig) -> dict:
    """Train the configured method; returns the final held-out metrics and the checkpoint path."""
    settings, model_s, tracking = (TrainSettings.from_config(cfg.train), ModelSettings.from_config(cfg.model),
                                   TrackingSettings.from_config(cfg.tracking))
    runtime = RuntimeSettings.from_config(cfg)
    check_method_key(settings.method_key, OmegaConf.select(cfg, settings.method_key))
    method = MethodSettings.from_config(OmegaConf.select(cfg, settings.method_key), settings.method_key)
    device = resolve_device(cfg.device)
    safety, sampling = build_safety(cfg.boom, cfg.tunnel, cfg.safety), hole_sampling(cfg.holes)
    train_safety = safety.with_distances(SafetyDistances.from_config(method.train_safety))
    # A sweep job keeps its model in its own job folder; a single run writes paths.data/models.
    models_dir = require_writable(sweep.job_output_dir() or project_path(cfg.paths.data) / "models", "paths.data")
    data = load_training_data(project_path(cfg.paths.data) / "holes", safety.boom, safety, sampling,
                              method.supervised, settings.val_size, settings.val_seed, method.sup_set)
    with torch.random.fork_rng(devices=[]):  # seeded initial weights without touching the global generator
        torch.manual_seed(settings.seed)
        model = build_model(safety.boom, data.pose.mean(0), data.pose.std(0), model_s.width, model_s.depth,
                            model_s.activation).to(device)
    run_cfg = {**as_dict(cfg), "method": as_dict(OmegaConf.select(cfg, settings.method_key))}
    run_cfg.pop("baselines", None)  # what this run trained, without the other methods' configs
    tags = {"stage": "train", "method": method.name, **sweep.child_tags()}
    with stage_run(tracking, f"train-{method.name}", tags, system_metrics=True) as mlrun:
        sweep.record_job_run(mlrun.run_id)
        mlrun.log_params(run_cfg)
        for context, (path, df) in data.files.items():
            mlrun.log_dataset(df, path, context)
        t0 = time.perf_counter()
        history = fit(model, safety.boom, train_safety, method.objective,
                      training_batches(data, method.objective, settings, safety, sampling, device),
                      settings.steps, settings.lr, data.val_pose.float().to(device), settings.eval_every,
                      settings.grad_clip, progress=runtime.progress, keep_best=settings.keep_best,
                      on_eval=lambda step, rec, elapsed: log_training_progress(
                          mlrun, step, settings.steps, rec, elapsed, method.name, echo=not runtime.progress))
        model = model.cpu()
        final = final_metrics(model, data.val_pose.float(), lambda p, q: summarize(solution_table(p, q, safety)),
                              history, time.perf_counter() - t0)
        save_outputs(model, history, final, models_dir, method.name, as_dict(cfg.boom), run_cfg, mlrun, tracking,
                     runtime.log_model, data.val_pose[:4].float().numpy())
    log.info("trained %s in %.0f s: held-out hole-seeking error %.2f mm -> %s",
             method.name, final["train_seconds"], final["val_hole_mm"], models_dir / f"{method.name}.pt")
    return {"checkpoint": str(models_dir / f"{method.name}.pt"), **final}


def save_outputs(model: IKNet, history: list[dict], final: dict, models_dir: Path, name: str, boom_cfg: dict,
                 run_cfg: dict, mlrun: StageRun, tracking: TrackingSettings, log_model: bool, example) -> None:
    """Checkpoint, history and summary into a private folder, logged from there, then published."""
    with tempfile.TemporaryDirectory(prefix=f".{name}.run-", dir=models_dir) as tmp:
        files = {Path(tmp) / f: models_dir / f for f in (f"{name}.pt", f"{name}_history.csv", f"{name}_final.json")}
        ckpt, hist, summary = files
        save_checkpoint(ckpt, model, boom_cfg, {"method": name, "history": history, "final": final,
                                                "config": run_cfg, "mlflow_run_id": mlrun.run_id})
        hist_df = pd.DataFrame(history)
        write_csv(hist_df, hist)
        write_json({"method": name, "overrides": sweep.job_overrides(), **final}, summary)
        mlrun.log_metrics(final, prefix="final_")
        if mlrun.active:
            from pipeline.evaluation.plots import training_curves

            mlrun.log_figure(training_curves({name: hist_df}), f"figures/training_{name}.png")
            if log_model:
                mlrun.log_network(model, example, ckpt, name=name, step=int(final["kept_step"]),
                                  registered_name=f"{tracking.experiment}-{name}" if tracking.register_models else None)
            mlrun.log_artifact(ckpt)
        publish(files, models_dir / f".{name}.lock")


@hydra.main(version_base="1.3", config_path="../conf", config_name="config")
def main(cfg: DictConfig) -> float:
    configure_process(RuntimeSettings.from_config(cfg).train_threads)
    return run(cfg)["val_hole_mm"]


if __name__ == "__main__":
    main()
