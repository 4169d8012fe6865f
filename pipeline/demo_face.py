"""Stage ``demo_face``: write the demo drill plan, ``paths.data/plans/demo_face.{csv,xml}``.

    python -m pipeline.demo_face

A realistic, drillable round for the configured boom, tunnel and safety distances (CSV and IREDES,
the same holes; see :func:`pipeline.plans.demo_face.demo_face`). The same config gives
byte-identical files. A stage of its own so that no study stage imports the product side.
"""

from __future__ import annotations

import logging
from pathlib import Path

from omegaconf import DictConfig

from pipeline.assembly.build import build_safety
from pipeline.core.config import project_path
from pipeline.core.stage import run_stage, stage_main
from pipeline.plans.demo_face import write_demo_plan

log = logging.getLogger(__name__)


def run(cfg: DictConfig) -> list[Path]:
    """The stage on a composed config; returns the files it wrote."""
    written = write_demo_plan(build_safety(cfg.boom, cfg.tunnel, cfg.safety), project_path(cfg.paths.data) / "plans")
    log.info("wrote %s", ", ".join(str(p) for p in written))
    return written


@stage_main
def main(cfg: DictConfig) -> None:
    run_stage(cfg, run, threads=None)  # torch's default threads


if __name__ == "__main__":
    main()
