"""Latency harness of the deployable network: torch eager, torch.export, torch.compile, TorchScript, ONNX Runtime.

It needs no trained model: latency depends on the network's shape, not on its weights. A network of
the ``model`` config with random weights goes through the export's own writers
(:mod:`pipeline.deploy.formats`) into a temporary folder. Each runtime then runs in its own process,
as on a rig, on the same holes, ``export.benchmark.batches`` at a time (one hole, 1 000 holes), with
``export.benchmark.threads`` torch threads. A time is the median of calls repeated for at least ``min_time_s`` and
``min_repeats`` times, the runtimes taking turns (``rounds``; see ``measure``).

Stage: ``python -m pipeline.export_benchmark`` (writes ``latency.{csv,md}`` beside the exports).
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import os
import platform
import statistics
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from pathlib import Path

import pandas as pd
import torch

from pipeline.assembly.build import load_boom
from pipeline.core.config import as_dict
from pipeline.deploy import formats
from pipeline.deploy.package import LatencySettings, check_poses, versions
from pipeline.evaluation.markdown import markdown_rows
from pipeline.learning.models import IKNet, build_model, load_checkpoint, save_checkpoint

log = logging.getLogger(__name__)

COLUMNS = ["runtime", "holes", "median_ms", "us_per_hole", "repeats", "setup_s", "note"]


def random_network(cfg, pose: torch.Tensor, seed: int) -> IKNet:
    """A network of the ``model`` config for ``cfg.boom``, random weights, normalised like ``pose``."""
    torch.manual_seed(seed)
    model = build_model(load_boom(cfg.boom), pose.mean(0), pose.std(0), int(cfg.model.width), int(cfg.model.depth),
                        str(cfg.model.activation))
    return model.eval().requires_grad_(False)


# --- files and runtimes ---------------------------------------------------------------------------------------

def write_files(model: IKNet, boom_cfg: dict, example: torch.Tensor, folder: Path, opset: int) -> dict[str, Path]:
    """The checkpoint (for eager and compiled torch) and every export the stage would write."""
    files = {"checkpoint": folder / "bench.pt", **{fmt: folder / f"bench{ext}" for fmt, ext in formats.FORMATS.items()}}
    save_checkpoint(files["checkpoint"], model, boom_cfg, {})
    program = formats.export_program(model, example)
    formats.save_program(program, files["torch_export"], "{}")
    formats.save_torchscript(model, example, files["torchscript"], "{}")
    if formats.missing_onnx_packages():
        del files["onnx"]
    else:
        formats.save_onnx(program, example, files["onnx"], opset, {})
    return files


def runtimes(bcfg: LatencySettings, files: dict[str, Path]) -> dict[str, tuple[str, Path, int | None] | str]:
    """Runtime name -> (kind, file, ONNX Runtime threads), or a note saying why it is not timed."""
    out: dict = {"torch eager": ("eager", files["checkpoint"], None),
                 "torch.export (.pt2)": ("torch_export", files["torch_export"], None),
                 "torch.compile": ("compile", files["checkpoint"], None) if bcfg.compile
                 else "skipped (export.benchmark.compile=false)",
                 "TorchScript (.ts)": ("torchscript", files["torchscript"], None)}
    for n in bcfg.ort_threads:
        out[f"ONNX Runtime, {n} thread{'s' * (n != 1)}"] = ("onnx", files["onnx"], int(n)) if "onnx" in files else (
            f"skipped: {', '.join(formats.missing_onnx_packages())} not installed ({formats.ONNX_HINT})")
    return out


# --- in a worker: one runtime ----------------------------------------------------------------------------------

_workers: dict[str, tuple[formats.Runner, list[torch.Tensor]]] = {}  # by runtime name: one in a worker process


def worker_setup(name: str, kind: str, path: str, threads: int, ort_threads: int | None,
                 poses: list[torch.Tensor]) -> float:
    """Make the runner of ``kind`` from ``path`` and keep it with ``poses``; returns the seconds it took. For
    torch.compile that includes compiling, which happens on the first calls (every batch size, dynamic=True)."""
    torch.set_num_threads(threads)
    t0 = time.perf_counter()
    if kind in ("eager", "compile"):
        run = load_checkpoint(path)[0].requires_grad_(False)
        if kind == "compile":
            run = torch.compile(run, dynamic=True)
            with torch.inference_mode():
                for pose in poses:
                    run(pose)
    else:
        run = formats.load_runner(kind, Path(path), ort_threads)
    _workers[name] = (run, poses)
    return time.perf_counter() - t0


def block_times(run: formats.Runner, pose: torch.Tensor, min_time_s: float, min_repeats: int) -> list[float]:
    """Wall times (s) of consecutive calls ``run(pose)``, for at least ``min_time_s`` and ``min_repeats`` calls,
    after two untimed ones (lazy allocations, TorchScript's profiling runs, thread pools waking up)."""
    with torch.inference_mode():
        run(pose)
        run(pose)
        times, start = [], time.perf_counter()
        while len(times) < min_repeats or time.perf_counter() - start < min_time_s:
            t0 = time.perf_counter()
            run(pose)
            times.append(time.perf_counter() - t0)
    return times


def worker_block(name: str, i: int, min_time_s: float, min_repeats: int) -> list[float]:
    run, poses = _workers[name]
    return block_times(run, poses[i], min_time_s, min_repeats)


# --- the parent: turns and the table ---------------------------------------------------------------------------

def measure(cfg, bcfg: LatencySettings, opset: int) -> tuple[pd.DataFrame, IKNet]:
    """The latency table: one row per runtime and batch size, for the ``model`` and ``boom`` of ``cfg``.

    Each runtime runs in its own process, as on a rig (``isolate``), so no runtime's thread pools, allocator
    or compiled kernels are there while another is timed. ``isolate=false`` runs them all here, which starts
    in a fraction of the time (tests, quick runs). The runtimes take turns, ``rounds`` blocks of calls each,
    so a load that comes and goes on a shared machine slows each of them alike."""
    pose = check_poses(as_dict(cfg.boom), cfg.tunnel, cfg.safety, cfg.holes, max(bcfg.batches), int(bcfg.seed) + 1)
    model = random_network(cfg, pose, int(bcfg.seed))
    poses = [pose[:n].clone() for n in sorted(bcfg.batches)]
    rounds, block_s = int(bcfg.rounds), float(bcfg.min_time_s) / int(bcfg.rounds)
    block_n = -(-int(bcfg.min_repeats) // rounds)
    with tempfile.TemporaryDirectory(prefix="boom-ik-latency-") as tmp, contextlib.ExitStack() as stack:
        plan = runtimes(bcfg, write_files(model, as_dict(cfg.boom), pose[:16], Path(tmp), opset))
        ctx = multiprocessing.get_context("spawn")  # a fork would inherit this process's torch thread pools
        new_worker = (lambda: ProcessPoolExecutor(1, mp_context=ctx)) if bcfg.isolate else (
            lambda: ThreadPoolExecutor(1))
        workers = {name: stack.enter_context(new_worker()) for name, how in plan.items() if not isinstance(how, str)}
        for started in [w.submit(os.getpid) for w in workers.values()]:  # processes start (import) side by side
            started.result()
        setup = {}
        for name, worker in workers.items():
            how = plan[name]
            try:  # one after another: a compile must not slow another runtime's setup
                setup[name] = worker.submit(worker_setup, name, how[0], str(how[1]), int(bcfg.threads), how[2],
                                            poses).result()
            except Exception as exc:  # torch.compile without a C++ compiler, ...: say why, time the others
                plan[name] = f"failed: {type(exc).__name__}: {str(exc).strip().splitlines()[0][:200]}"
        times = {(name, i): [] for name in setup for i in range(len(poses))}
        for i in range(len(poses)):
            for _ in range(rounds):
                for name in setup:
                    times[name, i] += workers[name].submit(worker_block, name, i, block_s, block_n).result()
    _workers.clear()  # isolate=false kept the runners in this process
    rows = []
    for i, x in enumerate(poses):
        for name, how in plan.items():
            if isinstance(how, str):
                rows.append({"runtime": name, "holes": len(x), "note": how})
                continue
            ms = 1000 * statistics.median(times[name, i])
            rows.append({"runtime": name, "holes": len(x), "median_ms": ms, "us_per_hole": 1000 * ms / len(x),
                         "repeats": len(times[name, i]), "setup_s": setup[name], "note": ""})
    return pd.DataFrame(rows, columns=COLUMNS), model


def machine(load_before: float, threads: int) -> dict[str, str | int]:
    cpu = platform.processor() or platform.machine()
    cpuinfo = Path("/proc/cpuinfo")  # Linux names the CPU model here; platform.processor() often does not
    if cpuinfo.is_file():
        names = [ln.split(":", 1)[1].strip() for ln in cpuinfo.read_text().splitlines() if ln.startswith("model name")]
        cpu = names[0] if names else cpu
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    # the machine may be shared: its load around the run says how far the times can be trusted
    load = f"{load_before:.1f} before, {os.getloadavg()[0]:.1f} after" if hasattr(os, "getloadavg") else "unknown"
    return {"cpu": cpu, "cores": cores, "torch_threads": threads, "load": load, "torch": torch.__version__,
            **{k: v for k, v in versions(not formats.missing_onnx_packages()).items() if k != "python"}}


def latency_markdown(table: pd.DataFrame, model: IKNet, about: dict) -> str:
    h = model.hparams
    rest = ", ".join(f"{k} {about[k]}" for k in about if k not in ("cpu", "cores", "torch_threads", "load"))
    rows = [[r.runtime, r.holes, r.note, "", ""] if pd.isna(r.median_ms) else
            [r.runtime, r.holes, f"{r.median_ms:.3f}", f"{r.us_per_hole:.2f}", f"{r.setup_s:.2f}"]
            for r in table.itertuples()]
    return (f"Network {h['depth']} x {h['width']} {h['activation'].upper()} (random weights), float32. "
            f"{about['cpu']}, {about['cores']} cores, {about['torch_threads']} torch thread(s), load average (1 min) "
            f"{about['load']}; {rest}.\n\n"
            + markdown_rows(["runtime", "holes per call", "median (ms)", "µs per hole", "setup (s)"], rows))
