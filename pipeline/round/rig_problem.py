"""An instance and its oracle from a rig and each boom's joint solutions (the stage's entry point).

``joints[b]`` is ``(H, n)``: boom b's chosen solution of each hole (any values where ``reach[b, h]``
is False; NaN is fine). Move times are the time model's synchronised moves between those solutions
(full-turn joints the short way), computed for every pair at once; drilling times come from each
hole's length and the boom's motion file (booms of one rig share one drilling model: the first's).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
import torch

from pipeline.round.oracle import KinematicOracle
from pipeline.round.problem import Instance, drill_phases
from pipeline.round.settings import RoundSettings

D = torch.float64


def kinematic_round(rig, hole_ids: Sequence[str], joints: Sequence[torch.Tensor], reach, lengths, motions,
                    collars=None, precedence=(), settings: RoundSettings | None = None, reasons=None,
                    clear_of_parks: bool = True):
    """``clear_of_parks``: a hole's solution for boom b that breaks d_boom to another boom standing at
    its park is taken out of b's reach (its reason says so). The round starts and ends with every boom
    at park, and the one-boom-at-a-time fallback of the timeline is conflict-free only for holes clear
    of the other parks (:mod:`pipeline.round.timeline`); the stage may instead solve each boom's holes
    with the other booms at park as obstacles, which gives the same guarantee with fewer losses."""
    from pipeline.motion.timing import move_time

    settings = settings or RoundSettings()
    H = len(hole_ids)
    nodes = [torch.cat([torch.as_tensor(q, dtype=D).reshape(H, -1), m.park[None].to(D)]) for q, m in
             zip(joints, rig.booms, strict=True)]
    move = np.stack([move_time(q[:, None, :], q[None, :, :], motions[b].joints).numpy() for b, q in enumerate(nodes)])
    dr = motions[0].drilling
    phases = drill_phases(lengths, dr.collaring_s, dr.rate_m_per_min, dr.retract_m_per_s)
    with torch.inference_mode():
        parks = np.stack([m.tool_pose(m.park.to(D))[0].numpy() for m in rig.booms])
    inst = Instance(tuple(rig.names), tuple(hole_ids), np.asarray(reach, bool), phases, move, tuple(precedence),
                    None if collars is None else np.asarray(collars, float),
                    np.array([m.base[1] for m in rig.booms]), parks, reasons)
    oracle = KinematicOracle(rig, nodes, [m.joints for m in motions], settings.sample_m, settings.traj_tol_m)
    if clear_of_parks and len(rig.booms) > 1:
        reach = np.array(reach, bool)
        why = list(reasons) if reasons is not None else [""] * H
        for b in range(len(rig.booms)):
            for o in range(len(rig.booms)):
                if o == b:
                    continue
                c = oracle.standing(b, o)[:H, H]
                hit = reach[b] & (c < 0)
                for h in np.flatnonzero(hit):
                    note = (f"boom {rig.names[b]}: in the way of boom {rig.names[o]} at park "
                            f"({c[h] + rig.d_boom:.3f} m < d_boom)")
                    why[h] = f"{why[h]}; {note}" if why[h] else note
                reach[b] &= ~hit
        inst = dataclasses.replace(inst, reach=reach, reasons=tuple(why))
    return inst, oracle
