"""Stage ``field_boom``: the boom a rig really has, and what a total station measures of it.

    python -m pipeline.field_boom          # -> paths.data/loop/true_boom.yaml, paths.data/loop/measurements.csv

The as-drilled loop (docs/calibration.md, "The loop: plan, drill, log, calibrate") needs a boom that is not its
nominal model: the nominal boom with error twists of an error level (``field_boom.level``, drawn with
``field_boom.seed``, as the calibration study draws its true boom), written as a model file
(``execute.true_boom_model=`` of ``execute`` drills through it), and ``field_boom.poses`` poses of it measured
with the sensor's noise (joints uniform over their ranges), written as the measurement file
``python -m pipeline.calibrate measurements=`` fits. Deterministic: the same settings write the same files.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import torch
from omegaconf import DictConfig

from pipeline.assembly.build import load_boom
from pipeline.calibration.error_model import BoomWithErrors, ErrorLevel, draw_errors
from pipeline.calibration.measurements import Sensor, simulate, write_measurements
from pipeline.calibration.model_file import save_model
from pipeline.core.config import as_dict, load_group_file, project_path
from pipeline.core.io import require_writable
from pipeline.core.settings import parse, rule
from pipeline.core.stage import run_stage, stage_main

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FieldBoomSettings:
    level: str = "field"
    seed: int = field(default=13, metadata=rule(ge=0, le=2**32 - 1))
    poses: int = field(default=60, metadata=rule(ge=1, le=100_000))
    pose_seed: int = field(default=1305, metadata=rule(ge=0, le=2**32 - 1))
    noise_seed: int = field(default=1306, metadata=rule(ge=0, le=2**32 - 1))
    sensor: str = "total_station"
    folder: str = "data/loop"


def run(cfg: DictConfig) -> dict:
    s = parse(FieldBoomSettings, as_dict(cfg.field_boom), "field_boom")
    level = ErrorLevel(**load_group_file("calibration/level", s.level))
    sensor = Sensor(**load_group_file("calibration/sensor", s.sensor))
    folder = require_writable(project_path(s.folder), "field_boom.folder")
    boom = load_boom(cfg.boom)
    twists = draw_errors(boom, level, seed=s.seed)
    true = BoomWithErrors(boom, twists)
    g = torch.Generator().manual_seed(s.pose_seed)
    lo, hi = boom.limits(torch.float64)
    q = boom.with_locks(lo + (hi - lo) * torch.rand(s.poses, boom.n_joints, generator=g, dtype=torch.float64))
    save_model(folder / "true_boom.yaml", boom, twists,
               notes=[f"the field boom of the as-drilled loop: level {s.level}, seed {s.seed} (pipeline.field_boom)"])
    write_measurements(simulate(true, q, sensor, s.noise_seed), boom, folder / "measurements.csv")
    with torch.no_grad():
        off = (true.tool_pose(q)[0] - boom.tool_pose(q)[0]).norm(dim=-1)
    out = {"true_boom": str(folder / "true_boom.yaml"), "measurements": str(folder / "measurements.csv"),
           "poses": s.poses, "collar_off_nominal_mm_mean": 1000 * float(off.mean())}
    log.info("field boom %s (level %s, seed %d): its tool point %.1f mm from the nominal on average over the %d "
             "measured poses -> %s", boom.name, s.level, s.seed, out["collar_off_nominal_mm_mean"], s.poses, folder)
    return out


@stage_main
def main(cfg: DictConfig) -> None:
    run_stage(cfg, run, threads=None)


if __name__ == "__main__":
    main()
