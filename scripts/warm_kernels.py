"""Compile every numba kernel of the project once, into numba's on-disk cache (``cache=True``).

    python scripts/warm_kernels.py

numba compiles a kernel the first time a process calls it on a machine (about a minute for all of
them on two cores) and loads it from the cache afterwards (under a second). The README's first
command runs this script before ``dvc repro``, and CI (``.ci/run``) after the install, so the stages
and the test command's two workers load the kernels instead of each compiling them. Nothing is written but
numba's cache (``__pycache__`` beside the kernels' modules, or ``NUMBA_CACHE_DIR``).
"""

from __future__ import annotations

import time

import numpy as np
import torch

from pipeline.assembly.build import build_safety
from pipeline.assembly.rig import composed_rig
from pipeline.core.config import compose
from pipeline.geometry.compiled_kinematics import ChainArrays, SafetyArrays, chain_values, clearance_values
from pipeline.learning.models import build_model
from pipeline.motion.timing import rig_motions
from pipeline.round.oracle import KinematicOracle
from pipeline.solvers.compiled import CompiledHybridSolver, CompiledMLP


def warm() -> dict[str, float]:
    """Seconds spent on each group of kernels (the hybrid's, the rig's, the round oracle's)."""
    cfg = compose(["rig=twin"])
    seconds = {}
    t0 = time.perf_counter()
    safety = build_safety(cfg.boom, cfg.tunnel, cfg.safety)
    boom = safety.boom
    CompiledHybridSolver(boom, safety, None)  # its constructor runs every kernel and mode once
    home = 0.5 * sum(boom.limits(torch.float64)).expand(2, -1).contiguous()
    pose = boom.pose6(home).float()
    CompiledMLP(build_model(boom, pose.mean(0), pose.std(0) + 1, 8, 2, "gelu"))(pose.numpy())  # the network start
    chain = ChainArrays.from_boom(boom)
    frames, _, _ = chain_values(chain, home.numpy())  # the batched chain and clearances (tests, calibration)
    clearance_values(chain, SafetyArrays.from_model(safety), frames)
    seconds["hybrid"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    rig = composed_rig(cfg)
    parks = rig.parks()
    for i, boom in enumerate(rig.booms):
        boom.clearances(parks[i][None])  # frames and clearances of one boom
    rig.boom_clearance(0, parks[0][None], 1, parks[1][None])  # ends and the indexed pair clearances
    seconds["rig"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    motions = rig_motions(cfg.motion, rig.booms)
    oracle = KinematicOracle(rig, [torch.stack([p, p]) for p in parks], [m.joints for m in motions])
    move = {"t0": np.zeros(1), "u": np.array([0]), "v": np.array([1])}  # node 0 to the park: one moving pair
    oracle.check(0, move, 1, move, np.zeros(1), np.ones(1))  # the round oracle's compiled advancement
    seconds["oracle"] = time.perf_counter() - t0
    return seconds


if __name__ == "__main__":
    torch.set_num_threads(1)
    print("numba kernels ready: " + ", ".join(f"{k} {v:.1f} s" for k, v in warm().items()))
