"""Stage ``export``: the trained networks in the formats a rig controller loads.

    python -m pipeline.export                               # export.methods (default: cuikm)
    python -m pipeline.export 'export.methods=[cuikm,uikm]' export.onnx=true

Writes under ``paths.data/export/``, for each method (docs/export.md): ``<method>.onnx`` (ONNX at opset
``export.opset``; needs the optional extra ``pip install -c constraints.txt -e ".[onnx]"``, else skipped
with one log line under ``export.onnx=auto`` or refused under ``export.onnx=true``), ``<method>.pt2``
(``torch.export``), ``<method>.ts`` (TorchScript, deprecated in torch; ``export.torchscript``) and
``<method>.manifest.json`` (names, shapes, joints and units, boom, versions, each file's sha256 and its
largest difference to eager torch on ``export.check.holes`` holes, measured by running each file as
written). Nothing is published for a method unless every file passes (:mod:`pipeline.deploy.package`).
"""

from __future__ import annotations

import logging

import torch
from omegaconf import DictConfig, OmegaConf

from pipeline.assembly.build import load_boom
from pipeline.core.config import project_path
from pipeline.core.settings import parse
from pipeline.core.stage import run_stage, stage_main
from pipeline.deploy.package import ExportSettings, check_poses, export_method
from pipeline.learning.network_source import load_network
from pipeline.tracking.runs import TrackingSettings, stage_run

log = logging.getLogger(__name__)


def run(cfg: DictConfig) -> dict[str, dict]:
    """Export every network of ``export.methods``; returns the manifests by method."""
    st = parse(ExportSettings, OmegaConf.to_container(cfg.export, resolve=True), "export")
    tracking = TrackingSettings.from_config(cfg.tracking)
    fmts = st.formats()
    models = project_path(cfg.paths.data) / "models"
    # every checkpoint read (and checked against the boom it was trained on) before writing
    networks = {m: load_network(models / f"{m}.pt", None) for m in st.methods}
    if "torchscript" in fmts:
        log.info("TorchScript (.ts) is deprecated in torch %s; written for libtorch rigs (export.torchscript=false "
                 "skips it)", torch.__version__)
    out = project_path(cfg.paths.data) / "export"
    manifests = {}
    with stage_run(tracking, "export", {"stage": "export"}) as mlrun:
        mlrun.log_params({"export": {"methods": st.methods, "formats": fmts, "opset": st.opset}})
        for method, (model, meta) in networks.items():
            pose = check_poses(meta["boom"], cfg.tunnel, cfg.safety, cfg.holes, st.check.holes, st.check.seed)
            manifests[method] = m = export_method(method, models / f"{method}.pt", model.requires_grad_(False),
                                                  load_boom(meta["boom"]), pose, out, st, fmts)
            mlrun.log_metrics(m["check"]["max_abs_diff_vs_eager"], prefix=f"{method}.max_abs_diff.")
            mlrun.log_artifact(out / f"{method}.manifest.json", "export")
            log.info("%s: %s written to %s; largest difference to eager torch on %d holes: %s", method,
                     ", ".join(f["file"] for f in m["files"].values()), out, st.check.holes,
                     ", ".join(f"{k} {v:.1e}" for k, v in m["check"]["max_abs_diff_vs_eager"].items()))
    return manifests


@stage_main
def main(cfg: DictConfig) -> None:
    run_stage(cfg, run, threads=None)  # torch's default threads


if __name__ == "__main__":
    main()
