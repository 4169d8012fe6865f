"""Timing (docs/benchmarks.md "Peers and the compiled hybrid"): the compiled hybrid,
the torch hybrid, Robotics Toolbox ik_LM and Pinocchio CLIK on the same holes drawn like test group 1,
every answer judged by the project's safety model; then where the compiled batch's time goes.

    python scripts/time_peers.py [model.pt] [holes]     # model.pt: e.g. data/quick/models/cuikm.pt (1 000 holes)

Prints one JSON line per solver (pipeline.evaluation.peer_timing.time_solver) and one for the breakdown.
Timings are wall clock on whatever else the machine is doing: compare the rows of one run.
"""

import json
import statistics
import sys
import time

import numpy as np
import torch

from pipeline.assembly.build import build_safety
from pipeline.core.config import load_group_file
from pipeline.data.holes import HoleSampling, sample_holes
from pipeline.evaluation.peer_timing import time_solver
from pipeline.learning.models import load_checkpoint
from pipeline.solvers.base import HoleTargets, NetworkSolver
from pipeline.solvers.compiled import CompiledHybridSolver, fast_path_parallel
from pipeline.solvers.hybrid import HybridSolver
from pipeline.solvers.peers import build_peer, missing_peers


def main(model_path: str, n: int) -> None:
    safety = build_safety("jumbo8", load_group_file("tunnel", "horseshoe"), load_group_file("safety", "paper"))
    boom = safety.boom
    pose, _ = sample_holes(n, safety, HoleSampling(), seed=1)  # the first test group's seed and sampling
    net = NetworkSolver(boom, load_checkpoint(model_path)[0], "cuikm")
    compiled = CompiledHybridSolver(boom, safety, net)
    solvers = [(compiled, 300, True), (HybridSolver(boom, safety, net), 100, True)]
    if missing_peers():
        print("peers extra not installed: pip install -e '.[peers]'")
    else:
        solvers += [(build_peer("rtb_ik_lm", boom), 300, False), (build_peer("pinocchio_clik", boom), 300, False)]
    for solver, single, batch in solvers:
        start = time.time()
        row = time_solver(solver, pose, safety, single=single, batch=batch)
        print(json.dumps({**row, "wall_s": round(time.time() - start, 1)}), flush=True)
    # where the compiled batch's time goes (min and median of 10 runs)
    targets, poses = HoleTargets(pose, boom.preview_depth), pose.numpy()
    parts: dict[str, list[float]] = {"network": [], "fast_kernel": [], "cascade": [], "total": []}
    for _ in range(10):
        t0 = time.perf_counter()
        q0 = compiled.start_joints(targets, poses)
        t1 = time.perf_counter()
        out = fast_path_parallel(poses, q0, compiled.s.max_iters, compiled.s.tol_mm / 1000, *compiled._kernel_args())
        t2 = time.perf_counter()
        rest = np.flatnonzero(~out[4])
        compiled._cascade(targets.subset(torch.from_numpy(rest)), torch.from_numpy(q0[rest]))
        t3 = time.perf_counter()
        for key, value in zip(parts, (t1 - t0, t2 - t1, t3 - t2, t3 - t0), strict=True):
            parts[key].append(value)
    print(json.dumps({"holes": n, "fast_path_done": int(out[4].sum()),
                      **{f"{k}_ms_min": round(1000 * min(v), 2) for k, v in parts.items()},
                      **{f"{k}_ms_median": round(1000 * statistics.median(v), 2) for k, v in parts.items()}}))


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "data/quick/models/cuikm.pt",
         int(sys.argv[2]) if len(sys.argv) > 2 else 1000)
