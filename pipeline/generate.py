"""Stage ``generate``: write the hole datasets under ``paths.data/holes``.

    python -m pipeline.generate                      # defaults of conf/config.yaml
    python -m pipeline.generate holes.unsup.size=2000 holes.cone_deg=10

Writes ``holes/``: ``train.parquet`` (Omega_unsup), ``test_group_<k>.parquet``, ``sup.parquet``
(Omega_sup, with joints) and ``meta.json`` (counts, seeds, statistics, each file's MD5), swapped in
whole. The same seeds give byte-identical files. The demo drill plan is the product side's
(``python -m pipeline.demo_face``).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

from omegaconf import DictConfig

from pipeline.assembly.build import build_safety, hole_sampling
from pipeline.core.config import as_dict, project_path
from pipeline.core.errors import ConfigError
from pipeline.core.io import save_figure
from pipeline.core.settings import SEED_MAX, parse, rule
from pipeline.core.stage import run_stage, stage_main
from pipeline.data.couplings import parse_couplings
from pipeline.data.hole_sets import MAX_SET, MAX_TEST_GROUPS, SupervisedSet, build_hole_sets, write_hole_sets
from pipeline.data.holes import joint_box
from pipeline.data.tables import POSE_COLUMNS
from pipeline.evaluation.plots import collar_clouds
from pipeline.solvers.labels import continuation, home_branch
from pipeline.tracking.runs import TrackingSettings, stage_run

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SetSize:
    size: int = field(metadata=rule(ge=1, le=MAX_SET))
    seed: int = field(metadata=rule(ge=0, le=SEED_MAX))


@dataclass(frozen=True)
class TestGroups:
    size: int = field(metadata=rule(ge=1, le=MAX_SET))
    seeds: list[int] = field(metadata=rule(ge=0, le=SEED_MAX, min_items=1, max_items=MAX_TEST_GROUPS))


def supervised_sets(holes) -> dict[str, SupervisedSet]:
    """``sup`` (paper 000's Omega_sup) and every ``holes.sup_variants`` entry (e.g. SIKM's best variant)."""
    sets = {"sup": parse(SupervisedSet, {k: v for k, v in as_dict(holes.sup).items() if k != "box"}, "holes.sup")}
    for name, node in (holes.get("sup_variants") or {}).items():
        if name in ("sup", "train") or name.startswith("test_group"):
            raise ConfigError(f"holes.sup_variants.{name}: the name is taken by another hole table")
        try:
            sets[name] = parse(SupervisedSet, as_dict(node), f"holes.sup_variants.{name}")
        except ConfigError as exc:
            if str(exc).startswith("holes.sup"):
                raise
            # a rule between settings (SupervisedSet.__post_init__) does not know its node: name it
            raise ConfigError(f"holes.sup_variants.{name}: {exc}") from None
    return sets


def check_couplings(boom, sup_sets: dict[str, SupervisedSet]) -> None:
    """Every set's couplings parse against the boom (before any sampling)."""
    for name, spec in sup_sets.items():
        if spec.couplings is not None:
            where = "holes.sup" if name == "sup" else f"holes.sup_variants.{name}"
            parse_couplings(spec.couplings, boom.joint_names, f"{where}.couplings")


def run(cfg: DictConfig) -> dict:
    """The stage on a composed config; returns the metadata it wrote."""
    t0 = time.perf_counter()
    unsup, sup_sets = parse(SetSize, cfg.holes.unsup, "holes.unsup"), supervised_sets(cfg.holes)
    test = parse(TestGroups, cfg.holes.test, "holes.test")
    tracking = TrackingSettings.from_config(cfg.tracking)
    safety = build_safety(cfg.boom, cfg.tunnel, cfg.safety)
    box = cfg.holes.sup.get("box")
    box = None if box is None else as_dict(box)
    joint_box(safety.boom, box)  # a bad box fails here, before any sampling
    check_couplings(safety.boom, sup_sets)
    data = project_path(cfg.paths.data)
    labellers = {"home_branch": home_branch(safety), "continuation": continuation(safety),  # injected: data sits below
                 "continuation_clear": continuation(safety, clear=True),
                 "continuation_rescue": continuation(safety, rescue=True)}
    with stage_run(tracking, "generate", {"stage": "generate"}) as mlrun:
        mlrun.log_params({k: as_dict(cfg[k]) for k in ("holes", "safety", "tunnel")})
        tables, meta = build_hole_sets(safety, hole_sampling(cfg.holes), unsup.size, unsup.seed, test.size,
                                       list(test.seeds), sup_sets, box, labellers)
        meta["config"] = {k: as_dict(cfg[k]) for k in ("boom", "tunnel", "safety", "holes")}
        fig = collar_clouds({"Omega_sup": tables["sup.parquet"][POSE_COLUMNS].to_numpy(),
                             "Omega_unsup": tables["train.parquet"][POSE_COLUMNS].to_numpy()}, safety.tunnel,
                            {"Omega_sup": meta["sup_sets"]["sup"]["face_window_share"]})
        written = write_hole_sets(tables, meta, data / "holes")  # only after every table is built
        save_figure(fig, data / "figures" / "collar_clouds.png")
        mlrun.log_figure(fig, "figures/collar_clouds.png")
        mlrun.log_metrics({"unsup_rejection_rate": meta["unsup_rejection"]["rejection_rate"],
                           **{f"{name}.face_window_share": st["face_window_share"]
                              for name, st in meta["sup_sets"].items()},
                           **{f"{name}.consistency.{k}": st["consistency"][k]
                              for name, st in meta["sup_sets"].items()
                              for k in ("ratio_p95", "branch_jump_share")},
                           **{f"sup.violation_share.{k}": v
                              for k, v in meta["sup_sets"]["sup"]["violation_share"].items()}})
        mlrun.log_artifact(data / "holes" / "meta.json")
    log.info("wrote %d files to %s in %.1f s; Omega_unsup rejection rate %.1f %%; Omega_sup face-like %.1f %%",
             len(written), data / "holes", time.perf_counter() - t0, 100 * meta["unsup_rejection"]["rejection_rate"],
             100 * meta["sup_sets"]["sup"]["face_window_share"])
    return meta


@stage_main
def main(cfg: DictConfig) -> None:
    run_stage(cfg, run, threads=None)  # torch's default threads


if __name__ == "__main__":
    main()
