"""Stage ``evaluate``: solve the test groups with every trained network; tables, figures, MLflow.

    python -m pipeline.evaluate                    # methods of eval.methods
    python -m pipeline.evaluate eval.methods=[cuikm]

Writes under ``paths.data/eval/``: ``predictions/<method>_group<k>.parquet`` (the network the other stages
use), ``predictions/<method>_seed<s>_group<k>.parquet`` (each seed's, when trained with ``train.seeds``),
``metrics.json`` (each method's metrics, with the mean and std over its seeds), ``seeds.csv`` (one row per
method and seed), ``collisions.csv`` (paper 000 Table 3 layout) and ``figures/``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd
from omegaconf import DictConfig

from pipeline.assembly.build import build_safety
from pipeline.core.config import project_path
from pipeline.core.io import save_figure, write_csv, write_json, write_parquet
from pipeline.core.settings import parse, rule
from pipeline.core.stage import run_stage, stage_main
from pipeline.data.hole_sets import read_test_groups
from pipeline.evaluation.metrics import MethodEvaluation, collision_table, evaluate_network, summary_frame
from pipeline.evaluation.plots import face_projection, method_comparison, training_curves
from pipeline.evaluation.seeds import seed_checkpoints, seed_spread, seed_table
from pipeline.learning.network_source import load_network
from pipeline.tracking.runs import TrackingSettings, stage_run

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class EvalSettings:
    methods: list[str] = field(metadata=rule())  # networks under paths.data/models/<method>.pt
    timing_repeats: int = field(default=5, metadata=rule(ge=1, le=1000))  # each a solve of every test hole


def run(cfg: DictConfig) -> dict:
    settings, tracking = parse(EvalSettings, cfg.eval, "eval"), TrackingSettings.from_config(cfg.tracking)
    safety = build_safety(cfg.boom, cfg.tunnel, cfg.safety)
    data = project_path(cfg.paths.data)
    groups = read_test_groups(data / "holes")
    # every network loaded and checked before anything is written
    networks = {m: load_network(data / "models" / f"{m}.pt", safety.boom) for m in settings.methods}
    seeds = {m: {seed: load_network(path, safety.boom) for seed, path in seed_checkpoints(data / "models", m).items()}
             for m in settings.methods}
    with stage_run(tracking, "evaluate", {"stage": "evaluate"}) as mlrun:
        mlrun.log_params({"eval": vars(settings), "safety": dict(cfg.safety)})
        for k, (df, _) in groups.items():
            mlrun.log_dataset(df, data / "holes" / f"test_group_{k}.parquet", "evaluation")
        results = {m: evaluate_network(model, meta, safety, groups, settings.timing_repeats)
                   for m, (model, meta) in networks.items()}
        by_seed = {m: {seed: evaluate_network(model, meta, safety, groups, 0) for seed, (model, meta) in nets.items()}
                   for m, nets in seeds.items() if nets}
        table = seed_table({m: {s: r.metrics for s, r in rs.items()} for m, rs in by_seed.items()},
                           {m: networks[m][1].get("seed") for m in by_seed})
        for m, spread in seed_spread(table).items():
            results[m].metrics.update(spread)
        figures = write_results(results, groups, safety, data / "eval", by_seed, table)
        metrics = {m: r.metrics for m, r in results.items()}
        mlrun.log_table(table, "tables/seeds.json")
        for m, values in metrics.items():
            mlrun.log_metrics(values, prefix=f"{m}.")
        mlrun.log_table(collision_table({(k, m): r.tables[k] for m, r in results.items() for k in r.tables}),
                        "tables/collisions.json")
        mlrun.log_table(summary_frame(metrics), "tables/metrics.json")
        for name, fig in figures.items():
            mlrun.log_figure(fig, f"figures/{name}")
        mlrun.log_artifact(data / "eval" / "metrics.json")
    for m, s in metrics.items():
        spread = (f"; over {s['seeds']} seeds {s['mean_mm_seed_mean']:.2f} +- {s['mean_mm_seed_std']:.2f} mm, "
                  f"{s['collision_rate_pct_seed_mean']:.2f} +- {s['collision_rate_pct_seed_std']:.2f} %"
                  if "seeds" in s else "")
        log.info("%s: hole-seeking error mean %.2f mm (p95 %.2f), collision rate %.2f %%, %.2f ms / 1000 holes%s",
                 m, s["hole_mm_mean"], s["hole_mm_p95"], 100 * s["collision_rate_paper"], s["solve_ms_per_1000"],
                 spread)
    return metrics


def write_results(results: dict[str, MethodEvaluation], groups, safety, out: Path,
                  by_seed: dict[str, dict[int, MethodEvaluation]], seeds: pd.DataFrame) -> dict:
    """Predictions per method (and seed) and group, ``metrics.json``, ``seeds.csv``, ``collisions.csv`` and the
    figures; returns the figures by file name (still open, for MLflow)."""
    for m, r in results.items():
        for k, pred in r.predictions.items():
            write_parquet(pred, out / "predictions" / f"{m}_group{k}.parquet")
    for m, rs in by_seed.items():
        for seed, r in rs.items():
            for k, pred in r.predictions.items():
                write_parquet(pred, out / "predictions" / f"{m}_seed{seed}_group{k}.parquet")
    write_csv(seeds, out / "seeds.csv")
    write_json({m: r.metrics for m, r in results.items()}, out / "metrics.json")
    write_csv(collision_table({(k, m): r.tables[k] for m, r in results.items() for k in r.tables}),
              out / "collisions.csv")
    all_pose = pd.concat([df for df, _ in groups.values()])
    figures = {
        "training_curves.png": training_curves({m: r.history for m, r in results.items() if len(r.history)}),
        "face_projection.png": face_projection(
            {m: (all_pose["collar_y"].to_numpy(), all_pose["collar_z"].to_numpy(), r.all_errors_mm())
             for m, r in results.items()}, safety.tunnel),
        "method_comparison.png": method_comparison({m: r.metrics for m, r in results.items()}),
    }
    for name, fig in figures.items():
        save_figure(fig, out / "figures" / name)
    return figures


@stage_main
def main(cfg: DictConfig) -> None:
    run_stage(cfg, run, threads=None)  # torch's default threads


if __name__ == "__main__":
    main()
