"""Stage ``train``: fit one IK network (SIKM, UIKM or CUIKM) and log it to MLflow.

    python -m pipeline.train method=cuikm
    python -m pipeline.train -m method=cuikm method.mu=0.1,1,10,100     # Hydra multirun

Writes ``paths.data/models/<method>.pt`` (``paths.models/<method>.pt`` when that is set: a job of the sweeps; it
loads alone with ``pipeline.learning.models.load_checkpoint``), ``<method>_history.csv`` (the held-out training
curves) and ``<method>_final.json``. The three are written in a private folder first, logged to MLflow from there,
and only then moved into place together: what a run logged is always its own model, whatever other trainings
run beside it.

The training's private folder ``.<method>.run-<digest>/`` (the digest of its settings, data and code)
holds its resume state ``resume.pt``, written every ``runtime.checkpoint_every`` steps and on SIGTERM /
SIGINT and logged to the run as ``checkpoints/resume.pt``; with ``train.resume=true`` (the default) a
training with that digest continues from it, in the same MLflow run, to the weights an uninterrupted
training gives. The folder is removed when the training's files are published.

A config with a ``tour`` node (``experiment=quick``) names the full study's figures, and a training
prints them beside its own, so that a short training's figure is read for what it is.
"""

from __future__ import annotations

import json
import logging
import os
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
from pipeline.core.io import process_token, publish, publish_lock, require_writable, write_csv, write_json
from pipeline.core.settings import SEED_MAX, RuntimeSettings, coerce, parse
from pipeline.core.stage import run_stage, stage_main
from pipeline.data.tables import POSE_COLUMNS
from pipeline.evaluation.metrics import solution_table, summarize
from pipeline.evaluation.seeds import mean_std
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
    training_dtype,
)
from pipeline.tracking import sweep
from pipeline.tracking.runs import (
    StageRun,
    TrackingSettings,
    log_training_progress,
    register_network,
    select_params,
    stage_run,
)

log = logging.getLogger(__name__)
RESUME_FILE = "resume.pt"
DONE_DIR = "done"                                     # a finished seed's files, waiting for the others
LOGGED_MODEL_FILE = "logged_model.txt"                # beside them: the MLflow model's URI
OUTPUT_SUFFIXES = (".pt", "_history.csv", "_final.json")


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
    """Train the configured method once per seed (``train.seeds`` of them, from ``train.seed`` up); returns the
    chosen network's final held-out metrics and its checkpoint path.

    Each seed's network is ``<method>_seeds/<method>_seed<k>.pt`` (with its history and summary); the network the other
    stages read, ``<method>.pt``, is the seed with the best held-out hole-seeking error (held-out holes, never a
    test group; ties to the lower seed), and its summary adds every seed's figure with their mean and std."""
    settings, model_s, tracking = (TrainSettings.from_config(cfg.train), ModelSettings.from_config(cfg.model),
                                   TrackingSettings.from_config(cfg.tracking))
    runtime = RuntimeSettings.from_config(cfg)
    tour = OmegaConf.select(cfg, "tour")
    study = None if tour is None else parse(StudyFigures, as_dict(tour), "tour")
    check_method_key(settings.method_key, OmegaConf.select(cfg, settings.method_key))
    method = MethodSettings.from_config(OmegaConf.select(cfg, settings.method_key), settings.method_key)
    if settings.seed + settings.seeds - 1 > SEED_MAX:
        raise ConfigError(f"train.seed = {settings.seed} with train.seeds = {settings.seeds}: the last seed "
                          f"passes {SEED_MAX}")
    device = resolve_device(cfg.device)
    safety, sampling = build_safety(cfg.boom, cfg.tunnel, cfg.safety), hole_sampling(cfg.holes)
    # A multirun job keeps its model in its own job folder, a job of the DVC sweeps in paths.models; a single run
    # writes paths.data/models. Only the last is registered: a sweep's variants stay in their runs.
    job_dir = sweep.job_output_dir()
    own = OmegaConf.select(cfg, "paths.models")
    if job_dir is None and own is not None:
        job_dir = project_path(own)
    models_dir = require_writable(job_dir or project_path(cfg.paths.data) / "models",
                                  "paths.models" if own is not None else "paths.data")
    data = load_training_data(project_path(cfg.paths.data) / "holes", safety.boom, safety, sampling,
                              method.supervised, settings.val_size, settings.val_seed, method.sup_set)
    job = TrainingJob(cfg, settings, model_s, tracking, runtime, method, device, safety, sampling, data, models_dir,
                      job_dir)
    trained = [train_seed(job, settings.seed + k) for k in range(settings.seeds)]
    chosen = min(trained, key=lambda t: (t.final["val_hole_mm"], t.seed))
    final = publish_chosen(trained, chosen, models_dir, method.name)
    if job.register and chosen.model_uri:
        register_network(chosen.model_uri, f"{tracking.experiment}-{method.name}")
    log.info("trained %s (%s): held-out hole-seeking error %s; seed %d kept -> %s", method.name,
             f"{len(trained)} seeds" if len(trained) > 1 else f"seed {chosen.seed}",
             ", ".join(f"{t.final['val_hole_mm']:.2f} mm" for t in trained), chosen.seed,
             models_dir / f"{method.name}.pt")
    if study is not None and method.name in study.hole_mm:
        collisions = study.collision_pct.get(method.name)
        log.info("the full study's %s (the README's first command) reaches %.2f mm on its five test groups%s",
                 method.name, study.hole_mm[method.name],
                 "" if collisions is None else f", {collisions:g} % collisions")
    return {"checkpoint": str(models_dir / f"{method.name}.pt"), **final}


@dataclass(frozen=True)
class TrainingJob:
    """What every seed of one method's training shares: the settings, the boom, the data, where it writes."""

    cfg: DictConfig
    settings: TrainSettings
    model_s: ModelSettings
    tracking: TrackingSettings
    runtime: RuntimeSettings
    method: MethodSettings
    device: torch.device
    safety: object
    sampling: object
    data: object
    models_dir: Path
    job_dir: Path | None

    @property
    def register(self) -> bool:
        return self.tracking.register_models and self.job_dir is None  # a sweep's variants stay in their runs


@dataclass(frozen=True)
class TrainedSeed:
    seed: int
    stem: str            # its files: <stem>.pt, <stem>_history.csv, <stem>_final.json
    run_dir: Path        # the training's private folder; the files wait in its done/ until published
    final: dict
    model_uri: str | None  # the network as logged to MLflow (registered once the seeds are compared)

    @property
    def files(self) -> list[Path]:
        return [self.run_dir / DONE_DIR / f"{self.stem}{suffix}" for suffix in OUTPUT_SUFFIXES]


def train_seed(job: TrainingJob, seed: int) -> TrainedSeed:
    """One seed's training, resumable, logged to its own MLflow run, published into the seeds folder."""
    cfg, settings, method, data, safety = job.cfg, job.settings, job.method, job.data, job.safety
    train_safety = safety.with_distances(SafetyDistances.from_config(method.train_safety))
    steps = method.steps(settings.steps)
    dtype = training_dtype(settings.precision, job.device)
    precision = "float32" if dtype is None else str(dtype).removeprefix("torch.")
    with torch.random.fork_rng(devices=[]):  # seeded initial weights without touching the global generator
        torch.manual_seed(seed)
        model = build_model(safety.boom, data.pose.mean(0), data.pose.std(0), job.model_s.width, job.model_s.depth,
                            job.model_s.activation).to(job.device)
    params = as_dict(cfg)
    params["train"] = {**params["train"], "seed": seed}  # this seed's training, whatever train.seeds is
    run_cfg = {"method": as_dict(OmegaConf.select(cfg, settings.method_key)), **select_params(params, PARAM_KEYS)}
    if safety.tunnel.kind == "profile":  # the drift the penalties keep from is the file's content, not its name
        run_cfg["tunnel_profile_md5"] = safety.tunnel.md5
    digest = training_digest(_digest_config(run_cfg, str(job.device), precision),
                             [path for path, _ in data.files.values()])
    stem = f"{method.name}_seed{seed}"
    # private to this training (config, data, code), beside the seeds folder: DVC empties that folder before a
    # rerun, and the resume state must outlive it; a finished seed waits in its done/ until every seed is
    run_dir = job.models_dir / f".{stem}.run-{digest[:12]}"
    done = run_dir / DONE_DIR
    if job.runtime.resume and (done / f"{stem}_final.json").is_file():
        log.info("train %s seed %d: finished before this run (%s), not trained again", method.name, seed, done)
        return _trained(seed, stem, run_dir)
    resume = load_training_state(run_dir / RESUME_FILE, digest) if job.runtime.resume else None
    tags = {"stage": "train", "method": method.name, "seed": str(seed), "train.digest": digest, **sweep.child_tags()}
    run_name = f"train-{method.name}" + (f"-seed{seed}" if settings.seeds > 1 else "")
    with stage_run(job.tracking, run_name, tags, system_metrics=True,
                   resume_run_id=resume and resume.get("mlflow_run_id")) as mlrun:
        sweep.record_job_run(mlrun.run_id)
        mlrun.log_params({**run_cfg, "steps_trained": steps, "precision_trained": precision})
        inputs = {context: mlrun.log_dataset(df, path, context) for context, (path, df) in data.files.items()}
        inputs["validation"] = mlrun.log_frame_dataset(
            pd.DataFrame(data.val_pose.numpy(), columns=POSE_COLUMNS), f"held-out holes (val_seed={settings.val_seed})",
            "validation")
        if resume is not None:
            mlrun.set_tags({"resumed_at_step": str(resume["step"])})
            log.info("train %s seed %d: resuming at step %d of %d from %s", method.name, seed, resume["step"], steps,
                     run_dir / RESUME_FILE)

        def save_state(state: dict) -> None:
            save_training_state(run_dir / RESUME_FILE, state, digest, {"mlflow_run_id": mlrun.run_id})
            mlrun.log_artifact(run_dir / RESUME_FILE, "checkpoints")

        t0 = time.perf_counter()
        seed_settings = TrainSettings(**{**vars(settings), "seed": seed})
        history = fit(model, safety.boom, train_safety, method.objective,
                      training_batches(data, method.objective, seed_settings, safety, job.sampling, job.device),
                      steps, settings.lr, data.val_pose.float().to(job.device), settings.eval_every,
                      settings.grad_clip, progress=job.runtime.progress, keep_best=settings.keep_best,
                      on_eval=lambda step, rec, elapsed: log_training_progress(
                          mlrun, step, steps, rec, elapsed, method.name, echo=not job.runtime.progress),
                      checkpoints=Checkpoints(save_state, job.runtime.checkpoint_every, resume), hidden_dtype=dtype)
        model = model.cpu()
        train_s = time.perf_counter() - t0 + (resume["elapsed_s"] if resume else 0.0)
        final = final_metrics(model, data.val_pose.float(), lambda p, q: summarize(solution_table(p, q, safety)),
                              history, train_s)
        save_outputs(model, history, final, run_dir, method.name, stem, as_dict(cfg.boom), run_cfg, mlrun,
                     job.runtime.log_model, data.val_pose[:4].float().numpy(), inputs,
                     {"precision": precision, "seed": seed})
    log.info("trained %s seed %d in %.0f s: held-out hole-seeking error %.2f mm", method.name, seed,
             final["train_seconds"], final["val_hole_mm"])
    return _trained(seed, stem, run_dir)


def _trained(seed: int, stem: str, run_dir: Path) -> TrainedSeed:
    done = run_dir / DONE_DIR
    uri = done / LOGGED_MODEL_FILE
    return TrainedSeed(seed, stem, run_dir, json.loads((done / f"{stem}_final.json").read_text()),
                       uri.read_text().strip() if uri.is_file() else None)


def publish_chosen(trained: list[TrainedSeed], chosen: TrainedSeed, models_dir: Path, name: str) -> dict:
    """Every seed's files as ``<name>_seeds/`` and the chosen seed's as ``<name>.pt`` / ``_history.csv`` /
    ``_final.json`` (its summary plus every seed's held-out figures, their mean and sample std), published
    together under one lock: the folder and the chosen set always come from one training, even beside another.
    The seeds' private folders go once they are in place."""
    figures = ("val_hole_mm", "val_hole_mm_p95", "val_collision_rate", "val_any_violation_share", "train_seconds")
    per_seed = {k: [t.final[k] for t in trained] for k in figures}
    spread = {}
    for k, values in per_seed.items():
        spread[f"{k}_seed_mean"], spread[f"{k}_seed_std"] = mean_std(values)
    final = {**chosen.final, "seeds": [t.seed for t in trained], **{f"{k}_by_seed": v for k, v in per_seed.items()},
             **spread}
    staging = Path(tempfile.mkdtemp(prefix=f".{name}.{process_token()}.", suffix=".tmp", dir=models_dir))
    try:
        seeds_new = staging / f"{name}_seeds"
        seeds_new.mkdir()
        for t in trained:
            for f in t.files:
                shutil.copyfile(f, seeds_new / f.name)
        top = dict(zip(chosen.files, (staging / f"{name}{suffix}" for suffix in OUTPUT_SUFFIXES), strict=True))
        for src, dst in top.items():
            if dst.suffix != ".json":
                shutil.copyfile(src, dst)
        write_json({**final, "method": name}, staging / f"{name}_final.json")
        publish({dst: models_dir / dst.name for dst in top.values()}, publish_lock(models_dir, name),
                folders={seeds_new: models_dir / seeds_new.name})
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    for t in trained:
        shutil.rmtree(t.run_dir, ignore_errors=True)
    return final


def _digest_config(run_cfg: dict, device: str, precision: str) -> dict:
    return {**{k: v for k, v in run_cfg.items() if k not in NOT_IN_DIGEST}, "device": device, "precision": precision}


def save_outputs(model: IKNet, history: list[dict], final: dict, run_dir: Path, name: str, stem: str,
                 boom_cfg: dict, run_cfg: dict, mlrun: StageRun, log_model: bool, example, inputs: dict,
                 facts: dict | None = None) -> None:
    """Checkpoint, history and summary written in the training's private folder and logged from there, then
    renamed to its ``done/`` (with the logged model's URI) and the resume state removed: a finished seed that
    waits there for the others is not trained again."""
    run_dir.mkdir(parents=True, exist_ok=True)
    out = Path(tempfile.mkdtemp(prefix="out-", dir=run_dir))  # this process's own, even beside a twin training
    ckpt, hist, summary = (out / f"{stem}{suffix}" for suffix in OUTPUT_SUFFIXES)
    save_checkpoint(ckpt, model, boom_cfg, {"method": name, "history": history, "final": final,
                                            "config": run_cfg, "mlflow_run_id": mlrun.run_id, **(facts or {})})
    hist_df = pd.DataFrame(history)
    write_csv(hist_df, hist)
    write_json({"method": name, "overrides": sweep.job_overrides(), **(facts or {}), **final}, summary)
    if mlrun.active:
        from pipeline.evaluation.plots import training_curves

        mlrun.log_figure(training_curves({name: hist_df}), f"figures/training_{name}.png")
        kept = int(final["kept_step"])
        # registered (if at all) once the seeds are compared: the registry's newest is the network the stages use
        info = mlrun.log_network(model, example, ckpt, name=name, step=kept) if log_model else None
        model_id = info.model_id if info is not None else None
        if info is not None:
            (out / LOGGED_MODEL_FILE).write_text(info.model_uri)
        # after the curves, linked to the model: held-out values on the held-out holes, the kept step's
        # loss on the training data (the model page lists both datasets), the rest on their own
        kept_rec = next((r for r in history if r.get("kept")), history[-1])
        mlrun.log_summary({k: v for k, v in final.items() if k.startswith("val_")}, kept, model_id,
                          inputs.get("validation"))
        mlrun.log_summary({"loss": kept_rec["loss"]}, kept, model_id, inputs.get("training"))
        mlrun.log_summary({k: v for k, v in final.items() if not k.startswith("val_")}, kept, model_id)
        mlrun.log_artifact(ckpt)
    done = run_dir / DONE_DIR
    shutil.rmtree(done, ignore_errors=True)  # a twin training's, of the same digest: the same weights
    os.replace(out, done)
    (run_dir / RESUME_FILE).unlink(missing_ok=True)


@stage_main
def main(cfg: DictConfig) -> float:
    return run_stage(cfg, run, threads="train_threads")["val_hole_mm"]


if __name__ == "__main__":
    main()
