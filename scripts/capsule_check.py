"""Measurement (docs/benchmarks.md, "The safety model's capsule check"): the tunnel check of a capsule,
with the exact check's candidate points (``safety.exact_capsules: true``, docs/design.md "Distances to
surfaces") and by evenly spaced samples alone, on the same configurations.

    python scripts/capsule_check.py [configurations]     # default 20 000

Two sets of jumbo8 configurations: joints uniform in their ranges (``sample_joints``), and the joints
of the hybrid solver's answers to holes drawn like test group 1 (near the tunnel, where a verdict can
flip). The reference is 4 001 samples per capsule. Per model and set: how often a tunnel verdict
differs from the reference's, the largest amount by which its clearance is above the reference's
(a sampled model can only be too optimistic) where the reference keeps the distance (elsewhere both
fail), and the batched time of ``clearances_from_frames`` (median of 5, one torch thread). Prints a
markdown table. Timings are wall clock on whatever else the machine is doing: compare the rows of one run.
"""

import statistics
import sys
import time

import torch

from pipeline.assembly.build import build_safety
from pipeline.core.config import load_group_file
from pipeline.data.holes import HoleSampling, sample_holes, sample_joints
from pipeline.geometry.collision import SafetyModel
from pipeline.geometry.tunnel import SURFACES
from pipeline.solvers.base import HoleTargets
from pipeline.solvers.hybrid import HybridSolver

MODELS = ((16, False), (64, False), (256, False), (16, True))


def _answers(safety: SafetyModel, n: int) -> torch.Tensor:
    pose, _ = sample_holes(n, safety, HoleSampling(), seed=1)
    return HybridSolver(safety.boom, safety, None).solve(HoleTargets(pose, safety.boom.preview_depth)).q


def _row(model: SafetyModel, frames: torch.Tensor, reference: dict) -> tuple[float, float, float]:
    times = []
    for _ in range(5):
        start = time.perf_counter()
        got = model.clearances_from_frames(frames)
        times.append(time.perf_counter() - start)
    flips = torch.stack([(got[k] < 0) != (reference[k] < 0) for k in SURFACES]).any(0).double().mean()
    above = max(float(torch.where(reference[k] >= 0, got[k] - reference[k], 0.0).max()) for k in SURFACES)
    return float(flips), above, statistics.median(times) / frames.shape[0]


def main(n: int) -> None:
    torch.set_num_threads(1)
    safety = build_safety("jumbo8", load_group_file("tunnel", "horseshoe"), load_group_file("safety", "paper"))
    boom = safety.boom
    sets = {"random joints": sample_joints(n, boom, seed=11),
            "hybrid answers (group 1 holes)": _answers(safety, n // 20)}
    print("| configurations | model | tunnel verdicts that differ from 4 001 samples | largest clearance above "
          "4 001 samples (mm) | time per configuration (us) |")
    print("|---|---|---|---|---|")
    for name, q in sets.items():
        frames = boom.frames(q)
        reference = SafetyModel(boom, safety.tunnel, safety.distances, 4001, False).clearances_from_frames(frames)
        for points, exact in MODELS:
            model = SafetyModel(boom, safety.tunnel, safety.distances, points, exact)
            flips, above, per = _row(model, frames, reference)
            label = f"{points} samples" + (" + 6 exact candidates (default)" if exact else "")
            print(f"| {name} ({q.shape[0]}) | {label} | {100 * flips:.3f} % | {1000 * above:.4f} | {1e6 * per:.2f} |")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 20000)
