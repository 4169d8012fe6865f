"""Stage ``train``: fit one IK network (SIKM, UIKM or CUIKM) and log it to MLflow.

    python -m pipeline.train method=cuikm
    python -m pipeline.train -m method=cuikm method.mu=0.1,1,10,100     # Hydra multirun

Writes ``paths.data/models/<method>.pt`` (loads alone with ``pipeline.learning.models.load_checkpoint``),
``<method>_history.csv`` (the held-out training curves) and ``<method>_final.json``. The three are
written in a private folder first, logged to MLflow from there, and only then moved into place
together: what a run logged is always its own model, whatever other trainings run beside it.

The training's private folder ``.<method>.run-<digest>/`` (the digest of its settings, data and code)
holds its resume state ``resume.pt``, written every ``runtime.checkpoint_every`` steps and on SIGTERM /
SIGINT and logged to the run as ``checkpoints/resume.pt``; with ``train.resume=true`` (the default) a
training with that digest continues from it, in the same MLflow run, to the weights an uninterrupted
training gives. The folder is removed when the training's files are published.

A config with a ``tour`` node (``experiment=quick``) names the full study's figures, and a training
prints them beside its own, so that a short training's figure is read for what it is.
"""

from __future__ import annotations

import logging
import shutil
import tempfile
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd
import torch
from omegaconf import DictConfig, OmegaConf

from pipeline.assembly.build import build_safety, hole_sampling
from pipeline.core.config import as_dict, project_path
from pipeline.core.device import resolve_device
from pipeline.core.errors import ConfigError
from pipeline.core.io import publish, publish_lock, require_writable, write_csv, write_json
from pipeline.core.settings import RuntimeSettings, coerce, parse
from pipeline.core.stage import run_stage, stage_main
from pipeline.data.tables import POSE_COLUMNS
from pipeline.evaluation.metrics import solution_table, summarize
from pipeline.geometry.collision import SafetyDistances
from pipeline.learning.models import IKNet, ModelSettings, build_model, save_checkpoint
from pipeline.learning.training import (
    Checkpoints,
    MethodSettings,
    TrainSettings,
    check_method_key,
    final_metrics,
    fit,
    load_training_data,
    load_training_state,
    save_training_state,
    training_batches,
    training_digest,
)
from pipeline.tracking import sweep
from pipeline.tracking.runs import StageRun, TrackingSettings, log_training_progress, select_params, stage_run

log = logging.getLogger(__name__)
RESUME_FILE = "resume.pt"


# What a training reads, and so what its run logs as params (not the other stages' settings).
PARAM_KEYS = ["model", "train", "holes.face_x", "holes.cone_deg", "holes.inset", "safety", "tunnel", "boom", "device",
              "runtime"]
# Settings that change how a training runs, not what it computes (threads, progress, checkpoint interval,
# resume itself): outside its resume digest.
NOT_IN_DIGEST = ("runtime",)


@dataclass(frozen=True)
class StudyFigures:
    """``tour``: what the full study reaches per method on its five test groups (README, "Results"), printed
    after a shorter training; an experiment without the node prints nothing."""

    hole_mm: dict = field(default_factory=dict)        # mean hole-seeking error, mm
    collision_pct: dict = field(default_factory=dict)  # collision rate, %

    def __post_init__(self):
        for key in ("hole_mm", "collision_pct"):
            if not isinstance(getattr(self, key), Mapping):
                raise ConfigError(f"tour.{key} = {getattr(self, key)!r}: expected a mapping of method to figure")
            for method, value in getattr(self, key).items():
                coerce(value, "float", f"tour.{key}.{method}")


def run(cfg: DictConfig) -> dict:
    """Train the configured method; returns the final held-out metrics and the checkpoint path."""
    settings, model_s, tracking = (TrainSettings.from_config(cfg.train), ModelSettings.from_config(cfg.model),
                                   TrackingSettings.from_config(cfg.tracking))
    runtime = RuntimeSettings.from_config(cfg)
    tour = OmegaConf.select(cfg, "tour")
    study = None if tour is None else parse(StudyFigures, as_dict(tour), "tour")
    check_method_key(settings.method_key, OmegaConf.select(cfg, settings.method_key))
    method = MethodSettings.from_config(OmegaConf.select(cfg, settings.method_key), settings.method_key)
    device = resolve_device(cfg.device)
    safety, sampling = build_safety(cfg.boom, cfg.tunnel, cfg.safety), hole_sampling(cfg.holes)
    train_safety = safety.with_distances(SafetyDistances.from_config(method.train_safety))
    steps = method.steps(settings.steps)
    # A sweep job keeps its model in its own job folder; a single run writes paths.data/models.
    job_dir = sweep.job_output_dir()
    models_dir = require_writable(job_dir or project_path(cfg.paths.data) / "models", "paths.data")
    data = load_training_data(project_path(cfg.paths.data) / "holes", safety.boom, safety, sampling,
                              method.supervised, settings.val_size, settings.val_seed, method.sup_set)
    with torch.random.fork_rng(devices=[]):  # seeded initial weights without touching the global generator
        torch.manual_seed(settings.seed)
        model = build_model(safety.boom, data.pose.mean(0), data.pose.std(0), model_s.width, model_s.depth,
                            model_s.activation).to(device)
    run_cfg = {"method": as_dict(OmegaConf.select(cfg, settings.method_key)),
               **select_params(as_dict(cfg), PARAM_KEYS)}
    if safety.tunnel.kind == "profile":  # the drift the penalties keep from is the file's content, not its name
        run_cfg["tunnel_profile_md5"] = safety.tunnel.md5
    digest = training_digest(_digest_config(run_cfg, str(device)), [path for path, _ in data.files.values()])
    run_dir = models_dir / f".{method.name}.run-{digest[:12]}"  # private to this training (config, data, code)
    resume = load_training_state(run_dir / RESUME_FILE, digest) if runtime.resume else None
    tags = {"stage": "train", "method": method.name, "train.digest": digest, **sweep.child_tags()}
    with stage_run(tracking, f"train-{method.name}", tags, system_metrics=True,
                   resume_run_id=resume and resume.get("mlflow_run_id")) as mlrun:
        sweep.record_job_run(mlrun.run_id)
        mlrun.log_params({**run_cfg, "steps_trained": steps})  # train.steps, or the method's max_steps below it
        inputs = {context: mlrun.log_dataset(df, path, context) for context, (path, df) in data.files.items()}
        inputs["validation"] = mlrun.log_frame_dataset(
            pd.DataFrame(data.val_pose.numpy(), columns=POSE_COLUMNS), f"held-out holes (val_seed={settings.val_seed})",
            "validation")
        if resume is not None:
            mlrun.set_tags({"resumed_at_step": str(resume["step"])})
            log.info("train %s: resuming at step %d of %d from %s", method.name, resume["step"], steps,
                     run_dir / RESUME_FILE)

        def save_state(state: dict) -> None:
            save_training_state(run_dir / RESUME_FILE, state, digest, {"mlflow_run_id": mlrun.run_id})
            mlrun.log_artifact(run_dir / RESUME_FILE, "checkpoints")

        t0 = time.perf_counter()
        history = fit(model, safety.boom, train_safety, method.objective,
                      training_batches(data, method.objective, settings, safety, sampling, device),
                      steps, settings.lr, data.val_pose.float().to(device), settings.eval_every,
                      settings.grad_clip, progress=runtime.progress, keep_best=settings.keep_best,
                      on_eval=lambda step, rec, elapsed: log_training_progress(
                          mlrun, step, steps, rec, elapsed, method.name, echo=not runtime.progress),
                      checkpoints=Checkpoints(save_state, runtime.checkpoint_every, resume))
        model = model.cpu()
        train_s = time.perf_counter() - t0 + (resume["elapsed_s"] if resume else 0.0)
        final = final_metrics(model, data.val_pose.float(), lambda p, q: summarize(solution_table(p, q, safety)),
                              history, train_s)
        register = tracking.register_models and job_dir is None  # a sweep's variants stay in their runs
        save_outputs(model, history, final, models_dir, run_dir, method.name, as_dict(cfg.boom), run_cfg, mlrun,
                     f"{tracking.experiment}-{method.name}" if register else None, runtime.log_model,
                     data.val_pose[:4].float().numpy(), inputs)
    log.info("trained %s in %.0f s: held-out hole-seeking error %.2f mm -> %s",
             method.name, final["train_seconds"], final["val_hole_mm"], models_dir / f"{method.name}.pt")
    if study is not None and method.name in study.hole_mm:
        collisions = study.collision_pct.get(method.name)
        log.info("the full study's %s (the README's first command) reaches %.2f mm on its five test groups%s",
                 method.name, study.hole_mm[method.name],
                 "" if collisions is None else f", {collisions:g} % collisions")
    return {"checkpoint": str(models_dir / f"{method.name}.pt"), **final}


def _digest_config(run_cfg: dict, device: str) -> dict:
    return {**{k: v for k, v in run_cfg.items() if k not in NOT_IN_DIGEST}, "device": device}


def save_outputs(model: IKNet, history: list[dict], final: dict, models_dir: Path, run_dir: Path, name: str,
                 boom_cfg: dict, run_cfg: dict, mlrun: StageRun, registered_name: str | None, log_model: bool,
                 example, inputs: dict) -> None:
    """Checkpoint, history and summary into the training's private folder, logged from there, then
    published; the folder (with its resume state) is removed once they are in place."""
    run_dir.mkdir(parents=True, exist_ok=True)
    out = Path(tempfile.mkdtemp(prefix="out-", dir=run_dir))  # this process's own, even beside a twin training
    files = {out / f: models_dir / f for f in (f"{name}.pt", f"{name}_history.csv", f"{name}_final.json")}
    ckpt, hist, summary = files
    save_checkpoint(ckpt, model, boom_cfg, {"method": name, "history": history, "final": final,
                                            "config": run_cfg, "mlflow_run_id": mlrun.run_id})
    hist_df = pd.DataFrame(history)
    write_csv(hist_df, hist)
    write_json({"method": name, "overrides": sweep.job_overrides(), **final}, summary)
    if mlrun.active:
        from pipeline.evaluation.plots import training_curves

        mlrun.log_figure(training_curves({name: hist_df}), f"figures/training_{name}.png")
        kept = int(final["kept_step"])
        info = mlrun.log_network(model, example, ckpt, name=name, step=kept,
                                 registered_name=registered_name) if log_model else None
        model_id = info.model_id if info is not None else None
        # after the curves, linked to the model: held-out values on the held-out holes, the kept step's
        # loss on the training data (the model page lists both datasets), the rest on their own
        kept_rec = next((r for r in history if r.get("kept")), history[-1])
        mlrun.log_summary({k: v for k, v in final.items() if k.startswith("val_")}, kept, model_id,
                          inputs.get("validation"))
        mlrun.log_summary({"loss": kept_rec["loss"]}, kept, model_id, inputs.get("training"))
        mlrun.log_summary({k: v for k, v in final.items() if not k.startswith("val_")}, kept, model_id)
        mlrun.log_artifact(ckpt)
    publish(files, publish_lock(models_dir, name))
    shutil.rmtree(run_dir, ignore_errors=True)


@stage_main
def main(cfg: DictConfig) -> float:
    return run_stage(cfg, run, threads="train_threads")["val_hole_mm"]


if __name__ == "__main__":
    main()
