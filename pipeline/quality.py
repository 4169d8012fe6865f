"""Stage ``quality``: what the rig drilled, read back against the plan.

    python -m pipeline.quality plan=data/round/demo_face.csv log=data/round/demo_face_executed_quality.xml
    python -m pipeline.quality plan=round_57.xml log=rig7/round_57_qual.xml strict=true

Reads the plan (CSV or IREDES) and the rig's IREDES quality log (``DRPQual``: either checksum convention, a
missing ``HoleName``, points local to an ``IR:TMatrix``), both in the plan's frame, and writes
``<plan stem>_quality.csv`` (per hole: ``hole_id, boom, status, collar_dev_m, toe_dev_m, direction_err_deg,
length_err_m, within``), ``_quality.json`` (the share within tolerance, mean / p95 / max deviations, the plan's
holes the log lacks and the log's holes the plan lacks, the files' checksum states) and ``_quality.png`` (the face
coloured by deviation), published as one set, and an MLflow run. ``strict=true``: exit 1 unless every planned hole
was drilled within tolerance (:mod:`pipeline.plans.deviations`).
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass, field

from omegaconf import DictConfig

from pipeline.core.config import as_dict, project_path
from pipeline.core.errors import ConfigError, StrictCheckFailed
from pipeline.core.io import require_writable
from pipeline.core.settings import coerce, parse, rule
from pipeline.core.stage import run_stage, stage_main
from pipeline.evaluation.plots import deviation_figure
from pipeline.plans.deviations import deviations, face_coordinates
from pipeline.plans.drpqual import read_quality_log
from pipeline.plans.output import solution_paths, write_solution_set
from pipeline.plans.read import read_plan
from pipeline.tracking.runs import TrackingSettings, stage_run

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class QualitySettings:
    """The ``quality`` node (conf/quality/default.yaml)."""

    collar_tol_m: float = field(default=0.1, metadata=rule(gt=0))
    toe_tol_share: float = field(default=0.06, metadata=rule(gt=0, le=1))
    figure: bool = True
    max_log_mb: float = field(default=256.0, metadata=rule(gt=0, le=4096))  # as solve.max_plan_mb


def run(cfg: DictConfig) -> dict:
    settings = parse(QualitySettings, cfg.quality, "quality")
    tracking = TrackingSettings.from_config(cfg.tracking)
    if not cfg.get("log"):
        raise ConfigError("log = null: give the rig's quality log, log=<DRPQual.xml>")
    plan_path, log_path = project_path(coerce(cfg.plan, "str", "plan")), project_path(coerce(cfg.log, "str", "log"))
    strict = coerce(cfg.get("strict", False), "bool", "strict")
    paths = solution_paths(plan_path, project_path(cfg.out) if cfg.get("out") else None, "quality", (log_path,))
    require_writable(paths.csv.parent, "out (its folder)")
    iredes = as_dict(cfg.solve.iredes)
    plan = read_plan(plan_path, **(iredes if plan_path.suffix.lower() == ".xml" else {}))
    drilled = read_quality_log(log_path, max_mb=settings.max_log_mb, **iredes)
    for line in [*plan.report(), *(p.describe(str(log_path)) for p in drilled.problems)]:
        log.warning("skipped: %s", line)
    table, summary = deviations(plan.holes, drilled.holes, settings.collar_tol_m, settings.toe_tol_share)
    record = {"plan": str(plan_path), **plan.provenance(), **drilled.provenance(), **summary}
    with stage_run(tracking, f"quality-{plan_path.stem}", {"stage": "quality", "plan": str(plan_path)}) as mlrun:
        mlrun.log_params({"plan": str(plan_path), "log": str(log_path), "quality": asdict(settings)})
        mlrun.log_metrics({k: v for k, v in summary.items() if isinstance(v, (int, float)) and v is not None})
        title = (f"{plan.name or plan_path.stem}: {summary['within']} of {summary['holes_planned']} holes within "
                 f"tolerance; collar deviation mean {1000 * (summary['collar_dev_m_mean'] or 0):.1f} mm")
        fig = deviation_figure(face_coordinates(plan.holes), table, title) if settings.figure else None
        if fig is not None:
            mlrun.log_figure(fig, "quality.png")
        write_solution_set(paths, table, record, fig, lambda staged: mlrun.log_artifact(staged["csv"]))
    log.info("%s: %d of %d holes within tolerance (collar mean %.4f m, p95 %.4f m); %d missing from the log -> %s",
             plan_path.name, summary["within"], summary["holes_planned"], summary["collar_dev_m_mean"] or 0.0,
             summary["collar_dev_m_p95"] or 0.0, len(summary["missing_from_log"]), paths.csv)
    if strict and summary["within"] != summary["holes_planned"]:
        raise StrictCheckFailed(f"strict: {summary['holes_planned'] - summary['within']} of "
                                f"{summary['holes_planned']} holes not drilled within tolerance (see {paths.csv})")
    return summary


@stage_main
def main(cfg: DictConfig) -> None:
    run_stage(cfg, run, threads=None)


if __name__ == "__main__":
    main()
