"""The joint CP-SAT model against the round planner at equal wall time (docs/benchmarks.md, "Joint
CP-SAT model against the routing"):

    python scripts/joint_vs_routing.py [--faces demo 50] [--factors 1 2] [--out data/benchmark] [overrides ...]
    python scripts/joint_vs_routing.py --faces 50 --factors 1 rig=twin schedule.network=null runtime.threads=1

Overrides are the stage's (``rig=``, ``round.*``, ``schedule.network``, ``solver.*``); the default rig is
``twin``. Writes ``<out>/joint_vs_routing.{csv,md}`` and prints the table. Wall times are the machine's
of the moment: compare the rows of one run.
"""

import argparse
import logging

from pipeline.core.config import as_dict, compose, project_path
from pipeline.core.io import write_csv, write_text
from pipeline.core.settings import parse
from pipeline.core.stage import run_stage
from pipeline.rig_benchmarks.joint_vs_routing import joint_vs_routing, markdown
from pipeline.round.settings import parse_round
from pipeline.schedule import ScheduleSettings, benchmark_rigs
from pipeline.solvers.hybrid import HybridSettings
from pipeline.solvers.network_start import first_starts, network_source
from pipeline.tracking.runs import TrackingSettings


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--faces", nargs="+", default=["demo", "50"], help="demo and/or hole counts of generated faces")
    ap.add_argument("--factors", nargs="+", type=float, default=[1.0, 2.0], help="CP-SAT's wall time in planning times")
    ap.add_argument("--out", default=None, help="folder of the table (default: paths.data/benchmark)")
    ap.add_argument("overrides", nargs="*")
    args = ap.parse_args()
    cfg = compose(["rig=twin", *args.overrides])
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")

    def run(cfg):
        schedule = parse(ScheduleSettings, cfg.schedule, "schedule")
        settings = parse_round(as_dict(cfg.round), "round")
        hybrid = parse(HybridSettings, cfg.solver, "solver")
        tracking = TrackingSettings.from_config(cfg.tracking)
        case = benchmark_rigs(cfg, [str(cfg.rig.name)])[0]
        source = network_source(project_path(cfg.paths.data), schedule.network, schedule.model_uri)
        first_start = first_starts(source, schedule.network, tracking.uri, "schedule.model_uri")
        box = cfg.holes.sup.get("box")
        faces = [f if f == "demo" else int(f) for f in args.faces]
        folder = project_path(args.out) if args.out else project_path(cfg.paths.data) / "benchmark"
        folder.mkdir(parents=True, exist_ok=True)

        def write(table):  # after every row: a long run keeps what it measured
            write_csv(table, folder / "joint_vs_routing.csv")
            write_text(markdown(table), folder / "joint_vs_routing.md")

        table = joint_vs_routing(faces, case, hybrid, settings, first_start, args.factors, schedule.bench_seed,
                                 None if box is None else as_dict(box), say=lambda m: logging.info("%s", m), done=write)
        print(markdown(table))

    run_stage(cfg, run, threads="threads")


if __name__ == "__main__":
    main()
