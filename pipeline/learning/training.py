"""Training loop shared by SIKM, UIKM and CUIKM (paper 000 Table 1, eq. 8)."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import torch
from tqdm.auto import tqdm

from pipeline.data.holes import HoleSampling, sample_holes
from pipeline.geometry.collision import SafetyModel
from pipeline.geometry.kinematics import Boom, pose_errors
from pipeline.learning.losses import joint_loss, pose_loss, safety_terms, total_loss
from pipeline.learning.models import IKNet


@dataclass(frozen=True)
class Objective:
    """What a method minimises: eq. 6 when supervised, else eq. 16 (eq. 7 when ``mu == 0``)."""

    supervised: bool
    lam: float = 1.0
    mu: float = 0.0
    pose_loss: str = "mse"


def loss_terms(
    model: IKNet,
    boom: Boom,
    safety: SafetyModel,
    objective: Objective,
    pose: torch.Tensor,
    q_target: torch.Tensor | None = None,
) -> dict[str, torch.Tensor]:
    """Every loss term of a batch; ``loss`` is the one optimised, the rest are for logging."""
    unit = model.unit_joints(pose)
    q = model.lower + model.span * unit
    frames = boom.frames(q)
    terms = {"l_pos": pose_loss(boom.pose6_from_frames(frames), pose, objective.pose_loss)}
    with torch.set_grad_enabled(torch.is_grad_enabled() and objective.mu > 0 and not objective.supervised):
        terms.update(safety_terms(safety.penalties(safety.clearances_from_frames(frames))))
    if objective.supervised:
        if q_target is None:
            raise ValueError("a supervised objective needs joint targets")
        terms["l_joint"] = joint_loss(unit, (q_target - model.lower) / model.span)
        terms["loss"] = terms["l_joint"]
    else:
        terms["loss"] = total_loss(terms, objective.lam, objective.mu)
    return terms


def dataset_batches(
    pose: torch.Tensor, q: torch.Tensor | None, batch: int, seed: int
) -> Iterator[tuple[torch.Tensor, torch.Tensor | None]]:
    """Random minibatches from a fixed set (Table 1: "select batch size group data at random")."""
    gen = torch.Generator().manual_seed(seed)
    while True:
        idx = torch.randint(len(pose), (batch,), generator=gen).to(pose.device)
        yield pose[idx], (None if q is None else q[idx])


def fresh_hole_batches(
    safety: SafetyModel, sampling: HoleSampling, batch: int, seed: int, device, dtype=torch.float32
) -> Iterator[tuple[torch.Tensor, None]]:
    """A new set of drillable holes every step, drawn like Omega_unsup."""
    gen = torch.Generator().manual_seed(seed)
    while True:
        pose, _ = sample_holes(batch, safety, sampling, gen)
        yield pose.to(device=device, dtype=dtype), None


@torch.no_grad()
def pose_metrics(model: IKNet, boom: Boom, pose: torch.Tensor) -> dict[str, float]:
    """Mean start / preview / hole-seeking error (mm) of the network on ``pose``, in float64 FK."""
    q = model(pose).double()
    err = pose_errors(boom.pose6(q), pose.double())
    return {f"val_{k}_mm": 1000 * float(err[k].mean()) for k in ("start", "preview", "hole")}


def train(
    model: IKNet,
    boom: Boom,
    safety: SafetyModel,
    objective: Objective,
    batches: Iterator[tuple[torch.Tensor, torch.Tensor | None]],
    steps: int,
    lr: float,
    val_pose: torch.Tensor,
    eval_every: int = 100,
    grad_clip: float | None = None,
    on_eval: Callable[[int, dict[str, float]], None] | None = None,
    progress: bool = True,
) -> list[dict[str, float]]:
    """Adam with the linearly annealed learning rate of eq. 8; returns the logged history."""
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda t: max(0.0, 1.0 - t / steps))
    history: list[dict[str, float]] = []
    bar = tqdm(range(steps), desc=f"train {'sup' if objective.supervised else 'unsup'}", disable=not progress)
    model.train()
    t0 = time.perf_counter()
    for step in bar:
        pose, q = next(batches)
        terms = loss_terms(model, boom, safety, objective, pose, q)
        opt.zero_grad(set_to_none=True)
        terms["loss"].backward()
        if grad_clip:
            torch.nn.utils.clip_grad_norm_(model.parameters(), grad_clip)
        opt.step()
        sched.step()
        if step % eval_every == 0 or step == steps - 1:
            model.eval()
            record = {"lr": sched.get_last_lr()[0], **{k: float(v.detach()) for k, v in terms.items()}}
            record.update(pose_metrics(model, boom, val_pose))
            model.train()
            history.append({"step": step, "elapsed_s": time.perf_counter() - t0, **record})
            bar.set_postfix(loss=f"{record['loss']:.3g}", hole_mm=f"{record['val_hole_mm']:.2f}")
            if on_eval is not None:
                on_eval(step, record)
    model.eval()
    return history
