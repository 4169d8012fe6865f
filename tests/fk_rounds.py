"""Joint vectors near a jumbo8 boom's face region, for round tests on real kinematics: holes are made
where these joints put the drill end, so each is drillable by the boom that made it (test scaffolding;
it lived in the library as ``pipeline.round.synthetic``; the round benchmark measures real faces)."""

from __future__ import annotations

import math

import torch

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


# q7 that puts each boom's feed on its outer / inner side, by the sign of its base y (the twin rig's parks)
def _q7(base_y: float, inner: bool) -> float:
    outer = 180.0 if base_y > 0 else 0.0
    return (outer + 180.0) % 360.0 if inner else outer
