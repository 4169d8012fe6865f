"""Stage ``calibrate`` (paper 004): kinematic error compensation against identification.

    python -m pipeline.calibrate                                  # the study -> paths.data/calibration/
    python -m pipeline.calibrate measurements=field.csv           # fit a measurement file -> calibration.model_file

The study and the fit: :mod:`pipeline.calibration.study`. Writes ``results.csv`` / ``results.md``, the
figure, the true and identified models and the identifiability report, and logs them to MLflow.
"""

from __future__ import annotations

from omegaconf import DictConfig, OmegaConf

from pipeline.calibration.study import CalibrationSettings, face_holes, fit_file, residual_errors, run_study
from pipeline.core.config import project_path
from pipeline.core.errors import InputError
from pipeline.core.settings import parse
from pipeline.core.stage import run_stage, stage_main
from pipeline.tracking.runs import TrackingSettings, stage_run

__all__ = ["face_holes", "residual_errors", "run"]  # the study's helpers, as tests import them from here


def run(cfg: DictConfig):
    """The study (default), or the fit of a measurement file (``measurements=<file>``)."""
    settings = parse(CalibrationSettings, OmegaConf.to_container(cfg.calibration, resolve=True), "calibration")
    tracking = TrackingSettings.from_config(cfg.tracking)
    fitting = bool(cfg.get("measurements"))
    if fitting and not project_path(cfg.measurements).is_file():  # before any run exists
        raise InputError(f"measurements = {cfg.measurements}: no such file")
    with stage_run(tracking, "calibrate-fit" if fitting else "calibrate", {"stage": "calibrate"}) as mlrun:
        mlrun.log_params({"calibration": OmegaConf.to_container(cfg.calibration, resolve=True),
                          "measurements": str(cfg.get("measurements"))})
        return fit_file(cfg, settings, mlrun) if fitting else run_study(cfg, settings, mlrun)


@stage_main
def main(cfg: DictConfig) -> None:
    run_stage(cfg, run, threads="calibrate_threads")  # one thread: see conf/runtime/


if __name__ == "__main__":
    main()
