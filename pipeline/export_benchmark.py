"""Latency of the deployable network: torch eager, torch.export, torch.compile, TorchScript, ONNX Runtime.

    python -m pipeline.export_benchmark                        # the `model` config: 4 x 512 GELU
    python -m pipeline.export_benchmark export.benchmark.compile=false

It needs no trained model: latency depends on the network's shape, not on its weights. A network of
the ``model`` config with random weights goes through the export stage's own functions into a
temporary folder. Each runtime then runs in its own process, as on a rig, on the same holes,
``export.benchmark.batches`` at a time (one hole, 1 000 holes), with ``export.benchmark.threads``
torch threads. A time is the median of calls repeated for at least ``min_time_s`` and
``min_repeats`` times, the runtimes taking turns (``rounds``; see ``measure``).

Writes ``paths.data/export/latency.{csv,md}`` and logs both to MLflow (run ``export-latency``). DVC's
``export`` stage runs it after the export, so the latency files are outputs of that stage.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import os
import platform
import re
import statistics
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from pathlib import Path

import hydra
import pandas as pd
import torch
from omegaconf import DictConfig

from pipeline import export
from pipeline.assembly.build import load_boom
from pipeline.core.config import as_dict, project_path
from pipeline.core.errors import ConfigError
from pipeline.core.io import write_csv, write_text
from pipeline.learning.models import IKNet, build_model, load_checkpoint, save_checkpoint
from pipeline.tracking.runs import TrackingSettings, stage_run

log = logging.getLogger(__name__)

COLUMNS = ["runtime", "holes", "median_ms", "us_per_hole", "repeats", "setup_s", "note"]


def random_network(cfg: DictConfig, pose: torch.Tensor, seed: int) -> IKNet:
    """A network of the ``model`` config for ``cfg.boom``, random weights, normalised like ``pose``."""
    torch.manual_seed(seed)
    model = build_model(load_boom(cfg.boom), pose.mean(0), pose.std(0), int(cfg.model.width), int(cfg.model.depth),
                        str(cfg.model.activation))
    return model.eval().requires_grad_(False)


def check_settings(bcfg: DictConfig) -> None:
    for key in ("threads", "min_repeats", "rounds"):
        if isinstance(bcfg[key], bool) or not isinstance(bcfg[key], int) or bcfg[key] < 1:
            raise ConfigError(f"export.benchmark.{key} = {bcfg[key]!r}: expected a positive integer")
    for key in ("batches", "ort_threads"):
        values = list(bcfg[key])
        if not values or not all(isinstance(v, int) and not isinstance(v, bool) and v >= 1 for v in values):
            raise ConfigError(f"export.benchmark.{key} = {values!r}: expected a list of positive integers")
    for key in ("compile", "isolate"):
        if not isinstance(bcfg[key], bool):
            raise ConfigError(f"export.benchmark.{key} = {bcfg[key]!r}: expected true or false")
    if not float(bcfg.min_time_s) >= 0:
        raise ConfigError(f"export.benchmark.min_time_s = {bcfg.min_time_s!r}: expected seconds >= 0")


# --- files and runtimes ---------------------------------------------------------------------------------------

def write_files(model: IKNet, boom_cfg: dict, example: torch.Tensor, folder: Path, opset: int) -> dict[str, Path]:
    """The checkpoint (for eager and compiled torch) and every export the stage would write."""
    files = {"checkpoint": folder / "bench.pt", **{fmt: folder / f"bench{ext}" for fmt, ext in export.FORMATS.items()}}
    save_checkpoint(files["checkpoint"], model, boom_cfg, {})
    program = export.export_program(model, example)
    export.save_program(program, files["torch_export"], "{}")
    export.save_torchscript(model, example, files["torchscript"], "{}")
    if export.missing_onnx_packages():
        del files["onnx"]
    else:
        export.save_onnx(program, example, files["onnx"], opset, {})
    return files


def runtimes(bcfg: DictConfig, files: dict[str, Path]) -> dict[str, tuple[str, Path, int | None] | str]:
    """Runtime name -> (kind, file, ONNX Runtime threads), or a note saying why it is not timed."""
    out: dict = {"torch eager": ("eager", files["checkpoint"], None),
                 "torch.export (.pt2)": ("torch_export", files["torch_export"], None),
                 "torch.compile": ("compile", files["checkpoint"], None) if bcfg.compile
                 else "skipped (export.benchmark.compile=false)",
                 "TorchScript (.ts)": ("torchscript", files["torchscript"], None)}
    for n in bcfg.ort_threads:
        out[f"ONNX Runtime, {n} thread{'s' * (n != 1)}"] = ("onnx", files["onnx"], int(n)) if "onnx" in files else (
            f"skipped: {', '.join(export.missing_onnx_packages())} not installed ({export.ONNX_HINT})")
    return out


# --- in a worker: one runtime ----------------------------------------------------------------------------------

_workers: dict[str, tuple[export.Runner, list[torch.Tensor]]] = {}  # by runtime name: one in a worker process


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
        run = export.load_runner(kind, Path(path), ort_threads)
    _workers[name] = (run, poses)
    return time.perf_counter() - t0


def block_times(run: export.Runner, pose: torch.Tensor, min_time_s: float, min_repeats: int) -> list[float]:
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

def measure(cfg: DictConfig) -> tuple[pd.DataFrame, IKNet]:
    """The latency table: one row per runtime and batch size.

    Each runtime runs in its own process, as on a rig (``isolate``), so no runtime's thread pools, allocator
    or compiled kernels are there while another is timed. ``isolate=false`` runs them all here, which starts
    in a fraction of the time (tests, quick runs). The runtimes take turns, ``rounds`` blocks of calls each,
    so a load that comes and goes on a shared machine slows each of them alike."""
    bcfg = cfg.export.benchmark
    check_settings(bcfg)
    pose = export.check_poses(cfg, as_dict(cfg.boom), max(bcfg.batches), int(bcfg.seed) + 1)
    model = random_network(cfg, pose, int(bcfg.seed))
    poses = [pose[:n].clone() for n in sorted(bcfg.batches)]
    rounds, block_s = int(bcfg.rounds), float(bcfg.min_time_s) / int(bcfg.rounds)
    block_n = -(-int(bcfg.min_repeats) // rounds)
    with tempfile.TemporaryDirectory(prefix="boom-ik-latency-") as tmp, contextlib.ExitStack() as stack:
        plan = runtimes(bcfg, write_files(model, as_dict(cfg.boom), pose[:16], Path(tmp), int(cfg.export.opset)))
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
            **{k: v for k, v in export.versions(not export.missing_onnx_packages()).items() if k != "python"}}


def markdown(table: pd.DataFrame, model: IKNet, about: dict) -> str:
    h = model.hparams
    rest = ", ".join(f"{k} {about[k]}" for k in about if k not in ("cpu", "cores", "torch_threads", "load"))
    lines = [f"Network {h['depth']} x {h['width']} {h['activation'].upper()} (random weights), float32. "
             f"{about['cpu']}, {about['cores']} cores, {about['torch_threads']} torch thread(s), load average (1 min) "
             f"{about['load']}; {rest}.",
             "", "| runtime | holes per call | median (ms) | µs per hole | setup (s) |", "|---|---|---|---|---|"]
    for r in table.itertuples():
        if pd.isna(r.median_ms):
            lines.append(f"| {r.runtime} | {r.holes} | {r.note} | | |")
        else:
            lines.append(f"| {r.runtime} | {r.holes} | {r.median_ms:.3f} | {r.us_per_hole:.2f} | {r.setup_s:.2f} |")
    return "\n".join(lines) + "\n"


def run(cfg: DictConfig) -> pd.DataFrame:
    tracking = TrackingSettings.from_config(cfg.tracking)
    load_before = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    threads = torch.get_num_threads()
    try:
        table, model = measure(cfg)
    finally:
        torch.set_num_threads(threads)  # isolate=false sets them in this process
    about = machine(load_before, int(cfg.export.benchmark.threads))
    out = project_path(cfg.paths.data) / "export"
    text = markdown(table, model, about)
    write_csv(table, out / "latency.csv")
    write_text(text, out / "latency.md")
    with stage_run(tracking, "export-latency", {"stage": "export"}) as mlrun:
        mlrun.log_params({"export.benchmark": as_dict(cfg.export.benchmark), "model": as_dict(cfg.model),
                          "machine": about})
        slug = lambda name: re.sub(r"[^a-z0-9]+", "_", name.lower()).strip("_")  # noqa: E731  ONNX Runtime, 1 thread -> onnx_...
        mlrun.log_metrics({f"latency_ms.{slug(r.runtime)}.holes_{r.holes}": r.median_ms
                           for r in table.dropna(subset=["median_ms"]).itertuples()})
        for path in (out / "latency.csv", out / "latency.md"):
            mlrun.log_artifact(path, "export")
    log.info("latency written to %s\n%s", out / "latency.md", text)
    return table


@hydra.main(version_base="1.3", config_path="../conf", config_name="config")
def main(cfg: DictConfig) -> None:
    run(cfg)


if __name__ == "__main__":
    main()
