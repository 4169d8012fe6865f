"""Training shared by SIKM, UIKM and CUIKM (paper 000 Table 1, eq. 8): settings, data, the loop.

The stage (:mod:`pipeline.train`) reads as config -> :func:`load_training_data` -> ``build_model``
-> :func:`fit` -> :func:`final_metrics` -> save and log; each step is a plain function here.

A training resumes exactly: :func:`fit` can save its whole state (weights, optimiser, schedule, the
torch / numpy / Python RNGs, the batch source's generator, step, history, best weights) every N steps
and when SIGTERM or SIGINT arrives (deferred to the next step boundary, so the state is consistent),
and continue from such a state to the same weights an uninterrupted training gives.
"""

from __future__ import annotations

import contextlib
import copy
import hashlib
import json
import logging
import math
import pickle
import random
import signal
import threading
import time
import zipfile
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from pipeline.core.errors import ConfigError, Diverged, InputError
from pipeline.core.io import atomic_write, file_md5
from pipeline.core.settings import SEED_MAX, parse, rule
from pipeline.core.signals import Terminated, raise_if_terminated
from pipeline.data.hole_sets import read_hole_poses, read_hole_table
from pipeline.data.holes import HoleSampling, sample_holes
from pipeline.data.tables import POSE_COLUMNS
from pipeline.geometry.collision import SafetyDistances, SafetyModel
from pipeline.geometry.kinematics import Boom, pose_errors
from pipeline.learning.losses import (
    JOINT_METRICS,
    POSE_LOSSES,
    joint_loss,
    label_pose_loss,
    pose_loss,
    safety_terms,
    supervised_loss,
    total_loss,
)
from pipeline.learning.models import IKNet

log = logging.getLogger(__name__)

Batches = Iterator[tuple[torch.Tensor, torch.Tensor | None]]

# Bounds (conf/train/default.yaml): 15 000 steps take 4-11 min on 2 cores, so 10^7 is days; a batch and the
# held-out holes live in memory with their forward kinematics and safety terms
MAX_STEPS = 10_000_000
MAX_BATCH = 65_536
MAX_VAL = 1_000_000
PRECISIONS = ("auto", "float32", "bfloat16")
MAX_SEEDS = 100


def training_dtype(precision: str, device) -> torch.dtype | None:
    """The dtype of the hidden layers' products for ``train.precision`` on ``device`` (None: float32)."""
    if precision == "float32":
        return None
    if precision == "bfloat16":
        return torch.bfloat16
    kind = torch.device(device).type
    if kind == "cuda":
        return torch.bfloat16 if torch.cuda.is_bf16_supported() else None
    if kind == "cpu":  # emulated bf16 on other CPUs is slower than float32
        native = torch.cpu._is_avx512_bf16_supported() or torch.cpu._is_amx_tile_supported()
        return torch.bfloat16 if native else None
    return None


@dataclass(frozen=True)
class TrainSettings:
    """The ``train`` config group."""

    steps: int = field(metadata=rule(ge=1, le=MAX_STEPS))
    batch_size: int = field(metadata=rule(ge=1, le=MAX_BATCH))
    lr: float = field(metadata=rule(gt=0))
    seed: int = field(default=0, metadata=rule(ge=0, le=SEED_MAX))
    seeds: int = field(default=3, metadata=rule(ge=1, le=MAX_SEEDS))  # trainings per method: seed, seed + 1, ...
    fresh_holes: bool = True
    eval_every: int = field(default=250, metadata=rule(ge=1, le=MAX_STEPS))
    val_size: int = field(default=1000, metadata=rule(ge=1, le=MAX_VAL))
    val_seed: int = field(default=999, metadata=rule(ge=0, le=SEED_MAX))
    grad_clip: float | None = field(default=None, metadata=rule(gt=0))
    method_key: str = "method"
    keep_best: bool = True  # end with the weights of the best held-out evaluation, not the last step's
    # the hidden layers' products while training (IKNet.unit_joints): auto is bfloat16 where the device has it
    # natively (a CPU with AVX-512 BF16 or AMX, a CUDA GPU with bf16), else float32; evaluation is float32 always
    precision: str = field(default="auto", metadata=rule(choices=PRECISIONS))

    @classmethod
    def from_config(cls, node: Mapping) -> TrainSettings:
        return parse(cls, node, "train")


@dataclass(frozen=True)
class Objective:
    """What a method minimises: eq. 6 when supervised (plus ``mu`` times the four safety penalties
    of eq. 16 when ``mu > 0``: labels say where the joints go, the penalties need none), else
    eq. 16 (eq. 7 when ``mu == 0``)."""

    supervised: bool
    lam: float = 1.0
    mu: float = 0.0
    pose_loss: str = "mse"
    joint_metric: str = "range"  # supervised: how a joint error is measured (JOINT_METRICS)


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
    # supervised methods: range (eq. 6, each joint over its range) or pose (eq. 6 plus the joint error
    # measured by what it does to the hole pose at the label, to first order; see supervised_loss)
    joint_metric: str = field(default="range", metadata=rule(choices=JOINT_METRICS))
    # at most this many training steps for this method (null: train.steps): a method whose best held-out
    # weights come early (SIKM on sampled labels overfits) need not pay the others' budget
    max_steps: int | None = field(default=None, metadata=rule(ge=1, le=MAX_STEPS))

    @classmethod
    def from_config(cls, node: Mapping, where: str = "method") -> MethodSettings:
        settings = parse(cls, node, where)
        SafetyDistances.from_config(dict(settings.train_safety))  # checked now, not after loading data
        return settings

    def steps(self, budget: int) -> int:
        """This method's training steps under the study's ``train.steps`` budget."""
        return budget if self.max_steps is None else min(budget, self.max_steps)

    @property
    def objective(self) -> Objective:
        return Objective(self.supervised, self.lam, self.mu, self.pose_loss, self.joint_metric)


def loss_terms(
    model: IKNet,
    boom: Boom,
    safety: SafetyModel,
    objective: Objective,
    pose: torch.Tensor,
    q_target: torch.Tensor | None = None,
    logged: bool = True,
    hidden_dtype: torch.dtype | None = None,
) -> dict[str, torch.Tensor]:
    """Every loss term of a batch; ``loss`` is the one optimised, the rest are for logging.

    ``logged=False``: only the terms ``loss`` is made of. :func:`fit` logs the terms of its evaluation
    steps alone, so the steps between skip the others: the supervised rows' forward kinematics and
    clearances, UIKM's clearances (``mu = 0``). The loss and its gradients are the same to the bit
    (tests/test_train_evaluate.py), and a supervised step is about a tenth cheaper."""
    unit = model.unit_joints(pose, hidden_dtype)
    q = model.lower + model.span * unit
    terms: dict[str, torch.Tensor] = {}
    pos_needed, safety_needed = logged or not objective.supervised, logged or objective.mu > 0
    if pos_needed or safety_needed:
        frames = boom.frames(q)
        if pos_needed:
            terms["l_pos"] = pose_loss(boom.pose6_from_frames(frames), pose, objective.pose_loss)
        if safety_needed:
            with torch.set_grad_enabled(torch.is_grad_enabled() and objective.mu > 0):
                terms.update(safety_terms(safety.penalties(safety.clearances_from_frames(frames))))
    if objective.supervised:
        if q_target is None:
            raise ValueError("a supervised objective needs joint targets")
        terms["l_joint"] = joint_loss(unit, (q_target - model.lower) / model.span)
        if objective.joint_metric == "pose":
            terms["l_joint_pose"] = label_pose_loss(boom, q, q_target.to(q), objective.pose_loss)
        terms["loss"] = supervised_loss(terms, objective.mu)
    else:
        terms["loss"] = total_loss(terms, objective.lam, objective.mu)
    return terms


# ---------------------------------------------------------------------------------------- data
class _SeededBatches:
    """An endless batch iterator driven by one CPU generator, whose state a checkpoint keeps."""

    def __init__(self, seed: int):
        self.gen = torch.Generator().manual_seed(seed)

    def __iter__(self):
        return self

    def state(self) -> torch.Tensor:
        return self.gen.get_state()

    def load_state(self, state: torch.Tensor) -> None:
        self.gen.set_state(state)


class DatasetBatches(_SeededBatches):
    """Random minibatches from a fixed set (Table 1: "select batch size group data at random")."""

    def __init__(self, pose: torch.Tensor, q: torch.Tensor | None, batch: int, seed: int):
        super().__init__(seed)
        self.pose, self.q, self.batch = pose, q, batch

    def __next__(self):
        idx = torch.randint(len(self.pose), (self.batch,), generator=self.gen).to(self.pose.device)
        return self.pose[idx], (None if self.q is None else self.q[idx])


class FreshHoleBatches(_SeededBatches):
    """A new set of drillable holes every step, drawn like Omega_unsup."""

    def __init__(self, safety: SafetyModel, sampling: HoleSampling, batch: int, seed: int, device,
                 dtype=torch.float32):
        super().__init__(seed)
        self.safety, self.sampling, self.batch, self.device, self.dtype = safety, sampling, batch, device, dtype

    def __next__(self):
        pose, _ = sample_holes(self.batch, self.safety, self.sampling, self.gen)
        return pose.to(device=self.device, dtype=self.dtype), None


def dataset_batches(pose: torch.Tensor, q: torch.Tensor | None, batch: int, seed: int) -> DatasetBatches:
    return DatasetBatches(pose, q, batch, seed)


def fresh_hole_batches(safety: SafetyModel, sampling: HoleSampling, batch: int, seed: int, device,
                       dtype=torch.float32) -> FreshHoleBatches:
    return FreshHoleBatches(safety, sampling, batch, seed, device, dtype)


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


@dataclass
class Checkpoints:
    """How :func:`fit` saves its state: ``save(state)`` every ``every`` steps (0: never on a schedule)
    and at a SIGTERM / SIGINT; ``resume``: a state saved by an earlier run of this same training."""

    save: Callable[[dict], None]
    every: int = 0
    resume: dict | None = None


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
    checkpoints: Checkpoints | None = None,
    hidden_dtype: torch.dtype | None = None,
    fused_adam: bool = True,
) -> list[dict[str, float]]:
    """Adam with the linearly annealed learning rate of eq. 8; returns the logged history.

    ``on_eval(step, record, elapsed_s)`` runs at every held-out evaluation (live MLflow curves). A
    non-finite loss stops training at once with the step named: a NaN model must never be saved.
    ``keep_best``: the model ends with the weights of its best held-out hole-seeking error (early
    stopping on held-out holes, never on the test groups); the history marks that step.
    ``checkpoints``: save the state on a schedule and on SIGTERM / SIGINT (then raise as the signal
    would), and start from ``checkpoints.resume`` if given; ``batches`` must then have ``state()`` and
    ``load_state()`` (the batch sources of this module do). ``hidden_dtype``: the hidden layers' products
    in that dtype while training (:func:`training_dtype`); the held-out evaluations stay float32. ``fused_adam``:
    Adam's update as one kernel (CPU and CUDA; the same arithmetic as its loop over tensors, in fewer passes)."""
    fused = fused_adam and next(model.parameters()).device.type in ("cpu", "cuda")
    opt = torch.optim.Adam(model.parameters(), lr=lr, fused=fused)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda t: max(0.0, 1.0 - t / steps))
    history: list[dict[str, float]] = []
    best = {"mm": math.inf, "step": None, "state": None}
    start, elapsed0 = 0, 0.0
    if checkpoints is not None and checkpoints.resume is not None:
        start, elapsed0, history, best = restore_state(checkpoints.resume, model, opt, sched, batches, steps)
    bar = tqdm(range(start, steps), initial=start, total=steps, disable=not progress,
               desc=f"train {'sup' if objective.supervised else 'unsup'}")
    model.train()
    t0 = time.perf_counter() - elapsed0

    def snapshot(next_step: int) -> dict:
        return training_state(next_step, steps, model, opt, sched, batches, history, best, time.perf_counter() - t0)

    with _deferred_signals() as caught:
        for step in bar:
            if caught:  # a signal during the previous step: the state is consistent again here
                _stop(caught, checkpoints, snapshot(step))
            raise_if_terminated()  # SIGTERM stops training at a step boundary even if its exception was swallowed
            pose, q = next(batches)
            logged = step % eval_every == 0 or step == steps - 1
            terms = loss_terms(model, boom, safety, objective, pose, q, logged=logged, hidden_dtype=hidden_dtype)
            if not torch.isfinite(terms["loss"]):
                raise Diverged(f"training diverged: loss = {float(terms['loss'].detach())} at step {step} "
                               f"(terms {_finite_report(terms)}); check the data and train.lr = {lr}")
            opt.zero_grad(set_to_none=True)
            terms["loss"].backward()
            if grad_clip:
                torch.nn.utils.clip_grad_norm_(model.parameters(), grad_clip)
            opt.step()
            sched.step()
            if logged:
                model.eval()
                record = {"lr": sched.get_last_lr()[0], **{k: float(v.detach()) for k, v in terms.items()}}
                record.update(pose_metrics(model, boom, val_pose))
                model.train()
                elapsed = time.perf_counter() - t0
                history.append({"step": step, "elapsed_s": elapsed, **record})
                if keep_best and record["val_hole_mm"] < best["mm"]:
                    best["mm"], best["step"] = record["val_hole_mm"], step
                    best["state"] = {k: v.detach().clone() for k, v in model.state_dict().items()}
                bar.set_postfix(loss=f"{record['loss']:.3g}", hole_mm=f"{record['val_hole_mm']:.2f}")
                if on_eval is not None:
                    on_eval(step, record, elapsed)
            due = checkpoints is not None and checkpoints.every and (step + 1) % checkpoints.every == 0
            if due and step + 1 < steps:
                checkpoints.save(snapshot(step + 1))
        if caught:  # a signal during the last step: the training is complete, save it as such and stop
            _stop(caught, checkpoints, snapshot(steps))
    if best["state"] is not None:
        model.load_state_dict(best["state"])
        for rec in history:
            rec["kept"] = int(rec["step"] == best["step"])
    model.eval()
    return history


def _stop(caught: list[int], checkpoints: Checkpoints | None, state: dict) -> None:
    """Save the state (if checkpointing) and stop as the first caught signal would have."""
    if checkpoints is not None:
        checkpoints.save(state)
        log.warning("training stopped by %s at step %d; its checkpoint resumes it (runtime.resume=true)",
                    signal.Signals(caught[0]).name, state["step"])
    if caught[0] == signal.SIGINT:
        raise KeyboardInterrupt("interrupted (SIGINT / Ctrl-C)")
    raise Terminated(caught[0])


@contextlib.contextmanager
def _deferred_signals() -> Iterator[list[int]]:
    """While inside, SIGTERM and SIGINT are noted (the yielded list) instead of raising mid-step, so the
    loop can save a consistent state first; a second signal raises at once (a user who insists)."""
    caught: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield caught
        return

    def handler(signum, _frame):
        if caught:
            raise KeyboardInterrupt("interrupted twice") if signum == signal.SIGINT else Terminated(signum)
        caught.append(signum)

    old = {s: signal.signal(s, handler) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        yield caught
    finally:
        for s, h in old.items():
            signal.signal(s, h)


# ---------------------------------------------------------------------------------------- resume
STATE_VERSION = 1


def rng_states() -> dict:
    """The torch (CPU and CUDA), numpy and Python generators' states, as tensors and plain lists
    (a checkpoint must load with ``weights_only=True``)."""
    kind, keys, pos, has_gauss, cached = np.random.get_state()
    version, internal, gauss = random.getstate()
    cuda = torch.cuda.get_rng_state_all() if torch.cuda.is_available() and torch.cuda.is_initialized() else []
    return {"torch": torch.get_rng_state(), "cuda": cuda,
            "numpy": {"kind": kind, "keys": torch.from_numpy(keys.astype(np.int64)), "pos": int(pos),
                      "has_gauss": int(has_gauss), "cached": float(cached)},
            "python": [version, list(internal), gauss]}


def set_rng_states(rng: Mapping) -> None:
    torch.set_rng_state(rng["torch"])
    if rng["cuda"] and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(rng["cuda"])
    n = rng["numpy"]
    np.random.set_state((n["kind"], n["keys"].numpy().astype(np.uint32), n["pos"], n["has_gauss"], n["cached"]))
    version, internal, gauss = rng["python"]
    random.setstate((version, tuple(internal), gauss))


def training_state(next_step: int, steps: int, model: IKNet, opt, sched, batches, history: list[dict],
                   best: dict, elapsed_s: float) -> dict:
    """Everything :func:`fit` needs to continue at ``next_step`` as if it had never stopped."""
    if not hasattr(batches, "state"):
        raise TypeError("checkpointing needs a batch source with state() / load_state() (dataset_batches, "
                        "fresh_hole_batches)")
    return {
        "version": STATE_VERSION, "step": next_step, "steps": steps, "elapsed_s": elapsed_s,
        "model": {k: v.detach().cpu().clone() for k, v in model.state_dict().items()},
        # copies: Adam updates its moment tensors in place, and a state must not change after it is taken
        "optimizer": copy.deepcopy(opt.state_dict()), "scheduler": copy.deepcopy(sched.state_dict()),
        "rng": rng_states(),
        "batches": batches.state(), "history": [dict(rec) for rec in history],
        "best": {"mm": best["mm"], "step": best["step"],
                 "state": None if best["state"] is None else {k: v.cpu() for k, v in best["state"].items()}},
    }


def restore_state(state: Mapping, model: IKNet, opt, sched, batches, steps: int):
    """Load a :func:`training_state` into the live objects; returns (step, elapsed_s, history, best)."""
    if state.get("version") != STATE_VERSION or state.get("steps") != steps:
        raise InputError(f"resume state of another training (version {state.get('version')}, "
                         f"{state.get('steps')} steps; this one: version {STATE_VERSION}, {steps} steps)")
    device = next(model.parameters()).device
    model.load_state_dict(state["model"])
    opt.load_state_dict(state["optimizer"])
    sched.load_state_dict(state["scheduler"])
    batches.load_state(state["batches"])
    set_rng_states(state["rng"])
    best = dict(state["best"])
    if best["state"] is not None:
        best["state"] = {k: v.to(device) for k, v in best["state"].items()}
    return int(state["step"]), float(state["elapsed_s"]), [dict(r) for r in state["history"]], best


def training_digest(config: Mapping, files: Iterable[Path], code_root: Path | None = None) -> str:
    """What makes two trainings the same: the settings they read, the MD5s of the files they read (as
    DVC records them) and the pipeline's source code; a checkpoint resumes only a training with its digest."""
    h = hashlib.sha256(json.dumps(config, sort_keys=True, default=str).encode())
    for f in sorted(Path(p) for p in files):
        h.update(f"{f.name}:{file_md5(f)}".encode())
    root = code_root or Path(__file__).resolve().parents[1]
    for f in sorted(root.rglob("*.py")):
        h.update(f"{f.relative_to(root)}:{file_md5(f)}".encode())
    return h.hexdigest()


def save_training_state(path: Path, state: dict, digest: str, extra: Mapping | None = None) -> None:
    atomic_write(path, lambda tmp: torch.save({**state, "digest": digest, **dict(extra or {})}, tmp))


def load_training_state(path: Path, digest: str) -> dict | None:
    """The saved state at ``path`` if it belongs to the training with ``digest``; else None (with why)."""
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except FileNotFoundError:
        return None
    except (pickle.UnpicklingError, EOFError, OSError, RuntimeError, zipfile.BadZipFile, ValueError) as exc:
        log.warning("%s: not a readable resume checkpoint (%s); training from the start", path, exc)
        return None
    if not isinstance(state, dict) or state.get("digest") != digest:
        log.warning("%s: a checkpoint of another config, data or code; training from the start", path)
        return None
    return state


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
