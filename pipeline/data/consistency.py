"""How consistent the labels of a supervised set are: a regression can only learn a label that is
a continuous function of its input.

A pose reached by several joint solutions ("data confusion", paper 000 sect. 3; Bishop 1994 on robot
IK) gives a set whose nearest neighbours in pose carry far-apart joints, and a regression averages
them into an answer that fits neither. Measured over nearest-neighbour pairs in pose:

* ``ratio``: joint distance / pose distance (joints scaled by the caller, e.g. by their ranges, so
  revolute and prismatic joints count alike; poses in metres). On one smooth branch it is bounded
  by the inverse's local gain; across branches it grows without bound as the set gets denser.
* ``branch``: the pair lies on different branches. Two labels of one smooth branch, close in pose,
  are close in joints too, so the joint midpoint maps (to second order) onto the pose midpoint;
  across branches the joint midpoint lands far away. A pair counts as on different branches when
  that miss exceeds the pair's own pose distance.
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from pipeline.core.errors import InputError
from pipeline.data.neighbours import nearest_neighbours

PoseMap = Callable[[torch.Tensor], torch.Tensor]  # joints (m, n_joints) -> poses (m, pose_dim)


def label_consistency(pose: torch.Tensor, q: torch.Tensor, joint_scale: torch.Tensor, pose_map: PoseMap, *,
                      sample_size: int = 10_000, queries: int = 2000, seed: int = 0,
                      chunk: int = 512) -> dict[str, float]:
    """The consistency of labels ``q (n, n_joints)`` of poses ``pose (n, d)`` over the pairs
    (sample, its nearest neighbour in pose), for ``queries`` samples drawn with ``seed`` (all
    of them when the set is smaller). ``joint_scale (n_joints,)`` divides the joint differences
    (e.g. each joint's range; 0 is refused); ``pose_map`` is the forward map of the labels.

    Neighbours are searched within a seeded subset of ``sample_size`` samples (the whole set when
    smaller): the ratio across branches grows with density, so sets of different sizes are
    compared at one density.

    Returns ``samples`` (searched), ``pairs``, the median pose distance of the pairs, the median
    and 95th percentile of the ratio joint distance / pose distance, and the share of pairs on
    different branches (see the module docstring). The inputs are not modified."""
    if pose.ndim != 2 or q.ndim != 2 or len(pose) != len(q):
        raise InputError(f"label consistency: poses {tuple(pose.shape)} and joints {tuple(q.shape)} must be "
                         "(n, d) and (n, n_joints) with the same n")
    if len(pose) < 2:
        raise InputError(f"label consistency: {len(pose)} sample(s); a nearest-neighbour pair needs at least 2")
    if joint_scale.shape != (q.shape[1],) or not bool((joint_scale > 0).all()):
        raise InputError(f"label consistency: joint_scale {joint_scale.tolist()} must hold one positive number "
                         f"per joint ({q.shape[1]})")
    gen = torch.Generator().manual_seed(int(seed))
    if len(pose) > sample_size:
        keep = torch.randperm(len(pose), generator=gen)[:sample_size]
        pose, q = pose[keep], q[keep]
    n = len(pose)
    query = torch.randperm(n, generator=gen)[:queries] if queries < n else torch.arange(n)
    nbr, pose_dist = nearest_neighbours(pose, query, chunk=chunk)
    duplicate = pose_dist <= 0  # the same pose twice: no ratio, but its labels still may differ
    qa, qb = q[query], q[nbr]
    joint_dist = ((qa - qb) / joint_scale.to(q)).norm(dim=-1)
    if bool(duplicate.all()):
        raise InputError("label consistency: every pair repeats one pose; no joint/pose ratio can be measured")
    ratio = joint_dist[~duplicate] / pose_dist[~duplicate]
    miss = (pose_map(0.5 * (qa + qb)) - 0.5 * (pose[query] + pose[nbr])).norm(dim=-1)
    # the floor keeps rounding (a repeated pose with a repeated label) from counting as a jump
    branch = miss > pose_dist.clamp_min(1e-9)
    return {
        "samples": n,
        "pairs": int(len(query)),
        "pose_distance_median": float(pose_dist.median()),
        "ratio_median": float(ratio.median()),
        "ratio_p95": float(torch.quantile(ratio, 0.95)),
        "branch_jump_share": float(branch.double().mean()),
    }
