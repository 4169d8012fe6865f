"""Benchmark (docs/benchmarks.md, "Training speed"): one training step of a method, side by side in one run, in
float32 and with the hidden layers in bfloat16 (``train.precision``), each with Adam's loop over tensors and with
its fused kernel.

    python scripts/train_step_benchmark.py [--steps 300] [--rounds 3] [--out data/benchmark/train_step] [overrides]

Each variant trains the configured method (``method=cuikm`` by default: fresh holes, the pose and safety terms)
with :func:`pipeline.learning.training.fit` for ``--steps`` steps after 20 untimed ones, in ``--rounds`` rounds
that take the variants in turn (so a slow spell of a shared machine falls on all of them); the figure is the median
round's milliseconds a step (the round's two held-out evaluations included: a few ms in all). Writes ``train_step.json``
and ``train_step.md`` under ``--out``, logs them as one MLflow run (``train-step-benchmark``) and prints the table.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time

import pandas as pd
import torch

from pipeline.assembly.build import build_safety, hole_sampling
from pipeline.core.config import compose, project_path
from pipeline.core.io import write_json, write_text
from pipeline.data.holes import sample_holes
from pipeline.evaluation.markdown import markdown_rows
from pipeline.geometry.collision import SafetyDistances
from pipeline.learning.models import ModelSettings, build_model
from pipeline.learning.training import MethodSettings, TrainSettings, fit, fresh_hole_batches, training_dtype
from pipeline.tracking.runs import TrackingSettings, stage_run

VARIANTS = {  # name: (train.precision, fused Adam)
    "float32, Adam loop": ("float32", False),
    "float32, fused Adam": ("float32", True),
    "bfloat16 hidden, Adam loop": ("bfloat16", False),
    "bfloat16 hidden, fused Adam": ("bfloat16", True),
}


def main(argv: list[str]) -> list[dict]:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--out", default="data/benchmark/train_step")
    args, overrides = p.parse_known_args(argv)
    if args.steps < 2 or args.rounds < 1:
        p.error("--steps must be at least 2 and --rounds at least 1")
    cfg = compose(["method=cuikm", *overrides])
    settings, model_s = TrainSettings.from_config(cfg.train), ModelSettings.from_config(cfg.model)
    method = MethodSettings.from_config(cfg.method)
    safety, sampling = build_safety(cfg.boom, cfg.tunnel, cfg.safety), hole_sampling(cfg.holes)
    train_safety = safety.with_distances(SafetyDistances.from_config(method.train_safety))
    val, _ = sample_holes(settings.val_size, safety, sampling, settings.val_seed)
    threads = torch.get_num_threads()

    if method.supervised or not settings.fresh_holes:
        p.error("the benchmark times an unsupervised method on fresh holes (method=cuikm or uikm)")

    def one_round(precision: str, fused: bool) -> float:
        torch.manual_seed(settings.seed)
        model = build_model(safety.boom, val.mean(0), val.std(0), model_s.width, model_s.depth, model_s.activation)
        batches = fresh_hole_batches(safety, sampling, settings.batch_size, settings.seed, "cpu")

        def steps(n: int) -> None:  # held out: two evaluations (steps 0 and n - 1), a few ms of the round
            fit(model, safety.boom, train_safety, method.objective, batches, n, settings.lr, val.float(),
                eval_every=n, progress=False, hidden_dtype=training_dtype(precision, "cpu"), fused_adam=fused)

        steps(20)
        t0 = time.perf_counter()
        steps(args.steps)
        return 1000 * (time.perf_counter() - t0) / args.steps

    times = {name: [] for name in VARIANTS}
    for _ in range(args.rounds):
        for name, (precision, fused) in VARIANTS.items():
            times[name].append(one_round(precision, fused))
            print(f"{name:<30} {times[name][-1]:7.2f} ms a step", flush=True)
    base = statistics.median(times["float32, Adam loop"])
    rows = [{"variant": name, "ms_per_step": statistics.median(t), "speedup": base / statistics.median(t),
             "rounds_ms": [round(x, 2) for x in t]} for name, t in times.items()]
    machine = {"torch": torch.__version__, "python": platform.python_version(), "threads": threads,
               "cpu_bf16": bool(torch.cpu._is_avx512_bf16_supported()), "method": method.name,
               "batch_size": settings.batch_size, "width": model_s.width, "depth": model_s.depth,
               "steps": args.steps, "rounds": args.rounds, "overrides": overrides}
    table = markdown_rows(["variant", "ms a step", "speed-up"],
                          [[r["variant"], f"{r['ms_per_step']:.1f}", f"{r['speedup']:.2f}x"] for r in rows])
    out = project_path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_json({"machine": machine, "rows": rows}, out / "train_step.json")
    write_text(table, out / "train_step.md")
    with stage_run(TrackingSettings.from_config(cfg.tracking), "train-step-benchmark",
                   {"stage": "script", "mode": "benchmark"}) as mlrun:
        mlrun.log_params(machine)
        mlrun.log_table(pd.DataFrame([{**r, "rounds_ms": json.dumps(r["rounds_ms"])} for r in rows]),
                        "train_step.json")
        for i, r in enumerate(rows):
            mlrun.log_metrics({"ms_per_step": r["ms_per_step"], "speedup": r["speedup"]}, prefix=f"variant{i}.")
    print(table)
    return rows


if __name__ == "__main__":
    main(sys.argv[1:])
