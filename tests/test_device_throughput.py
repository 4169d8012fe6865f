"""The hybrid on any device and its throughput benchmark.

No GPU here: the hybrid is shown to make every tensor on its holes' device by solving CPU holes with
torch's default device set to ``meta``, where any tensor made without the holes' device lands and then
fails the first operation that meets a CPU tensor; the answers must equal an ordinary solve's. Where CUDA
is present, a CUDA solve must give the CPU one's statuses. The benchmark script runs at a tiny size, and
its check of the answers is shown to catch a solver that calls wrong joints ``ok``."""

import json

import pytest
import torch

from pipeline.core.errors import InputError
from pipeline.data.holes import HoleSampling, sample_holes
from pipeline.evaluation.device_throughput import measure_size
from pipeline.learning.models import build_model
from pipeline.solvers.base import HoleTargets, NetworkSolver
from pipeline.solvers.hybrid import HybridSettings, HybridSolver

SMALL = HybridSettings(perturbed_starts=4, random_starts=4, deep_starts=8, deep_iters=10)


@pytest.fixture(scope="module")
def holes(safety):
    pose, _ = sample_holes(48, safety, HoleSampling(), 11)
    return HoleTargets(pose, safety.boom.preview_depth)


def _network(boom):
    """An untrained network: its answers are poor, so the fallbacks (perturbed, random, deep) all run."""
    torch.manual_seed(0)
    return NetworkSolver(boom, build_model(boom, torch.zeros(6), torch.ones(6), 32, 2, "tanh"), "untrained")


def _same(a, b):
    assert a.status == b.status
    assert torch.equal(a.q, b.q) and torch.equal(a.iterations, b.iterations)
    assert all(torch.equal(a.clearances[k], b.clearances[k]) for k in a.clearances)


@pytest.mark.parametrize("first", ["network", "mid-range", "given start"])
def test_the_hybrid_makes_every_tensor_on_its_holes_device(safety, holes, first):
    init = _network(safety.boom) if first == "network" else None
    solver = HybridSolver(safety.boom, safety, init, SMALL, base=[0.1, -0.2, 0.0] if first == "network" else None)
    lo, hi = safety.boom.limits()
    start = safety.boom.with_locks(0.5 * (lo + hi)) if first == "given start" else None
    reference = solver.solve(holes, start=start)
    assert "ok" in reference.status
    previous = torch.get_default_device()
    torch.set_default_device("meta")
    try:
        on_meta_default = solver.solve(holes, start=start)
    finally:
        torch.set_default_device(previous)
    _same(reference, on_meta_default)


def test_the_meta_default_device_does_catch_a_tensor_made_without_a_device(safety, holes):
    """The check above can fail: a solver whose LM damping is made on the default device breaks."""
    from pipeline.optim import least_squares as ls

    original = ls.torch.full

    def careless_full(size, value, *, dtype=None, device=None, **kw):
        return original(size, value, dtype=dtype, **kw)  # forgets the device, as the old code did

    solver = HybridSolver(safety.boom, safety, None, SMALL)
    previous = torch.get_default_device()
    torch.set_default_device("meta")
    try:
        ls.torch.full = careless_full
        with pytest.raises(RuntimeError, match="meta"):
            solver.solve(holes)
    finally:
        ls.torch.full = original
        torch.set_default_device(previous)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_a_cuda_solve_gives_the_cpu_solve_s_statuses(safety, holes):
    init = _network(safety.boom)
    cpu = HybridSolver(safety.boom, safety, init, SMALL).solve(holes)
    gpu_init = NetworkSolver(safety.boom, init.model.cuda(), "untrained")
    gpu = HybridSolver(safety.boom, safety, gpu_init, SMALL).solve(HoleTargets(holes.pose.cuda(), holes.depth))
    assert gpu.q.device.type == "cuda"
    assert gpu.status == cpu.status
    assert (gpu.q.cpu() - cpu.q).abs().max() < 1e-6


def test_the_throughput_script_writes_its_table(tmp_path):
    import importlib.util

    from pipeline.core.config import PROJECT_ROOT

    spec = importlib.util.spec_from_file_location("gpu_throughput", PROJECT_ROOT / "scripts" / "gpu_throughput.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    script.main(["--sizes", "24", "--model", "none", "--repeats", "1", "--device", "cpu", "--out", str(tmp_path),
                 "--stages", "16", "solver.deep_starts=8", "solver.random_starts=4"])
    result = json.loads((tmp_path / "throughput.json").read_text())
    stages = result["stages"]  # the pose-only LM over every hole first, the whole solve last
    assert stages[0]["stage"].startswith("refine, safety rows off") and stages[0]["rows"] == 16
    assert stages[-1]["stage"] == "whole solve" and stages[-1]["seconds"] >= sum(r["seconds"] for r in stages[:-1])
    (row,) = result["rows"]
    assert row["holes"] == 24 and row["device"] == "cpu" and row["holes_per_s"] > 0
    assert sum(row["statuses"].values()) == 24 and row["repeat_identical"] is True
    assert row["ok_but_bad"] == 0 and row["ok_share"] == row["statuses"].get("ok", 0) / 24
    assert "| cpu | hybrid | 24 |" in (tmp_path / "throughput.md").read_text()
    with pytest.raises(SystemExit):  # a bad option is named by argparse, before any work
        script.main(["--sizes", "0"])
    # logged as one MLflow run from the JSON, as a GPU machine's table is logged back here
    import mlflow

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    script.log_to_mlflow(script.read_result(str(tmp_path / "throughput.json")), [f"tracking.uri={uri}"])
    mlflow.set_tracking_uri(uri)
    (run,) = mlflow.search_runs(search_all_experiments=True, output_format="list")
    assert run.data.metrics["cpu.hybrid.24.holes_per_s"] == pytest.approx(row["holes_per_s"])
    with pytest.raises(InputError, match="cannot read it as JSON"):
        script.read_result(str(tmp_path / "missing.json"))


def test_the_benchmark_s_check_catches_joints_wrongly_called_ok(safety):
    """A solver that returns its joints a little off and still says ``ok`` is caught by the
    benchmark's own check from the joints (``ok_but_bad``), and its ok share falls."""

    class Careless(HybridSolver):
        def solve(self, targets, obstacles=(), start=None):
            res = super().solve(targets, obstacles, start)
            res.q = res.q.clone()
            res.q[::2, 7] += 0.01  # q8, the feed: 1 cm along the hole
            res.status = ["ok"] * len(res.q)
            return res

    sampling = HoleSampling()
    honest = measure_size(HybridSolver(safety.boom, safety, None, SMALL), safety, sampling, 16, 3,
                          torch.device("cpu"), 1, 16)
    careless = measure_size(Careless(safety.boom, safety, None, SMALL), safety, sampling, 16, 3,
                            torch.device("cpu"), 1, 16)
    assert honest.ok_but_bad == 0
    assert careless.ok_but_bad >= 8 and careless.ok_share <= honest.ok_share - 0.5
