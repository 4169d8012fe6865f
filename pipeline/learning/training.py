"""Training shared by SIKM, UIKM and CUIKM (paper 000 Table 1, eq. 8): settings, data, the loop.

The stage (:mod:`pipeline.train`) reads as config -> :func:`load_training_data` -> ``build_model``
-> :func:`fit` -> :func:`final_metrics` -> save and log; each step is a plain function here.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import torch
from tqdm.auto import tqdm

from pipeline.core.errors import ConfigError, InputError
from pipeline.core.settings import parse, rule
from pipeline.core.signals import raise_if_terminated
from pipeline.data.hole_sets import read_hole_poses, read_hole_table
from pipeline.data.holes import HoleSampling, sample_holes
from pipeline.data.tables import POSE_COLUMNS
from pipeline.geometry.collision import SafetyDistances, SafetyModel
from pipeline.geometry.kinematics import Boom, pose_errors
from pipeline.learning.losses import POSE_LOSSES, joint_loss, pose_loss, safety_terms, total_loss
from pipeline.learning.models import IKNet

Batches = Iterator[tuple[torch.Tensor, torch.Tensor | None]]


@dataclass(frozen=True)
class TrainSettings:
    """The ``train`` config group."""

    steps: int = field(metadata=rule(ge=1))
    batch_size: int = field(metadata=rule(ge=1))
    lr: float = field(metadata=rule(gt=0))
    seed: int = field(default=0, metadata=rule(ge=0))
    fresh_holes: bool = True
    eval_every: int = field(default=250, metadata=rule(ge=1))
    val_size: int = field(default=1000, metadata=rule(ge=1))
    val_seed: int = field(default=999, metadata=rule(ge=0))
    grad_clip: float | None = field(default=None, metadata=rule(gt=0))
    method_key: str = "method"
    keep_best: bool = True  # end with the weights of the best held-out evaluation, not the last step's

    @classmethod
    def from_config(cls, node: Mapping) -> TrainSettings:
        return parse(cls, node, "train")


@dataclass(frozen=True)
class Objective:
    """What a method minimises: eq. 6 when supervised, else eq. 16 (eq. 7 when ``mu == 0``)."""

    supervised: bool
    lam: float = 1.0
    mu: float = 0.0
    pose_loss: str = "mse"


@dataclass(frozen=True)
class MethodSettings:
    """A ``method`` config node (``conf/method/*.yaml``): name, objective, training safety distances."""

    name: str
    supervised: bool
    lam: float = field(metadata=rule(ge=0))
    mu: float = field(metadata=rule(ge=0))
    pose_loss: str = field(metadata=rule(choices=POSE_LOSSES))
    train_safety: dict = field(default_factory=dict)
    sup_set: str = "sup"  # supervised methods: which Omega_sup table of the hole set (sup, or a holes.sup_variants key)

    @classmethod
    def from_config(cls, node: Mapping, where: str = "method") -> MethodSettings:
        settings = parse(cls, node, where)
        SafetyDistances.from_config(dict(settings.train_safety))  # checked now, not after loading data
        return settings

    @property
    def objective(self) -> Objective:
        return Objective(self.supervised, self.lam, self.mu, self.pose_loss)


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


# ---------------------------------------------------------------------------------------- data
def dataset_batches(pose: torch.Tensor, q: torch.Tensor | None, batch: int, seed: int) -> Batches:
    """Random minibatches from a fixed set (Table 1: "select batch size group data at random")."""
    gen = torch.Generator().manual_seed(seed)
    while True:
        idx = torch.randint(len(pose), (batch,), generator=gen).to(pose.device)
        yield pose[idx], (None if q is None else q[idx])


def fresh_hole_batches(
    safety: SafetyModel, sampling: HoleSampling, batch: int, seed: int, device, dtype=torch.float32
) -> Batches:
    """A new set of drillable holes every step, drawn like Omega_unsup."""
    gen = torch.Generator().manual_seed(seed)
    while True:
        pose, _ = sample_holes(batch, safety, sampling, gen)
        yield pose.to(device=device, dtype=dtype), None


@dataclass
class TrainingData:
    """What a training run reads: its input set (which also sets the network's normalisation),
    joint labels when supervised, the held-out holes, and the files they came from."""

    pose: torch.Tensor
    q: torch.Tensor | None
    val_pose: torch.Tensor
    files: dict[str, tuple[Path, object]]  # MLflow dataset context -> (file, table)


def load_training_data(holes_dir: Path, boom: Boom, safety: SafetyModel, sampling: HoleSampling,
                       supervised: bool, val_size: int, val_seed: int, sup_set: str = "sup") -> TrainingData:
    """Omega_sup (``<sup_set>.parquet``: poses and joints, both checked finite) or Omega_unsup, read
    once and verified against ``meta.json``; held-out holes drawn like Omega_unsup with their own seed."""
    if supervised:
        name = f"{sup_set}.parquet"
        df = read_hole_table(holes_dir, name, [*POSE_COLUMNS, *boom.joint_names])
        pose = torch.tensor(df[POSE_COLUMNS].to_numpy(dtype="float64"))
        q = torch.tensor(df[boom.joint_names].to_numpy(dtype="float64"))
    else:
        name = "train.parquet"
        df, pose = read_hole_poses(holes_dir, name)
        q = None
    val_pose, _ = sample_holes(val_size, safety, sampling, val_seed)
    return TrainingData(pose, q, val_pose, {"training": (Path(holes_dir) / name, df)})


def training_batches(data: TrainingData, objective: Objective, settings: TrainSettings, safety: SafetyModel,
                     sampling: HoleSampling, device) -> Batches:
    if objective.supervised:
        return dataset_batches(data.pose.float().to(device), data.q.float().to(device), settings.batch_size,
                               settings.seed)
    if settings.fresh_holes:
        return fresh_hole_batches(safety, sampling, settings.batch_size, settings.seed, device)
    return dataset_batches(data.pose.float().to(device), None, settings.batch_size, settings.seed)


# ---------------------------------------------------------------------------------------- loop
@torch.no_grad()
def pose_metrics(model: IKNet, boom: Boom, pose: torch.Tensor) -> dict[str, float]:
    """Mean start / preview / hole-seeking error (mm) of the network on ``pose``, in float64 FK."""
    q = model(pose).double()
    err = pose_errors(boom.pose6(q), pose.double())
    return {f"val_{k}_mm": 1000 * float(err[k].mean()) for k in ("start", "preview", "hole")}


def fit(
    model: IKNet,
    boom: Boom,
    safety: SafetyModel,
    objective: Objective,
    batches: Batches,
    steps: int,
    lr: float,
    val_pose: torch.Tensor,
    eval_every: int = 100,
    grad_clip: float | None = None,
    on_eval: Callable[[int, dict[str, float], float], None] | None = None,
    progress: bool = True,
    keep_best: bool = False,
) -> list[dict[str, float]]:
    """Adam with the linearly annealed learning rate of eq. 8; returns the logged history.

    ``on_eval(step, record, elapsed_s)`` runs at every held-out evaluation (live MLflow curves). A
    non-finite loss stops training at once with the step named: a NaN model must never be saved.
    ``keep_best``: the model ends with the weights of its best held-out hole-seeking error (early
    stopping on held-out holes, never on the test groups); the history marks that step."""
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda t: max(0.0, 1.0 - t / steps))
    history: list[dict[str, float]] = []
    bar = tqdm(range(steps), desc=f"train {'sup' if objective.supervised else 'unsup'}", disable=not progress)
    model.train()
    t0 = time.perf_counter()
    best_mm, best_state, best_step = math.inf, None, None
    for step in bar:
        raise_if_terminated()  # SIGTERM stops training at a step boundary even if its exception was swallowed
        pose, q = next(batches)
        terms = loss_terms(model, boom, safety, objective, pose, q)
        if not torch.isfinite(terms["loss"]):
            raise InputError(f"training diverged: loss = {float(terms['loss'].detach())} at step {step} "
                             f"(terms {_finite_report(terms)}); check the data and train.lr = {lr}")
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
            elapsed = time.perf_counter() - t0
            history.append({"step": step, "elapsed_s": elapsed, **record})
            if keep_best and record["val_hole_mm"] < best_mm:
                best_mm, best_step = record["val_hole_mm"], step
                best_state = {k: v.detach().clone() for k, v in model.state_dict().items()}
            bar.set_postfix(loss=f"{record['loss']:.3g}", hole_mm=f"{record['val_hole_mm']:.2f}")
            if on_eval is not None:
                on_eval(step, record, elapsed)
    if best_state is not None:
        model.load_state_dict(best_state)
        for rec in history:
            rec["kept"] = float(rec["step"] == best_step)
    model.eval()
    return history


def _finite_report(terms: dict[str, torch.Tensor]) -> dict[str, float]:
    return {k: round(float(v.detach()), 6) for k, v in terms.items()}


Score = Callable[[torch.Tensor, torch.Tensor], Mapping[str, float]]  # (poses, joints) -> summary statistics


@torch.no_grad()
def final_metrics(model: IKNet, val_pose: torch.Tensor, score: Score, history: list[dict],
                  train_seconds: float) -> dict[str, float]:
    """Held-out errors and safety of the trained network; refuses a non-finite result.

    ``score(pose, q)`` gives ``hole_mm_p95``, ``collision_rate_paper`` and ``any_violation_share``
    (the evaluation's own statistics, passed in by the stage: learning sits below evaluation)."""
    val = score(val_pose.cpu(), model(val_pose.cpu()))
    kept = next((rec for rec in history if rec.get("kept")), history[-1])  # the weights the model ends with
    final = {
        **{k: v for k, v in kept.items() if k.startswith("val_")},
        "kept_step": kept["step"],
        "val_hole_mm_p95": val["hole_mm_p95"],
        "val_collision_rate": val["collision_rate_paper"],
        "val_any_violation_share": val["any_violation_share"],
        "train_seconds": train_seconds,
    }
    bad = sorted(k for k, v in final.items() if not math.isfinite(v))
    if bad:
        raise InputError(f"the trained network gives non-finite held-out metrics {bad}; not saving it")
    return final


def check_method_key(key: str, node) -> None:
    if node is None or "name" not in node:
        raise ConfigError(f"train.method_key = {key!r}: no method config at that key")
