"""Stage ``benchmark``: every solver and every trained network on the same holes, in one run.

    python -m pipeline.benchmark                        # test group 1, first 100 holes
    python -m pipeline.benchmark benchmark.holes=1000 'benchmark.methods=[cuikm,nm,cuikm_nm]'

Writes ``paths.data/benchmark/results.{csv,json,md}`` and ``figures/error_vs_time.png`` and logs
them to MLflow (run ``benchmark``). Times are wall clock on this machine with
``benchmark.threads`` torch threads; networks run on the CPU like the rest, for a fair race.
"""

from __future__ import annotations

import logging
import platform
import statistics
import time
from pathlib import Path

import hydra
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pandas as pd  # noqa: E402
import torch  # noqa: E402
from omegaconf import DictConfig, OmegaConf  # noqa: E402

from pipeline.core.build import build_safety  # noqa: E402
from pipeline.core.config import project_path  # noqa: E402
from pipeline.core.errors import ConfigError, InputError  # noqa: E402
from pipeline.core.io import atomic_write, write_json, write_text  # noqa: E402
from pipeline.data.tables import read_poses  # noqa: E402
from pipeline.evaluation.metrics import solution_table, summarize  # noqa: E402
from pipeline.solvers import HoleTargets, Solver, build_solver  # noqa: E402
from pipeline.tracking import runs as tracking  # noqa: E402

log = logging.getLogger(__name__)

COLUMNS = ["method", "holes", "hole_mm_mean", "hole_mm_p95", "hole_mm_max", "solved_1mm_share",
           "collision_rate_paper", "any_violation_share", "batch_ms_per_hole", "single_ms_per_hole",
           "iterations_mean", "setup_s"]


def load_holes(holes_dir: Path, group: int, n: int) -> HoleTargets:
    path = holes_dir / f"test_group_{group}.parquet"
    if not path.exists():
        raise InputError(f"{path} is missing: run `python -m pipeline.generate` (or `dvc repro`) first")
    _, pose = read_poses(path)
    if not 1 <= n <= len(pose):
        raise ConfigError(f"benchmark.holes = {n}: test group {group} has {len(pose)} holes")
    return pose[:n].double()


def measure(solver: Solver, pose: torch.Tensor, depth: float, safety, single: int) -> tuple[dict, torch.Tensor]:
    """A batched solve of every hole (repeated up to 1 s for fast solvers, median time), then
    ``single`` holes one at a time (median latency)."""
    targets = HoleTargets(pose, depth)
    solver.solve(targets.subset([0]))  # warm-up: lazy setup (RBF fit, first kernels) is not timed
    result = solver.solve(targets)
    batch_s = [result.wall_s]
    while sum(batch_s) < 1.0 and len(batch_s) < 20:  # fast solvers: median of repeats, not one noisy sample
        batch_s.append(solver.solve(targets).wall_s)
    latencies = [solver.solve(targets.subset([i])).wall_s for i in range(min(single, len(targets)))]
    row = summarize(solution_table(pose, result.q, safety))
    return {
        "holes": len(targets),
        "hole_mm_mean": row["hole_mm_mean"], "hole_mm_p95": row["hole_mm_p95"], "hole_mm_max": row["hole_mm_max"],
        "solved_1mm_share": row["solved_1mm_share"], "collision_rate_paper": row["collision_rate_paper"],
        "any_violation_share": row["any_violation_share"],
        "batch_ms_per_hole": 1000 * statistics.median(batch_s) / len(targets),
        "single_ms_per_hole": 1000 * statistics.median(latencies) if latencies else float("nan"),
        "iterations_mean": float(result.iterations.double().mean()),
    }, result.q


def markdown_table(df: pd.DataFrame, digits: int = 4) -> str:
    """A GitHub Markdown table; floats to ``digits`` significant figures."""
    cell = lambda v: f"{v:.{digits}g}" if isinstance(v, float) else str(v)  # noqa: E731
    head = "| " + " | ".join(map(str, df.columns)) + " |\n|" + "---|" * len(df.columns) + "\n"
    return head + "".join("| " + " | ".join(cell(v) for v in row) + " |\n" for row in df.itertuples(index=False))


def markdown(df: pd.DataFrame) -> str:
    fmt = df.copy()
    for col in ["hole_mm_mean", "hole_mm_p95", "hole_mm_max"]:
        fmt[col] = fmt[col].map(lambda v: f"{v:.3g}" if v < 100 else f"{v:.0f}")
    for col in ["solved_1mm_share", "collision_rate_paper", "any_violation_share"]:
        fmt[col] = (100 * fmt[col]).map(lambda v: f"{v:.1f} %")
    for col in ["batch_ms_per_hole", "single_ms_per_hole"]:
        fmt[col] = fmt[col].map(lambda v: f"{v:.3g}")
    fmt["iterations_mean"] = fmt["iterations_mean"].map(lambda v: f"{v:.0f}")
    fmt["setup_s"] = fmt["setup_s"].map(lambda v: f"{v:.1f}")
    return markdown_table(fmt)


def error_vs_time(df: pd.DataFrame):
    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    ax.scatter(df["batch_ms_per_hole"], df["hole_mm_mean"], c=100 * df["collision_rate_paper"], cmap="viridis_r",
               s=60, edgecolor="k")
    for r in df.itertuples():
        ax.annotate(r.method, (r.batch_ms_per_hole, r.hole_mm_mean), textcoords="offset points", xytext=(4, 4),
                    fontsize=8)
    ax.set(xscale="log", yscale="log", xlabel="time per hole, batched (ms)", ylabel="mean hole-seeking error (mm)",
           title="IK methods on the same holes (colour: collision rate %)")
    fig.colorbar(ax.collections[0], ax=ax, label="collision rate (%)")
    fig.tight_layout()
    return fig


def run(cfg: DictConfig) -> pd.DataFrame:
    bcfg = cfg.benchmark
    torch.set_num_threads(int(bcfg.threads))
    data = project_path(cfg.paths.data)
    out = data / "benchmark"
    safety = build_safety(cfg.boom, cfg.tunnel, cfg.safety)
    boom = safety.boom
    specs = OmegaConf.to_container(bcfg.solvers, resolve=True)
    unknown = [m for m in bcfg.methods if m not in specs]
    if unknown:
        raise ConfigError(f"benchmark.methods: {unknown} have no entry under benchmark.solvers ({sorted(specs)})")
    pose = load_holes(data / "holes", int(bcfg.group), int(bcfg.holes))
    solvers = {}
    for m in bcfg.methods:  # build (and load) everything before the first solve: fail early
        start = time.perf_counter()
        solvers[m] = (build_solver(m, specs[m], boom, data / "models", specs), time.perf_counter() - start)
    rows = []
    for m, (solver, setup_s) in solvers.items():
        if hasattr(solver, "fit"):
            start = time.perf_counter()
            solver.fit()
            setup_s += time.perf_counter() - start
        row, _ = measure(solver, pose, boom.preview_depth, safety, int(bcfg.single))
        rows.append({"method": m, **row, "setup_s": setup_s})
        log.info("%-10s mean %.4g mm, p95 %.4g mm, solved<=1mm %.1f %%, collisions %.1f %%, %.4g ms/hole batched",
                 m, row["hole_mm_mean"], row["hole_mm_p95"], 100 * row["solved_1mm_share"],
                 100 * row["collision_rate_paper"], row["batch_ms_per_hole"])
    df = pd.DataFrame(rows, columns=COLUMNS)
    machine = {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
               "torch": torch.__version__, "threads": torch.get_num_threads(), "group": int(bcfg.group),
               "holes": int(bcfg.holes)}
    atomic_write(out / "results.csv", lambda tmp: df.to_csv(tmp, index=False))
    # keyed by method so `dvc metrics show` / `dvc exp show` list one column per method and figure
    write_json({"machine": machine, **{r["method"]: {k: v for k, v in r.items() if k != "method"} for r in rows}},
               out / "results.json")
    write_text(f"Test group {machine['group']}, first {machine['holes']} holes; {machine['processor']}, "
               f"{machine['threads']} torch threads, torch {machine['torch']}.\n\n" + markdown(df),
               out / "results.md")
    fig = error_vs_time(df)
    atomic_write(out / "figures" / "error_vs_time.png", lambda tmp: fig.savefig(tmp, dpi=120, format="png"))
    if cfg.tracking.enabled:
        import mlflow

        tracking.setup(cfg.tracking.uri, cfg.tracking.experiment, cfg.tracking.artifact_root)
        with tracking.start(run_name="benchmark", tags={"stage": "benchmark"}):
            tracking.log_params(tracking.flatten({"benchmark": OmegaConf.to_container(bcfg, resolve=True),
                                                  "machine": machine}))
            for r in rows:
                tracking.log_metrics({k: v for k, v in r.items() if k != "method"}, prefix=f"{r['method']}.")
            mlflow.log_table(df, "tables/benchmark.json")
            mlflow.log_figure(fig, "figures/error_vs_time.png")
            tracking.log_artifact(out / "results.csv")
    plt.close(fig)
    return df


@hydra.main(version_base="1.3", config_path="../conf", config_name="config")
def main(cfg: DictConfig) -> None:
    run(cfg)


if __name__ == "__main__":
    main()
