"""How far to trust the hybrid solver's ``unsafe`` and ``unreachable``: the same holes again with a
slow, thorough multi-start search as the reference, and the agreement of the two.

The fast path stops searching a hole as soon as a start is exact and clear, and gives up after a
fixed budget of starts; the reference spends about 50 times more (many more random starts, longer
LM runs). Every hole the fast path did not call ``ok`` is re-solved, with a random sample of the
holes it did call ``ok`` (an ``ok`` is checked by its own joints, so it cannot be wrong in the other
direction; the sample shows the reference agrees there too).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import replace

import torch

from pipeline.solvers.base import HoleTargets
from pipeline.solvers.hybrid import HybridSettings, HybridSolver


def reference_settings(fast: HybridSettings) -> HybridSettings:
    return replace(fast, max_iters=100, perturbed_starts=64, random_starts=256, deep_starts=1024, deep_iters=100,
                   seed=fast.seed + 1000)


def status_agreement(solver: HybridSolver, pose: torch.Tensor, fast_status: list[str], ok_sample: int,
                     seed: int = 0) -> dict:
    """Statuses of the fast path and of the reference on every non-ok hole and ``ok_sample`` ok holes."""
    not_ok = [i for i, s in enumerate(fast_status) if s != "ok"]
    ok = torch.tensor([i for i, s in enumerate(fast_status) if s == "ok"], dtype=torch.long)
    pick = ok[torch.randperm(len(ok), generator=torch.Generator().manual_seed(seed))[:ok_sample]].tolist()
    index = sorted(not_ok + pick)
    reference = HybridSolver(solver.boom, solver.safety, solver.init, reference_settings(solver.s), "reference",
                             (solver.space.full(solver.start_lo[None])[0], solver.space.full(solver.start_hi[None])[0]))
    result = reference.solve(HoleTargets(pose[index], solver.boom.preview_depth))
    pairs = Counter((fast_status[i], slow) for i, slow in zip(index, result.status, strict=True))
    agree = sum(n for (a, b), n in pairs.items() if a == b)
    return {
        "holes_checked": len(index), "fast_not_ok": len(not_ok), "ok_sampled": len(pick),
        "agreement": agree / len(index) if index else 1.0,
        "fast_not_ok_that_reference_solves": sum(n for (a, b), n in pairs.items() if a != "ok" and b == "ok"),
        "no_clear_solution_found_by_reference": sum(1 for s in result.status if s != "ok"),
        "pairs": {f"{a}->{b}": n for (a, b), n in sorted(pairs.items())},
        "reference_s": result.wall_s,
    }
