"""Rounds without a plan or an IK solver: holes made by forward kinematics of joint vectors near each
boom's face region, for tests and for measuring the planner on real kinematics.

Each boom's holes are where its sampled joints put the drill end (collar) in the rig frame, so each
hole is drillable by the boom that made it (``reach`` is one boom per hole): allocation is fixed,
order and timing are what is planned. ``inner`` of a boom's holes put its feed on the inner side of
the boom (toward the centre line), where the booms meet: those are the conflicts.

The rig, the motions and the settings come from the caller (nothing here reads ``conf/``).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from pipeline.round.instance import RoundSettings
from pipeline.round.kinematic import kinematic_round

D = torch.float64


def boom_joints(n: int, seed: int, q7_deg: float, swing_deg=(-12.0, 12.0)) -> torch.Tensor:
    """``(n, 8)`` jumbo8 joints: swing, lift and both extensions varied; the feed kept near +x (q5, q6
    undo the lift and the swing); ``q7`` puts the feed on one side of the boom."""
    g = torch.Generator().manual_seed(seed)
    u = torch.rand(n, 8, generator=g, dtype=D)
    q = torch.zeros(n, 8, dtype=D)
    q[:, 0] = math.radians(swing_deg[0]) + u[:, 0] * math.radians(swing_deg[1] - swing_deg[0])
    q[:, 1] = math.radians(-10) + u[:, 1] * math.radians(30)
    q[:, 2] = 3.2 + 0.8 * u[:, 2]
    q[:, 4], q[:, 5], q[:, 6] = -q[:, 1], -q[:, 0], math.radians(q7_deg)
    q[:, 7] = 2.0 + 0.8 * u[:, 7]
    return q


# q7 that puts each boom's feed on its outer / inner side, by the sign of its base y (spec twin parks)
def _q7(base_y: float, inner: bool) -> float:
    outer = 180.0 if base_y > 0 else 0.0
    return (outer + 180.0) % 360.0 if inner else outer


def fk_round(rig, motions, n_per_boom: int, seed: int = 0, inner: float = 0.3, length: float = 4.0,
             settings: RoundSettings | None = None):
    """An instance and its kinematic oracle: ``n_per_boom`` holes per boom, a share ``inner`` of them
    with the feed on the boom's inner side; rows interleave the booms (plan order). Holes in the way of
another boom at its park are dropped, so a round may hold a few holes less than ``B * n_per_boom``."""
    B, n_in = len(rig.booms), int(round(inner * n_per_boom))
    qs, owner = [], []
    for b, m in enumerate(rig.booms):
        q_out = boom_joints(n_per_boom - n_in, seed * 101 + 2 * b, _q7(m.base[1], False))
        q_in = boom_joints(n_in, seed * 101 + 2 * b + 1, _q7(m.base[1], True), (-6.0, 6.0))
        qs.append(torch.cat([q_out, q_in]))
        owner.append(np.full(n_per_boom, b))
    order = np.argsort(np.concatenate([np.arange(n_per_boom) * B + b for b in range(B)]), kind="stable")
    H = B * n_per_boom
    joints, reach, collars = [], np.zeros((B, H), bool), np.zeros((H, 3))
    owner = np.concatenate(owner)[order]
    with torch.inference_mode():
        points = torch.cat([m.tool_pose(q)[0] for m, q in zip(rig.booms, qs, strict=True)]).numpy()[order]
    allq = torch.cat(qs)[torch.as_tensor(order)]
    for b in range(B):
        mine = torch.as_tensor(owner == b)
        joints.append(torch.where(mine[:, None], allq, torch.full_like(allq, math.nan)))
        reach[b] = owner == b
    collars[:] = points
    ids = [f"h{k:03d}" for k in range(H)]
    inst, oracle = kinematic_round(rig, ids, joints, reach, np.full(H, length), motions, collars, settings=settings)
    keep = inst.drillable  # holes in the way of another boom's park are dropped (as a reach table would)
    if keep.all():
        return inst, oracle
    idx = np.flatnonzero(keep)
    return kinematic_round(rig, [ids[k] for k in idx], [q[torch.as_tensor(idx)] for q in joints], reach[:, idx],
                           np.full(len(idx), length), motions, collars[idx], settings=settings)
