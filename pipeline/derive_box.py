"""Derive Omega_sup's working box once, reproducibly, and write it as ``conf/sup_box/working.yaml``.

    python -m pipeline.derive_box                       # 5000 holes, seed 7, 1st-99th percentile
    python -m pipeline.params                           # then recompose params.yaml

See :mod:`pipeline.learning.supervised_set` (the box) and :mod:`pipeline.solvers.labels` (the local search).
The file is configuration (committed); ``generate`` reads it.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import yaml
from omegaconf import DictConfig

from pipeline.assembly.build import build_safety, hole_sampling
from pipeline.core.config import CONF_DIR, IN_CHECKOUT, base_dir
from pipeline.core.io import write_text
from pipeline.core.settings import SEED_MAX, parse, rule
from pipeline.core.stage import run_stage, stage_main
from pipeline.learning.supervised_set import derive_working_box
from pipeline.solvers.labels import local_search

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class DeriveBoxSettings:
    holes: int = field(default=5000, metadata=rule(ge=100, le=1_000_000))  # each solved by the local search
    seed: int = field(default=7, metadata=rule(ge=0, le=SEED_MAX))
    percentiles: list[float] = field(default_factory=lambda: [1.0, 99.0], metadata=rule(ge=0, le=100))


def run(cfg: DictConfig) -> dict:
    s = parse(DeriveBoxSettings, cfg.derive_box, "derive_box")
    safety = build_safety(cfg.boom, cfg.tunnel, cfg.safety)
    box, stats = derive_working_box(safety, hole_sampling(cfg.holes), s.holes, s.seed, tuple(s.percentiles),
                                    solve=local_search(safety))
    header = (
        "# @package holes.sup\n"
        "# Omega_sup's working box (docs/reference.md, section 3): per joint [lower, upper], deg for revolute "
        "joints, m for\n"
        "# prismatic ones. Derived by `python -m pipeline.derive_box` (pipeline/learning/supervised_set.py, with\n"
        f"# the local search of pipeline/solvers/labels.py): the percentiles {stats['percentiles']} of the exact,\n"
        f"# clear solutions that the search finds for {stats['holes']} holes drawn like Omega_unsup with seed "
        f"{stats['seed']}\n# ({stats['ok']} of them solved so). Full mechanical ranges instead: sup_box=full.\n"
    )
    text = header + yaml.safe_dump({"box": box}, sort_keys=False, default_flow_style=None)
    # the checkout's config; installed from the wheel, the packaged configs stay as shipped: ./conf/sup_box/
    out = (CONF_DIR if IN_CHECKOUT else base_dir() / "conf") / "sup_box" / "working.yaml"
    write_text(text, out)
    log.info("working box from %d of %d holes: %s -> %s", stats["ok"], stats["holes"], box, out)
    return {"box": box, **stats}


@stage_main
def main(cfg: DictConfig) -> None:
    run_stage(cfg, run, threads="threads")


if __name__ == "__main__":
    main()
