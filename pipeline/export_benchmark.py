"""Stage ``export`` (second half): latency of the deployable network in every runtime.

    python -m pipeline.export_benchmark                        # the `model` config: 4 x 512 GELU
    python -m pipeline.export_benchmark export.benchmark.compile=false

Needs no trained model (random weights of the ``model`` config; see :mod:`pipeline.deploy.latency`).
Writes ``paths.data/export/latency.{csv,md}`` and logs both to MLflow (run ``export-latency``). DVC's
``export`` stage runs it after the export, so the latency files are outputs of that stage.
"""

from __future__ import annotations

import logging
import os
import re

import pandas as pd
import torch
from omegaconf import DictConfig, OmegaConf

from pipeline.core.config import as_dict, project_path
from pipeline.core.io import write_csv, write_text
from pipeline.core.settings import parse
from pipeline.core.stage import run_stage, stage_main
from pipeline.deploy.latency import COLUMNS, latency_markdown, machine, measure
from pipeline.deploy.package import ExportSettings
from pipeline.tracking.runs import TrackingSettings, stage_run

log = logging.getLogger(__name__)
__all__ = ["COLUMNS", "run"]


def run(cfg: DictConfig) -> pd.DataFrame:
    st = parse(ExportSettings, OmegaConf.to_container(cfg.export, resolve=True), "export")
    tracking = TrackingSettings.from_config(cfg.tracking)
    load_before = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    threads = torch.get_num_threads()
    try:
        table, model = measure(cfg, st.benchmark, st.opset)
    finally:
        torch.set_num_threads(threads)  # isolate=false sets them in this process
    about = machine(load_before, st.benchmark.threads)
    out = project_path(cfg.paths.data) / "export"
    text = latency_markdown(table, model, about)
    write_csv(table, out / "latency.csv")
    write_text(text, out / "latency.md")
    with stage_run(tracking, "export-latency", {"stage": "export"}) as mlrun:
        mlrun.log_params({"export.benchmark": as_dict(cfg.export.benchmark), "model": as_dict(cfg.model),
                          "machine": about})
        slug = lambda name: re.sub(r"[^a-z0-9]+", "_", name.lower()).strip("_")  # noqa: E731  ONNX Runtime, 1 thread -> onnx_...
        mlrun.log_metrics({f"latency_ms.{slug(r.runtime)}.holes_{r.holes}": r.median_ms
                           for r in table.dropna(subset=["median_ms"]).itertuples()})
        for path in (out / "latency.csv", out / "latency.md"):
            mlrun.log_artifact(path, "export")
    log.info("latency written to %s\n%s", out / "latency.md", text)
    return table


@stage_main
def main(cfg: DictConfig) -> None:
    run_stage(cfg, run, threads=None)  # torch's default threads


if __name__ == "__main__":
    main()
