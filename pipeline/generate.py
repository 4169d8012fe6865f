"""Stage ``generate``: write the hole datasets under ``paths.data/holes``.

    python -m pipeline.generate                      # defaults of conf/config.yaml
    python -m pipeline.generate holes.unsup.size=2000 holes.cone_deg=10

Writes ``train.parquet`` (Omega_unsup), ``test_group_<k>.parquet``, ``sup.parquet``
(Omega_sup, with joints) and ``meta.json``. The same seeds give byte-identical files.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import hydra
import pandas as pd
from omegaconf import DictConfig

from pipeline.core.build import build_safety
from pipeline.core.config import as_dict, project_path
from pipeline.core.errors import ConfigError
from pipeline.core.io import write_json
from pipeline.data.holes import HoleSampling, sample_holes, sample_joints
from pipeline.data.tables import holes_frame, joints_frame, write_parquet
from pipeline.geometry.collision import KINDS, SafetyModel

log = logging.getLogger(__name__)


def _count(value, field: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        raise ConfigError(f"{field} = {value!r}: expected a positive integer")
    return value


def _seed(value, field: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ConfigError(f"{field} = {value!r}: expected a non-negative integer seed")
    return value


def build_hole_sets(
    safety: SafetyModel,
    sampling: HoleSampling,
    unsup_size: int,
    unsup_seed: int,
    sup_size: int,
    sup_seed: int,
    test_size: int,
    test_seeds: list[int],
) -> tuple[dict[str, pd.DataFrame], dict]:
    """All hole tables by file name, and the statistics that go into ``meta.json``."""
    seeds = [unsup_seed, sup_seed, *test_seeds]
    if len(set(seeds)) != len(seeds):
        raise ConfigError(f"holes: seeds must all differ (unsup, sup, test...), got {seeds}")
    tables: dict[str, pd.DataFrame] = {}
    train, train_stats = sample_holes(unsup_size, safety, sampling, unsup_seed)
    tables["train.parquet"] = holes_frame(train)
    test_stats = []
    for k, seed in enumerate(test_seeds, start=1):
        poses, stats = sample_holes(test_size, safety, sampling, seed)
        tables[f"test_group_{k}.parquet"] = holes_frame(poses)
        test_stats.append(stats)
    boom = safety.boom
    q = sample_joints(sup_size, boom, sup_seed)
    frames = boom.frames(q)
    sup = pd.concat([joints_frame(q, boom.joint_names), holes_frame(boom.pose6_from_frames(frames))], axis=1)
    tables["sup.parquet"] = sup[["hole_id", *boom.joint_names, *sup.columns[len(boom.joint_names) + 1 :]]]
    violated = safety.violations(safety.clearances_from_frames(frames))
    any_violation = violated["self"] | violated["wall"] | violated["ground"] | violated["arch"]
    meta = {
        "counts": {name: len(df) for name, df in tables.items()},
        "seeds": {"unsup": unsup_seed, "sup": sup_seed, "test": list(test_seeds)},
        "unsup_rejection": train_stats,
        "test_rejection": test_stats,
        "sup_violation_share": {
            **{k: float(violated[k].double().mean()) for k in KINDS},
            "any": float(any_violation.double().mean()),
        },
    }
    return tables, meta


def write_hole_sets(tables: dict[str, pd.DataFrame], meta: dict, out_dir: Path) -> list[Path]:
    """Write every table, then ``meta.json``; each file lands whole or not at all."""
    paths = []
    for name, df in tables.items():
        write_parquet(df, out_dir / name)
        paths.append(out_dir / name)
    write_json(meta, out_dir / "meta.json")
    return [*paths, out_dir / "meta.json"]


def run(cfg: DictConfig) -> dict:
    """The stage on a composed config; returns the metadata it wrote."""
    t0 = time.perf_counter()
    holes = cfg.holes
    sampling = HoleSampling(tuple(holes.face_x), float(holes.cone_deg), float(holes.inset))
    safety = build_safety(cfg.boom, cfg.tunnel, cfg.safety)
    test_seeds = [_seed(s, f"holes.test.seeds[{i}]") for i, s in enumerate(holes.test.seeds)]
    tables, meta = build_hole_sets(
        safety,
        sampling,
        _count(holes.unsup.size, "holes.unsup.size"),
        _seed(holes.unsup.seed, "holes.unsup.seed"),
        _count(holes.sup.size, "holes.sup.size"),
        _seed(holes.sup.seed, "holes.sup.seed"),
        _count(holes.test.size, "holes.test.size"),
        test_seeds,
    )
    meta["config"] = {k: as_dict(cfg[k]) for k in ("boom", "tunnel", "safety", "holes")}
    out = project_path(cfg.paths.data) / "holes"
    written = write_hole_sets(tables, meta, out)  # only after every table is built
    log.info(
        "wrote %d files to %s in %.1f s; Omega_unsup rejection rate %.1f %%; Omega_sup violation share %s",
        len(written),
        out,
        time.perf_counter() - t0,
        100 * meta["unsup_rejection"]["rejection_rate"],
        {k: round(v, 4) for k, v in meta["sup_violation_share"].items()},
    )
    return meta


@hydra.main(version_base="1.3", config_path="../conf", config_name="config")
def main(cfg: DictConfig) -> None:
    run(cfg)


if __name__ == "__main__":
    main()
