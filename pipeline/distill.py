"""Stage ``distill``: a small start network for the hybrid, distilled from a trained one (CUIKM).

    python -m pipeline.distill                                  # data/models/cuikm_start.pt from cuikm.pt
    python -m pipeline.distill distill.width=64 distill.name=cuikm_start64

Reads ``paths.data/models/<distill.teacher>.pt``; writes ``<distill.name>.pt`` (an ordinary network
checkpoint: ``kind: network`` and a hybrid's ``init`` load it as they load CUIKM) and
``<distill.name>_final.json`` (how closely it imitates the teacher, and each network's own error), the two
published together, and logs both to MLflow (run ``distill-<name>``). The method:
:mod:`pipeline.learning.distillation`; why a start network: docs/benchmarks.md, "A distilled start".
"""

from __future__ import annotations

import logging
import shutil
import tempfile
import time
from dataclasses import asdict
from pathlib import Path

from omegaconf import DictConfig

from pipeline.assembly.build import build_safety, hole_sampling
from pipeline.core.config import as_dict, project_path
from pipeline.core.errors import InputError
from pipeline.core.io import publish, publish_lock, require_writable, write_json
from pipeline.core.stage import run_stage, stage_main
from pipeline.data.holes import sample_holes
from pipeline.learning.distillation import DistillSettings, distil, imitation_metrics
from pipeline.learning.models import load_checkpoint, save_checkpoint
from pipeline.learning.network_source import load_network
from pipeline.tracking.runs import TrackingSettings, stage_run

log = logging.getLogger(__name__)


def run(cfg: DictConfig) -> dict:
    s, tracking = DistillSettings.from_config(cfg.distill), TrackingSettings.from_config(cfg.tracking)
    safety, sampling = build_safety(cfg.boom, cfg.tunnel, cfg.safety), hole_sampling(cfg.holes)
    models = require_writable(project_path(cfg.paths.data) / "models", "paths.data")
    teacher_path = models / f"{s.teacher}.pt"
    teacher, meta = load_network(teacher_path, safety.boom)
    if meta.get("boom") is not None and meta["boom"] != as_dict(cfg.boom):
        raise InputError(f"{teacher_path}: trained for another boom than the configured one ({cfg.boom.name}); "
                         f"retrain it or configure its boom")
    _refuse_to_replace_another_network(models / f"{s.name}.pt")
    # holes drawn like Omega_unsup, the pool and the held-out ones from two seeds of their own
    pool, _ = sample_holes(s.pool, safety, sampling, s.seed)
    val, _ = sample_holes(s.val_size, safety, sampling, s.seed + 1)
    params = {"distill": asdict(s), "teacher_file": str(teacher_path), "teacher_hparams": meta["hparams"],
              "teacher_mlflow_run_id": meta.get("mlflow_run_id")}
    with stage_run(tracking, f"distill-{s.name}", {"stage": "distill", "method": s.name}) as mlrun:
        mlrun.log_params(params)
        t0 = time.perf_counter()
        student, history = distil(teacher, pool.float(), s.width, s.depth, s.activation, s.steps, s.batch_size,
                                  s.lr, s.lr_min, s.seed)
        final = {"method": s.name, "teacher": s.teacher, "train_seconds": time.perf_counter() - t0,
                 **imitation_metrics(student, teacher, safety.boom, val.float())}
        for rec in history:
            mlrun.log_metrics({"loss": rec["loss"], "lr": rec["lr"]}, step=rec["step"])
        mlrun.log_metrics({k: v for k, v in final.items() if k not in ("method", "teacher")})
        tmp = Path(tempfile.mkdtemp(prefix=f".{s.name}.distill-", dir=models))
        try:  # written and logged in a private folder, then published together; the folder never stays
            files = {tmp / f"{s.name}.pt": models / f"{s.name}.pt",
                     tmp / f"{s.name}_final.json": models / f"{s.name}_final.json"}
            ckpt, summary = files
            save_checkpoint(ckpt, student, as_dict(cfg.boom), {"method": s.name, "history": history, "final": final,
                                                               "config": params, "mlflow_run_id": mlrun.run_id})
            write_json(final, summary)
            mlrun.log_artifact(ckpt)
            mlrun.log_artifact(summary)
            publish(files, publish_lock(models, s.name))
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    log.info("distilled %s (%d x %d %s) from %s in %.0f s: joints within %.4f of their ranges (p95), its own "
             "hole error %.1f mm (the teacher's %.2f mm) -> %s", s.name, s.depth, s.width, s.activation, s.teacher,
             final["train_seconds"], final["joint_dev_p95"], final["student_hole_mm_mean"],
             final["teacher_hole_mm_mean"], models / f"{s.name}.pt")
    return final


def _refuse_to_replace_another_network(path: Path) -> None:
    """A student replaces an earlier student, never a trained network (``distill.name=uikm`` would)."""
    if not path.exists():
        return
    _, meta = load_checkpoint(path)
    if "distill" not in (meta.get("config") or {}):
        raise InputError(f"{path}: holds a network that was not distilled (method {meta.get('method')!r}); "
                         f"the student would replace it: choose another distill.name")


@stage_main
def main(cfg: DictConfig) -> None:
    run_stage(cfg, run, threads="train_threads")


if __name__ == "__main__":
    main()
