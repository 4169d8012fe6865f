"""Labels by continuation: each hole pose solved from the joints of an already solved neighbour, so
that the labels follow one branch of the many-valued inverse across the whole set.

An independent search per pose (the home-branch labels) lands on whichever branch its own descent
reaches, and two neighbouring poses can end on different branches; a regression then averages
them. Here the set is walked along a nearest-neighbour graph in pose: starting from the poses
already solved (seeds: those the home descent solves, or a few nearest the set's centre), wave
after wave every unsolved pose with a solved neighbour is refined from its nearest solved
neighbour's joints, a short step that stays on that neighbour's branch. The walk spreads from the
seeds outwards (breadth first on the graph: an order along the face in collar and direction alike,
since the pose holds the collar and the preview point). Each wave is one batched solve, so the loop
runs over waves (the graph's depth, some tens), never over holes.
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from pipeline.data.neighbours import nearest_neighbours

Refine = Callable[[torch.Tensor, torch.Tensor], tuple[torch.Tensor, torch.Tensor]]  # starts, poses -> joints, exact


def continuation_labels(pose: torch.Tensor, refine: Refine, q0: torch.Tensor, solved0: torch.Tensor,
                        neighbours: int = 8, max_tries: int = 3) -> tuple[torch.Tensor, torch.Tensor, dict]:
    """Joints ``(n, n_joints)`` for poses ``pose (n, 6)``, whether each is exact ``(n,)``, and the
    walk's statistics. ``q0, solved0``: the labels the walk starts from and which of them are
    exact (they are kept); ``refine(starts, poses)`` solves poses from given starts. A pose whose
    refinement fails is tried again from its nearest solved neighbour in later waves, at most
    ``max_tries`` times; poses never solved keep ``exact = False``. The inputs are not modified."""
    n = len(pose)
    k = min(neighbours, n - 1)
    nbr, dist = nearest_neighbours(pose, torch.arange(n), k=k)
    nbr, dist = nbr.reshape(n, k).flatten(), dist.reshape(n, k).flatten()
    me = torch.arange(n).repeat_interleave(k)
    # the graph's edges both ways (a point is reached from its neighbours and from those it is a
    # neighbour of), so a tight cluster whose own neighbours all lie inside it is still reached
    src, dst, length = torch.cat([nbr, me]), torch.cat([me, nbr]), torch.cat([dist, dist])
    q, solved = q0.clone(), solved0.clone()
    tries = torch.zeros(n, dtype=torch.long)
    sizes = []
    while True:
        live = (solved[src] & ~solved[dst] & (tries[dst] < max_tries)).nonzero().squeeze(-1)
        if len(live) == 0:
            break
        live = live[length[live].argsort()]  # shortest edges first, so each target's first edge is its nearest
        frontier, inverse = torch.unique(dst[live], return_inverse=True)
        first = torch.full((len(frontier),), len(live)).scatter_reduce(0, inverse, torch.arange(len(live)), "amin")
        source = src[live[first]]  # each unsolved point's nearest solved neighbour
        q_new, ok = refine(q[source], pose[frontier])
        q[frontier[ok]], solved[frontier[ok]] = q_new[ok], True
        tries[frontier[~ok]] += 1
        sizes.append(len(frontier))
    stats = {"seeded_share": float(solved0.double().mean()), "waves": len(sizes),
             "largest_wave": max(sizes, default=0), "solved_share": float(solved.double().mean())}
    return q, solved, stats
