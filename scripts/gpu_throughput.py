"""Benchmark (docs/benchmarks.md, "The hybrid on a GPU"): the hybrid solver on one
device at 10^4, 10^5 and 10^6 holes, and beside it, in the same run, the torch and compiled hybrids on
that machine's CPU.

    python scripts/gpu_throughput.py [--sizes 10000 100000 1000000] [--device auto|cpu|cuda]
        [--model data/models/cuikm.pt | none] [--cpu-baseline 10000] [--out data/benchmark/device]
        [hydra overrides ...]

The holes are drawn like the study's test groups (``holes.*``), the solver is ``solve``'s hybrid with the
``solver`` group's settings, its random starts in the working box (``holes.sup.box``), its first start the
network at ``--model`` (the study's CUIKM by default; ``none``: the mid-range joints). Every answer is
judged again from its joints (pipeline/evaluation/device_throughput.py). Writes ``throughput.json`` and
``throughput.md`` under ``--out`` and prints the table. Needs torch, numpy, pandas, PyYAML, omegaconf,
hydra-core and, for ``--cpu-baseline``, numba; not MLflow. Back on the project's machine,

    python scripts/gpu_throughput.py --log <throughput.json> [hydra overrides ...]

logs a table as one MLflow run (``device-throughput``, the composed experiment).

On a GPU machine without network access, with the project's pure-Python settings packages copied over as
wheels (docs/benchmarks.md says how), the same command runs there: its ``python3`` has its own CUDA torch.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import torch

from pipeline.assembly.build import build_safety, hole_sampling
from pipeline.core.config import as_dict, compose, project_path
from pipeline.core.errors import InputError
from pipeline.core.io import write_json, write_text
from pipeline.core.settings import parse
from pipeline.data.holes import joint_box, sample_holes
from pipeline.evaluation.device_throughput import markdown_table, measure_size
from pipeline.learning.network_source import load_network
from pipeline.solvers.base import HoleTargets, NetworkSolver
from pipeline.solvers.hybrid import HybridSettings, HybridSolver


def _args(argv: list[str]) -> tuple[argparse.Namespace, list[str]]:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000, 1_000_000])
    p.add_argument("--device", default="auto", help="auto (CUDA when there), cpu, cuda or cuda:N")
    p.add_argument("--model", default="data/models/cuikm.pt", help="the first start's network, or none")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--chunk", type=int, default=1_000_000, help="holes per solve call (bounds the peak memory)")
    p.add_argument("--seed", type=int, default=20_000, help="the holes of size i are drawn with seed + i")
    p.add_argument("--cpu-baseline", type=int, default=0, metavar="N",
                   help="also solve N holes on this machine's CPU with the torch and the compiled hybrid")
    p.add_argument("--stages", type=int, default=0, metavar="N",
                   help="also time each stage of one solve of N holes (the device synchronised around each)")
    p.add_argument("--out", default="data/benchmark/device")
    args, overrides = p.parse_known_args(argv)
    bad = [o for o in overrides if "=" not in o or o.startswith("-")]
    if bad:
        p.error(f"not an option or a hydra override (key=value): {bad}")
    if min(args.sizes + [args.repeats, args.chunk]) < 1 or args.cpu_baseline < 0:
        p.error("--sizes, --repeats and --chunk must be positive, --cpu-baseline non-negative")
    return args, overrides


def _device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    device = torch.device(name)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise InputError(f"--device {name}: this torch ({torch.__version__}) sees no CUDA device")
    return device


def main(argv: list[str]) -> dict:
    args, overrides = _args(argv)
    cfg = compose(overrides)
    device = _device(args.device)
    safety = build_safety(cfg.boom, cfg.tunnel, cfg.safety)
    settings = parse(HybridSettings, cfg.solver, "solver")
    box = cfg.holes.sup.get("box")
    start_box = joint_box(safety.boom, None if box is None else as_dict(box))
    network = None
    if args.model.lower() != "none":
        model = load_network(project_path(args.model), safety.boom)[0]
        network = NetworkSolver(safety.boom, model.to(device), "cuikm")
    solver = HybridSolver(safety.boom, safety, network, settings, "hybrid", start_box)
    sampling = hole_sampling(cfg.holes)
    rows = []
    for i, n in enumerate(args.sizes):
        row = measure_size(solver, safety, sampling, n, args.seed + i, device, args.repeats, args.chunk)
        rows.append(row.as_dict())
        print(markdown_table(rows[-1:]).splitlines()[-1], flush=True)
    stages = stage_times(solver, safety, sampling, args.stages, args.seed, device) if args.stages else []
    if args.cpu_baseline:
        from pipeline.solvers.compiled import CompiledHybridSolver

        cpu = torch.device("cpu")
        cpu_net = None if network is None else NetworkSolver(safety.boom, network.model.cpu(), "cuikm")
        for s in (HybridSolver(safety.boom, safety, cpu_net, settings, "hybrid", start_box),
                  CompiledHybridSolver(safety.boom, safety, cpu_net, settings, "hybrid_compiled", start_box)):
            row = measure_size(s, safety, sampling, args.cpu_baseline, args.seed, cpu, args.repeats, args.chunk)
            rows.append(row.as_dict())
            print(markdown_table(rows[-1:]).splitlines()[-1], flush=True)
    machine = {"torch": torch.__version__, "python": platform.python_version(), "threads": torch.get_num_threads(),
               "gpu": torch.cuda.get_device_name(device) if device.type == "cuda" else None,
               "model": args.model, "overrides": overrides, "date": time.strftime("%Y-%m-%d")}
    result = {"machine": machine, "rows": rows, "stages": stages}
    out = project_path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_json(result, out / "throughput.json")
    write_text(markdown_table(rows), out / "throughput.md")
    print(markdown_table(rows))
    return result


def stage_times(solver: HybridSolver, safety, sampling, n: int, seed: int, device: torch.device) -> list[dict]:
    """Where one solve of ``n`` holes spends its time: the network, then each call of ``refine`` (the
    pose-only LM, then the cascade's stages), the device synchronised around each. Measured by wrapping
    the solver's own methods for one solve; the solve is first run untimed."""
    pose, _ = sample_holes(n, safety, sampling, seed)
    targets = HoleTargets(pose.to(device), safety.boom.preview_depth)
    solver.solve(targets)
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    log = []

    def timed(stage: str, rows: int, fn, *a, **kw):
        sync()
        t0 = time.perf_counter()
        out = fn(*a, **kw)
        sync()
        log.append({"stage": stage, "rows": rows, "seconds": time.perf_counter() - t0})
        return out

    refine, network = solver.refine, solver.init

    def timed_refine(q0, target, use_safety, max_iters=None, owner=None, others=()):
        stage = f"refine, safety rows {'on' if use_safety else 'off'}, {max_iters or solver.s.max_iters} iterations"
        return timed(stage, len(q0), refine, q0, target, use_safety, max_iters, owner, others)

    solver.refine = timed_refine
    if network is not None:
        network.joints = lambda t: timed("network", len(t), type(network).joints, network, t)
    try:
        sync()
        t0 = time.perf_counter()
        solver.solve(targets)
        sync()
        total = time.perf_counter() - t0
    finally:
        del solver.refine  # the class's own methods again
        if solver.init is not None:
            del solver.init.joints
    log.append({"stage": "whole solve", "rows": n, "seconds": total})
    for row in log:
        print(f"{row['stage']:<45} {row['rows']:>10,} rows {row['seconds']:8.3f} s", flush=True)
    return log


def log_to_mlflow(result: dict, overrides: list[str]) -> None:
    """One MLflow run (``device-throughput``) with the machine as params, the rows as a table and each
    row's speed and checks as metrics: here, from the JSON a GPU machine wrote."""
    import pandas as pd

    from pipeline.tracking.runs import TrackingSettings, stage_run

    cfg = compose(overrides)
    with stage_run(TrackingSettings.from_config(cfg.tracking), "device-throughput",
                   {"stage": "script", "mode": "benchmark"}) as run:
        run.log_params(result["machine"])
        rows = result["rows"]
        run.log_table(pd.DataFrame([{**r, "statuses": json.dumps(r["statuses"])} for r in rows]), "throughput.json")
        for r in rows:
            key = f"{r['device'].replace(':', '_')}.{r['solver']}.{r['holes']}"
            run.log_metrics({f"{key}.{k}": float(r[k]) for k in ("holes_per_s", "ok_share", "ok_but_bad",
                                                                 "hole_mm_max_ok", "peak_gib") if r[k] is not None})


def read_result(path: str) -> dict:
    """A ``throughput.json`` this script wrote (on any machine), checked for its rows."""
    try:
        result = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise InputError(f"--log {path}: cannot read it as JSON ({exc})") from None
    if not isinstance(result, dict) or not isinstance(result.get("rows"), list) or "machine" not in result:
        raise InputError(f"--log {path}: not a throughput.json of this script (no machine and rows)")
    return result


if __name__ == "__main__":
    try:
        argv = sys.argv[1:]
        if argv[:1] == ["--log"]:  # python scripts/gpu_throughput.py --log <throughput.json> [overrides]
            if len(argv) < 2:
                raise InputError("--log needs the throughput.json to log")
            log_to_mlflow(read_result(argv[1]), argv[2:])
        else:
            main(argv)
    except InputError as exc:
        sys.exit(f"error: {exc}")
