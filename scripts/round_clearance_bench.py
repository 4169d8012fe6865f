"""Benchmark (docs/benchmarks.md "The round's clearances, compiled"): the rig's clearances
through the numba kernels (pipeline/geometry/compiled_rig.py) against the torch code, side by side
in one run on one torch thread.

    python scripts/round_clearance_bench.py [face] [rig] [hydra overrides ...]   # default: 50 twin

Part 1, per batch size (1, 16, 256, 4096 configurations, random joints of the rig's first two booms):
the boom-boom clearance (``Rig.boom_clearance``) and one boom's four clearances
(``MountedBoom.clearances``), median of 7 timings each, and the largest difference of the two answers.
Part 2: one round planned three times by the stage's function (the round benchmark's cell:
reach table, sweeps, routing, baselines, certified moves; ``face``: ``demo`` or a hole count): every
kernel on; the clearance kernels on but the conflict oracle's advancement on torch
(``KinematicOracle.compiled``, pipeline/round/compiled_oracle.py); every kernel off
(``MountedBoom.compiled``); everything else the same: planning seconds and whether the rounds'
round and trajectory tables are byte-identical. One MLflow run
(``round-clearance-benchmark`` in the composed experiment) holds the table. Wall clock on whatever else
the machine does: compare the rows of one run.
"""

from __future__ import annotations

import contextlib
import statistics
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd
import torch

from pipeline.core.config import as_dict, compose
from pipeline.core.settings import parse
from pipeline.rig_benchmarks.round_faces import markdown, round_benchmark
from pipeline.round.oracle import KinematicOracle
from pipeline.round.settings import parse_round
from pipeline.schedule import benchmark_rigs
from pipeline.solvers.hybrid import HybridSettings
from pipeline.tracking.runs import TrackingSettings, stage_run

SIZES = (1, 16, 256, 4096)


def _median_s(fn, reps: int = 7) -> float:
    fn()  # loaded and warm
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _joints(boom, n: int, seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    lo, hi = boom.limits(torch.float64)
    return boom.with_locks(lo + (hi - lo) * torch.rand(n, boom.n_joints, generator=g, dtype=torch.float64))


def _set_compiled(rig, on: bool) -> None:
    for m in rig.booms:
        m.compiled = on


def kernels_table(rig) -> pd.DataFrame:
    a, b = rig.booms[0], rig.booms[1]
    rows = []
    for n in SIZES:
        qa, qb = _joints(a.boom, n, 1), _joints(b.boom, n, 2)
        for what, call in (("boom-boom", lambda qa=qa, qb=qb: rig.boom_clearance(0, qa, 1, qb)),
                           ("one boom's four", lambda qa=qa: a.clearances(qa))):
            with torch.inference_mode():
                _set_compiled(rig, True)
                fast, t_fast = call(), _median_s(call)
                _set_compiled(rig, False)
                slow, t_slow = call(), _median_s(call)
                _set_compiled(rig, True)
            if isinstance(fast, dict):
                diff = max(float((fast[k] - slow[k]).abs().max()) for k in fast)
            else:
                diff = float((fast - slow).abs().max())
            rows.append({"clearance": what, "batch": n, "compiled_ms": 1e3 * t_fast, "torch_ms": 1e3 * t_slow,
                         "speedup": t_slow / t_fast, "max_difference_m": diff})
    return pd.DataFrame(rows)


@contextlib.contextmanager
def _oracle_on_torch(on: bool):
    """While inside (``on``), every conflict oracle made advances on torch: the round benchmark builds its
    oracle inside, and ``KinematicOracle.compiled`` is an instance setting."""
    if not on:
        yield
        return
    init = KinematicOracle.__init__

    def torch_init(self, *args, **kwargs):
        init(self, *args, **kwargs)
        self.compiled = False

    KinematicOracle.__init__ = torch_init
    try:
        yield
    finally:
        KinematicOracle.__init__ = init


MODES = {"compiled": (True, False), "oracle on torch": (True, True), "torch": (False, False)}


def round_rows(cfg, face, rig_name: str) -> tuple[pd.DataFrame, bool]:
    """The round planned in each of :data:`MODES`; and whether their round and trajectory tables are identical."""
    case = benchmark_rigs(cfg, [rig_name])[0]
    settings = parse_round(as_dict(cfg.round), "round")
    hybrid = parse(HybridSettings, cfg.solver, "solver")
    box = cfg.holes.sup.get("box")
    out, files = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for k, (mode, (kernels, oracle_on_torch)) in enumerate(MODES.items()):
            folder = Path(tmp) / str(k)
            folder.mkdir()
            _set_compiled(case.rig, kernels)
            with _oracle_on_torch(oracle_on_torch):
                table = round_benchmark([face], [case], hybrid, settings, lambda boom: None, 0, print, folder,
                                        None if box is None else as_dict(box))
            out.append(table.assign(clearances=mode))
            # the round and trajectory tables (the JSON names its folder's plan, so it differs by the path)
            files.append(b"".join(f.read_bytes() for f in sorted(folder.glob("*_round.csv"))
                                  + sorted(folder.glob("*_trajectory.csv"))))
    _set_compiled(case.rig, True)
    return pd.concat(out, ignore_index=True), all(f == files[0] for f in files)


def main(argv: list[str]) -> None:
    face = argv[0] if argv else "50"
    rig_name = argv[1] if len(argv) > 1 else "twin"
    cfg = compose(argv[2:])
    torch.set_num_threads(1)
    tracking = TrackingSettings.from_config(cfg.tracking)
    with stage_run(tracking, "round-clearance-benchmark", {"stage": "script", "mode": "benchmark"}) as run:
        rig = benchmark_rigs(cfg, [rig_name])[0].rig
        kernels = kernels_table(rig)
        print(kernels.to_markdown(index=False, floatfmt=".4g"))
        rounds, same = round_rows(cfg, face if face == "demo" else int(face), rig_name)
        print(markdown(rounds.drop(columns=["clearances"])))
        compiled_s, oracle_torch_s, torch_s = (float(rounds.iloc[i]["planning_s"]) for i in range(3))
        print(f"planning: compiled {compiled_s:.1f} s, the oracle's advancement on torch {oracle_torch_s:.1f} s "
              f"({oracle_torch_s / compiled_s:.2f}x), torch {torch_s:.1f} s ({torch_s / compiled_s:.2f}x); "
              f"the trajectory files identical: {same}")
        run.log_params({"face": face, "rig": rig_name})
        run.log_table(kernels, "kernels.json")
        run.log_table(rounds, "rounds.json")
        run.log_metrics({"planning_compiled_s": compiled_s, "planning_oracle_torch_s": oracle_torch_s,
                         "planning_torch_s": torch_s, "same_round": float(same)})


if __name__ == "__main__":
    main(sys.argv[1:])
