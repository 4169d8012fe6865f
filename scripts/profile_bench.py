"""Benchmark (docs/plans_to_rig.md, "Profiles: what they cost"): the compiled hybrid solver in the reference
horseshoe and in each example profile, side by side in one run.

    python scripts/profile_bench.py [holes] [single] [hydra overrides ...]    # default: 20 000 holes, 1000 alone

Per drift (conf/tunnel/horseshoe.yaml, then every CSV of conf/tunnel/profiles/): ``holes`` holes drawn like
Omega_unsup for that drift (collars uniform in its profile less 0.2 m, x in 6-7 m, a 15 deg cone, holes whose
feed beam alone breaks a safety distance redrawn; seed 2026), solved by the benchmark's ``hybrid_compiled``
(the distilled start network of paths.data/models, from ``dvc repro``): batched (holes/s, the median of
repeats), then the first ``single`` holes one at a time on one thread (median, p95, p99 of the latency), as
the benchmark stage measures it (pipeline.evaluation.solver_benchmark.measure). The network was trained in the
horseshoe: in a profile it is only the hybrid's start. One MLflow run (``profile-benchmark``) holds the table.
"""

from __future__ import annotations

import sys

import pandas as pd
import torch

from pipeline.assembly.build import build_safety, hole_sampling
from pipeline.core.config import CONF_DIR, as_dict, compose, project_path
from pipeline.core.settings import parse
from pipeline.data.holes import joint_box, sample_holes
from pipeline.evaluation.solver_benchmark import SolverBenchmarkSettings, build_solvers, measure
from pipeline.solvers.hybrid import HybridSettings
from pipeline.tracking.runs import TrackingSettings, stage_run

SEED = 2026


def drifts() -> dict[str, dict]:
    out = {"horseshoe (conf/tunnel/horseshoe.yaml)": {"kind": "horseshoe", "width": 5.0, "wall_height": 3.2}}
    for path in sorted((CONF_DIR / "tunnel" / "profiles").glob("*.csv")):
        out[f"profile {path.name}"] = {"kind": "profile", "file": str(path)}
    return out


def main(argv: list[str]) -> None:
    n = int(argv[0]) if argv else 20_000  # 5 000 left the batched rate varying by a third from run to run
    single = int(argv[1]) if len(argv) > 1 else 1000
    cfg = compose(argv[2:])
    settings = parse(SolverBenchmarkSettings, as_dict(cfg.solver_benchmark), "solver_benchmark")
    hybrid = parse(HybridSettings, cfg.solver, "solver")
    sampling = hole_sampling(cfg.holes)
    box = cfg.holes.sup.get("box")
    models = project_path(cfg.paths.data) / "models"
    rows = []
    for name, tunnel in drifts().items():
        safety = build_safety(cfg.boom, tunnel, cfg.safety)
        vertices = len(safety.tunnel.yz) if safety.tunnel.kind == "profile" else 0
        pose, _ = sample_holes(n, safety, sampling, SEED)
        solvers = build_solvers(["hybrid_compiled"], settings.solvers,  # with its start's entry
                                safety, models, joint_box(safety.boom, None if box is None else as_dict(box)), hybrid)
        solver = solvers["hybrid_compiled"][0]
        row, _ = measure(solver, pose, safety.boom.preview_depth, safety, single)
        rows.append({"drift": name, "vertices": vertices, **row})
        print({k: rows[-1][k] for k in ("drift", "holes_per_s", "ok_share", "single_ms_per_hole", "single_ms_p99")},
              flush=True)
    table = pd.DataFrame(rows)
    base = table.iloc[0]
    table["single_vs_horseshoe"] = table["single_ms_per_hole"] / base["single_ms_per_hole"]
    cols = ["drift", "vertices", "holes", "ok_share", "hole_mm_max", "holes_per_s", "single_ms_per_hole",
            "single_ms_p95", "single_ms_p99", "single_vs_horseshoe"]
    print(table[cols].to_markdown(index=False, floatfmt=".4g"))
    with stage_run(TrackingSettings.from_config(cfg.tracking), "profile-benchmark",
                   {"stage": "script", "mode": "benchmark"}) as run:
        run.log_params({"holes": n, "single": single, "seed": SEED, "threads": torch.get_num_threads()})
        run.log_table(table, "profiles.json")
        run.log_metrics({"min_holes_per_s": float(table["holes_per_s"].min()),
                         "max_single_vs_horseshoe": float(table["single_vs_horseshoe"].max())})


if __name__ == "__main__":
    main(sys.argv[1:])
