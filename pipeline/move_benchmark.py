"""Stage ``move_benchmark``: collision-free moves of a rig's booms on a plan, and what redundancy saves.

    python -m pipeline.move_benchmark rig=twin                          # 200 seeded pairs per boom
    python -m pipeline.move_benchmark rig=twin move_benchmark.pairs=1000  # the issue's 1000

Solves the plan (``plan``, the demo face by default) by every boom of the rig (the reach table, the
others at park; network ``solve.network``, hybrid ``solver``), then measures (pipeline/rig_benchmarks/moves.py):
moves between random pairs of each boom's ok holes with every other boom standing at a random ok hole
of its own; chained against independent solutions (summed move time); boom-boom clearances per second.
Writes ``paths.data/benchmark/moves_<rig>.csv`` (one row per pair), ``redundancy_<rig>.csv`` and
``moves_<rig>.json`` (the summary), and logs them to MLflow. Product side: no study stage imports it.
"""

from __future__ import annotations

import logging
import math
import time

from omegaconf import DictConfig

from pipeline.assembly.rig import composed_rig
from pipeline.calibration.model_file import model_setting
from pipeline.core.config import as_dict, project_path
from pipeline.core.errors import ConfigError
from pipeline.core.io import write_csv, write_json
from pipeline.core.settings import coerce, parse
from pipeline.core.stage import run_stage, stage_main
from pipeline.motion.timing import rig_motions
from pipeline.plans.navigation import NavigationSettings, navigation_params
from pipeline.plans.reach import solved_reach
from pipeline.plans.read import read_plan_in_rig_frame
from pipeline.rig_benchmarks.moves import MoveBenchmarkSettings, distance_rate, move_benchmark, redundancy
from pipeline.solvers.hybrid import HybridSettings
from pipeline.solvers.network_start import first_starts, network_source
from pipeline.tracking.runs import TrackingSettings, stage_run

log = logging.getLogger(__name__)


def run(cfg: DictConfig) -> dict:
    settings = parse(MoveBenchmarkSettings, as_dict(cfg.move_benchmark), "move_benchmark")
    hybrid = parse(HybridSettings, cfg.solver, "solver")
    tracking = TrackingSettings.from_config(cfg.tracking)
    rig = composed_rig(cfg, model_setting)  # its booms from boom, boom_model, boom_models: before any work
    if len(rig) < 2:
        raise ConfigError(f"rig = {rig.name!r} ({rig.spec.source}) has one boom; the move benchmark stands another "
                          "boom in the way: use rig=twin or rig=trio")
    limits = [m.joints for m in rig_motions(as_dict(cfg.motion), rig.booms)]
    plan_path = project_path(coerce(cfg.plan, "str", "plan"))
    plan = read_plan_in_rig_frame(plan_path, parse(NavigationSettings, cfg.navigation, "navigation"),
                                  as_dict(cfg.solve.iredes))
    network = coerce(cfg.solve.network, "str", "solve.network")
    source = network_source(project_path(cfg.paths.data), network, cfg.solve.get("model_uri"))
    out = project_path(cfg.paths.data) / "benchmark"
    box = cfg.holes.sup.get("box")
    with stage_run(tracking, f"move-benchmark-{rig.name}", {"stage": "move_benchmark", "rig": rig.name}) as mlrun:
        mlrun.log_params({"plan": str(plan_path), "rig": rig.name, "move_benchmark": as_dict(cfg.move_benchmark),
                          "solver": as_dict(cfg.solver), "network": str(source), **navigation_params(plan)})
        first_start = first_starts(source, network, tracking.uri, "solve.model_uri")
        solvers, reach = solved_reach(plan, rig, first_start, hybrid, None if box is None else as_dict(box),
                                      f"hybrid ({network})")
        rates = distance_rate(rig, settings)
        saved = redundancy(rig, plan, reach, solvers, limits)
        started = time.perf_counter()
        moves, summary = move_benchmark(rig, plan, reach, solvers, limits, settings)
        summary = {"rig": rig.name, "plan": str(plan_path), "pairs_per_boom": settings.pairs,
                   "wall_s": time.perf_counter() - started, **summary, **rates,
                   "redundancy": saved.to_dict(orient="records")}
        write_csv(moves, out / f"moves_{rig.name}.csv")
        write_csv(saved, out / f"redundancy_{rig.name}.csv")
        # a boom with no move (every pair blocked, or no ok hole) has no median: null in JSON, no metric
        summary = {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in summary.items()}
        write_json(summary, out / f"moves_{rig.name}.json")
        mlrun.log_metrics({k: v for k, v in summary.items() if isinstance(v, (int, float))})
        mlrun.log_table(moves, "moves.json")
        mlrun.log_table(saved, "redundancy.json")
    log.info("moves of rig %s: %s; redundancy: %s", rig.name,
             {k: v if v is None else round(v, 3) for k, v in summary.items() if k.startswith("all.")},
             saved.to_dict(orient="records"))
    return summary


@stage_main
def main(cfg: DictConfig) -> None:
    run_stage(cfg, run, threads="threads")


if __name__ == "__main__":
    main()
