"""A small start network distilled from a trained one: the hybrid's first start at a fraction of the cost.

The hybrid refines its first start by Levenberg-Marquardt, so the start need not be millimetric: it has to
land in the basin of the answer the teacher (CUIKM) would lead to, in the same posture and as clear of the
tunnel. A network that imitates the teacher's joints does that, and a 2 x 128 ReLU network (about 18 000
multiply-adds a hole) imitates a 4 x 512 GELU one (about 800 000) to a few thousandths of each joint's range.
The student keeps the teacher's input normalisation and joint ranges, so its outputs stay inside the limits
as the teacher's do. Measured in docs/benchmarks.md ("A distilled start").
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import torch

from pipeline.core.errors import ConfigError
from pipeline.core.settings import parse, rule
from pipeline.geometry.kinematics import Boom, pose_errors
from pipeline.learning.models import ACTIVATIONS, IKNet

NETWORK_NAME = re.compile(r"[A-Za-z0-9_-][A-Za-z0-9_.-]{0,63}")


@dataclass(frozen=True)
class DistillSettings:
    """The ``distill`` config group (conf/distill/default.yaml says why each value)."""

    teacher: str = "cuikm"
    name: str = "cuikm_start"
    width: int = field(default=128, metadata=rule(ge=1, le=4096))
    depth: int = field(default=2, metadata=rule(ge=1, le=16))
    activation: str = field(default="relu", metadata=rule(choices=sorted(ACTIVATIONS)))
    steps: int = field(default=10000, metadata=rule(ge=1, le=10_000_000))
    batch_size: int = field(default=1024, metadata=rule(ge=1, le=65_536))
    lr: float = field(default=2.0e-3, metadata=rule(gt=0, le=1))
    lr_min: float = field(default=2.0e-5, metadata=rule(ge=0))
    pool: int = field(default=100000, metadata=rule(ge=1, le=1_000_000))
    val_size: int = field(default=5000, metadata=rule(ge=1, le=1_000_000))
    seed: int = field(default=0, metadata=rule(ge=0, le=2**32 - 1))

    @classmethod
    def from_config(cls, node) -> DistillSettings:
        settings = parse(cls, node, "distill")
        for key in ("teacher", "name"):  # a file name in paths.data/models, never a path out of it
            value = getattr(settings, key)
            if not NETWORK_NAME.fullmatch(value):
                raise ConfigError(f"distill.{key} = {value!r}: expected a network name (letters, digits, '_', '-', "
                                  "'.'; 1-64 characters, not starting with '.'): it names <name>.pt in "
                                  "paths.data/models, so no folder or '..' in it")
        if settings.batch_size > settings.pool:
            raise ConfigError(f"distill.batch_size = {settings.batch_size}: more than distill.pool = {settings.pool} "
                              "holes to draw a batch from")
        if settings.name == settings.teacher:
            raise ConfigError(f"distill.name = {settings.name!r} is the teacher's name: the student would overwrite "
                              "the network it learns from")
        if settings.lr_min > settings.lr:
            raise ConfigError(f"distill.lr_min = {settings.lr_min} is above distill.lr = {settings.lr}")
        return settings


def student_like(teacher: IKNet, width: int, depth: int, activation: str) -> IKNet:
    """A fresh network with the teacher's input normalisation and joint ranges."""
    return IKNet(teacher.lower, teacher.lower + teacher.span, teacher.in_mean, teacher.in_std, width, depth,
                 activation)


def distil(teacher: IKNet, pose: torch.Tensor, width: int, depth: int, activation: str, steps: int,
           batch_size: int, lr: float, lr_min: float, seed: int) -> tuple[IKNet, list[dict]]:
    """A student fitted to the teacher's joints (fractions of their ranges, mean squared) on ``pose``
    ``(N, 6)``: Adam, the rate annealed from ``lr`` to ``lr_min`` (cosine), minibatches drawn with ``seed``.
    Returns the student (eval mode) and its loss every tenth of the steps."""
    teacher = teacher.eval()
    pose = pose.to(teacher.in_mean.dtype)
    with torch.no_grad():
        target = teacher.unit_joints(pose)  # once: the teacher is fixed
    with torch.random.fork_rng(devices=[]):  # seeded initial weights without touching the global generator
        torch.manual_seed(seed)
        student = student_like(teacher, width, depth, activation)
    opt = torch.optim.Adam(student.parameters(), lr=lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps, eta_min=lr_min)
    gen = torch.Generator().manual_seed(seed)
    history, every = [], max(1, steps // 10)
    student.train()
    for step in range(1, steps + 1):
        idx = torch.randint(len(pose), (batch_size,), generator=gen)
        loss = (student.unit_joints(pose[idx]) - target[idx]).square().mean()
        value = float(loss.detach())
        if not math.isfinite(value):
            raise FloatingPointError(f"distillation: the loss is {value} at step {step}")
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        sched.step()
        if step % every == 0 or step == steps:
            history.append({"step": step, "loss": value, "lr": sched.get_last_lr()[0]})
    return student.eval(), history


@torch.no_grad()
def imitation_metrics(student: IKNet, teacher: IKNet, boom: Boom, pose: torch.Tensor) -> dict[str, float]:
    """How far the student's joints lie from the teacher's (fractions of each joint's range: mean, p95,
    max over holes of the largest joint's), and each network's own hole-seeking error (mm, float64 FK):
    the student's start need not be exact, the hybrid refines it."""
    pose = pose.to(teacher.in_mean.dtype)
    qs, qt = student(pose), teacher(pose)
    dev = ((qs - qt).abs() / teacher.span).amax(-1).double()
    out = {"joint_dev_mean": float(dev.mean()), "joint_dev_p95": float(torch.quantile(dev, 0.95)),
           "joint_dev_max": float(dev.max())}
    for who, q in (("student", qs), ("teacher", qt)):
        err = 1000 * pose_errors(boom.pose6(q.double()), pose.double())["hole"]
        out[f"{who}_hole_mm_mean"] = float(err.mean())
        out[f"{who}_hole_mm_p95"] = float(torch.quantile(err, 0.95))
    return out
