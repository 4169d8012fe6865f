"""The hole-set folder (``paths.data/holes``): built together, swapped in whole, verified on read.

``meta.json`` records the MD5 of every table (the hash DVC records too). Readers check a table
against it, so a folder mixing files of two ``generate`` runs, or a file edited by hand, is
refused with a message that says how to rebuild it, instead of training on it silently.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd
import torch

from pipeline.core.errors import ConfigError, InputError
from pipeline.core.io import file_md5, write_json, write_parquet
from pipeline.core.settings import SEED_MAX, rule
from pipeline.data.consistency import label_consistency
from pipeline.data.couplings import parse_couplings, sample_coupled_joints
from pipeline.data.holes import HoleSampling, in_face_window, sample_holes, sample_joints
from pipeline.data.tables import POSE_COLUMNS, check_table, holes_frame, joints_frame
from pipeline.geometry.collision import SAFETY_KINDS, SafetyModel

LABELS = ("sampled", "home_branch", "continuation", "continuation_clear", "continuation_rescue")
REBUILD = "rebuild it with `python -m pipeline.generate` (or `dvc repro generate`)"
# Bounds (conf/holes/default.yaml): ten times the largest set the study draws (100 000); a labelled set's holes are
# each solved by LM, so a larger one only runs for hours
MAX_SET = 1_000_000
MAX_TEST_GROUPS = 100
MAX_LABEL_ITERS = 10_000


@dataclass(frozen=True)
class SupervisedSet:
    """One Omega_sup table of ``size`` samples drawn with ``seed``.

    ``poses``: ``box`` (paper 000: joint vectors uniform in the working box, poses by forward
    kinematics) or ``holes`` (hole poses drawn like Omega_unsup, which then need a solver's labels);
    ``labels``: ``sampled`` (the drawn joints, paper 000), ``home_branch`` (each pose's solution
    that a descent from the home pose reaches), ``continuation`` (each pose solved from a solved
    neighbour, :mod:`pipeline.solvers.continuation`), ``continuation_clear`` (the same with
    solutions that keep every safety distance) or ``continuation_rescue`` (the poses the walk misses
    solved by the full hybrid from their nearest labelled neighbour, and walked on from);
    ``label_iters``: the labelling solver's Levenberg-Marquardt iterations per refinement (null: the
    local search's own budget, 12); a descent that meets a joint limit (the boom extension, high in
    the arch) needs more to slide along the redundancy, and a pose left unsolved is left out;
    ``window``: keep only face-like samples (mismatch study); ``couplings``: draw the joints on these linear couplings
    (:mod:`pipeline.data.couplings`, e.g. paper 000's pair, which leaves 6 free joints), not over
    the whole box."""

    size: int = field(metadata=rule(ge=1, le=MAX_SET))
    seed: int = field(metadata=rule(ge=0, le=SEED_MAX))
    labels: str = field(default="sampled", metadata=rule(choices=LABELS))
    window: bool = False
    couplings: list | None = None
    poses: str = field(default="box", metadata=rule(choices=("box", "holes")))
    label_iters: int | None = field(default=None, metadata=rule(ge=1, le=MAX_LABEL_ITERS))

    def __post_init__(self):
        if self.poses == "holes" and (self.labels == "sampled" or self.window or self.couplings is not None):
            raise ConfigError(f"Omega_sup with poses = 'holes' draws no joints: it needs labels from a solver "
                              f"({[x for x in LABELS if x != 'sampled']}), not labels = '{self.labels}', and takes "
                              "neither window nor couplings")


# poses (n, 6), iteration budget (None: the solver's own) -> joints, exact (n,)
Labeller = Callable[[torch.Tensor, int | None], tuple[torch.Tensor, torch.Tensor]]


def supervised_table(safety: SafetyModel, spec: SupervisedSet, box: Mapping | None,
                     labellers: Mapping[str, Labeller], sampling: HoleSampling | None = None
                     ) -> tuple[pd.DataFrame, dict]:
    """Joints and their poses (by forward kinematics), and the set's statistics for ``meta.json``.
    ``labellers``: the solvers of the label kinds other than ``sampled``, by name; ``sampling``:
    how hole poses are drawn (``poses = 'holes'``)."""
    boom = safety.boom
    if spec.labels != "sampled" and spec.labels not in labellers:
        raise ConfigError(f"Omega_sup labels = '{spec.labels}' need a labelling solver; given: {sorted(labellers)}")
    relabelled = None
    if spec.poses == "holes":
        if sampling is None:
            raise ConfigError("Omega_sup with poses = 'holes' needs the hole sampling")
        target, _ = sample_holes(spec.size, safety, sampling, spec.seed)
        q, exact = labellers[spec.labels](target, spec.label_iters)
        q, relabelled = q[exact], float(exact.double().mean())  # a hole the solver misses has no label: left out
    else:
        draw = joint_sampler(boom, box, spec.couplings)
        q = sample_joints_in_window(spec.size, safety, spec.seed, draw) if spec.window else draw(spec.size, spec.seed)
        if spec.labels != "sampled":  # same poses, other (branch-consistent) joints where the solver is exact
            found, exact = labellers[spec.labels](boom.pose6(q), spec.label_iters)
            q, relabelled = torch.where(exact[:, None], found, q), float(exact.double().mean())
    frames = boom.frames(q)
    pose = boom.pose6_from_frames(frames)
    df = pd.concat([joints_frame(q, boom.joint_names), holes_frame(pose)], axis=1)
    violated = safety.violations(safety.clearances_from_frames(frames))
    any_violation = torch.stack([violated[k] for k in SAFETY_KINDS]).any(dim=0)
    stats = {
        "size": len(q), "seed": spec.seed, "poses": spec.poses, "labels": spec.labels, "window": spec.window,
        "label_iters": spec.label_iters,
        "face_window_share": float(in_face_window(pose, safety.tunnel).double().mean()),
        "relabelled_share": relabelled,  # poses = holes: the share of holes labelled (the others left out)
        "couplings": None if spec.couplings is None else [dict(row) for row in spec.couplings],
        "consistency": set_consistency(boom, pose, q),
        "violation_share": {**{k: float(violated[k].double().mean()) for k in SAFETY_KINDS},
                            "any": float(any_violation.double().mean())},
    }
    return df[["hole_id", *boom.joint_names, *POSE_COLUMNS]], stats


def build_hole_sets(
    safety: SafetyModel,
    sampling: HoleSampling,
    unsup_size: int,
    unsup_seed: int,
    test_size: int,
    test_seeds: list[int],
    sup_sets: Mapping[str, SupervisedSet],
    sup_box: Mapping | None = None,
    labellers: Mapping[str, Labeller] | None = None,
) -> tuple[dict[str, pd.DataFrame], dict]:
    """All hole tables by file name, and the statistics that go into ``meta.json``: Omega_unsup,
    the test groups, and one Omega_sup table per entry of ``sup_sets`` (``sup`` is paper 000's),
    drawn in ``sup_box`` (the working box; None: the full mechanical ranges) and labelled by
    ``labellers`` (by label kind) where a set asks for a solver's labels."""
    seeds = [unsup_seed, *(spec.seed for spec in sup_sets.values()), *test_seeds]
    if len(set(seeds)) != len(seeds):
        raise ConfigError(f"holes: seeds must all differ (unsup, sup sets, test...), got {seeds}")
    tables: dict[str, pd.DataFrame] = {}
    train, train_stats = sample_holes(unsup_size, safety, sampling, unsup_seed)
    tables["train.parquet"] = holes_frame(train)
    test_stats = []
    for k, seed in enumerate(test_seeds, start=1):
        poses, stats = sample_holes(test_size, safety, sampling, seed)
        tables[f"test_group_{k}.parquet"] = holes_frame(poses)
        test_stats.append(stats)
    sup_stats = {}
    for name, spec in sup_sets.items():
        tables[f"{name}.parquet"], sup_stats[name] = supervised_table(safety, spec, sup_box, labellers or {}, sampling)
    meta = {
        "counts": {name: len(df) for name, df in tables.items()},
        "seeds": {"unsup": unsup_seed, "sup": {n: spec.seed for n, spec in sup_sets.items()}, "test": list(test_seeds)},
        "unsup_rejection": train_stats,
        "test_rejection": test_stats,
        "sup_box": None if sup_box is None else {k: list(v) for k, v in sup_box.items()},
        "sup_sets": sup_stats,
    }
    return tables, meta


JointSampler = Callable[[int, int], torch.Tensor]  # (n, seed) -> joints (n, n_joints)


def joint_sampler(boom, box: Mapping | None, couplings: list | None,
                  where: str = "holes.sup.couplings") -> JointSampler:
    """Draws joints uniformly in ``box``, on ``couplings`` where given (checked now, before any draw)."""
    if couplings is None:
        return lambda n, seed: sample_joints(n, boom, seed, box)
    rows = parse_couplings(couplings, boom.joint_names, where)
    return lambda n, seed: sample_coupled_joints(n, boom, seed, box, rows)


def set_consistency(boom, pose: torch.Tensor, q: torch.Tensor) -> dict[str, float]:
    """:func:`pipeline.data.consistency.label_consistency` of a supervised set, joints scaled by their
    mechanical ranges (as SIKM's loss scales them; a locked joint, of zero range, by 1)."""
    lo, hi = boom.limits(q.dtype)
    span = hi - lo
    return label_consistency(pose, q, torch.where(span > 0, span, torch.ones_like(span)), boom.pose6)


def sample_joints_in_window(n: int, safety: SafetyModel, seed: int, draw: JointSampler) -> torch.Tensor:
    """``n`` joint vectors from ``draw`` whose poses lie in the face window (rejection, in batches)."""
    gen_seed, kept, have = seed, [], 0
    for _ in range(1000):
        q = draw(max(4 * (n - have), 1024), gen_seed)
        q = q[in_face_window(safety.boom.pose6(q), safety.tunnel)]
        kept.append(q)
        have += len(q)
        gen_seed += 1_000_003  # the next batch: another stream, deterministic
        if have >= n:
            return torch.cat(kept)[:n]
    raise ConfigError(f"holes.sup.window: fewer than {n} face-like samples in 1000 batches; widen the box")


def write_hole_sets(tables: dict[str, pd.DataFrame], meta: dict, out_dir: Path) -> list[Path]:
    """Write every table and ``meta.json`` (with each table's MD5) into a fresh folder beside
    ``out_dir``, then swap it in: a reader sees the old set, the new set, or (killed between the
    two renames) no set, never a mix."""
    out_dir = Path(out_dir)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.new-", dir=out_dir.parent))
    try:
        for name, df in tables.items():
            write_parquet(df, staging / name)
        meta = {**meta, "files": {name: file_md5(staging / name) for name in tables}}
        write_json(meta, staging / "meta.json")
        os.chmod(staging, 0o777 & ~_umask())  # mkdtemp makes 0700
        old = None
        if out_dir.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.old-", dir=out_dir.parent))
            os.replace(out_dir, old / out_dir.name)
        os.replace(staging, out_dir)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return [*(out_dir / name for name in tables), out_dir / "meta.json"]


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def read_meta(holes_dir: Path) -> dict:
    path = Path(holes_dir) / "meta.json"
    if not path.is_file():
        raise InputError(f"{path}: missing, so the hole set cannot be verified; {REBUILD}")
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not valid JSON ({exc}); {REBUILD}") from None


def read_hole_table(holes_dir: Path, name: str, columns: list[str] | None = None) -> pd.DataFrame:
    """Table ``name`` of a hole set, checked against ``meta.json`` and for finite values in
    ``columns`` (the pose columns by default, joint columns too where asked)."""
    holes_dir = Path(holes_dir)
    path = holes_dir / name
    if not path.is_file():
        raise InputError(f"{path}: no such hole table; {REBUILD}")
    expected = read_meta(holes_dir).get("files", {}).get(name)
    if expected is None:
        raise InputError(f"{path}: not listed in {holes_dir / 'meta.json'} (written by an older generate); {REBUILD}")
    actual = file_md5(path)
    if actual != expected:
        raise InputError(f"{path}: MD5 {actual} differs from {expected} in meta.json: the folder mixes files of "
                         f"two generate runs or was edited; {REBUILD}")
    df = pd.read_parquet(path)
    check_table(df, columns or POSE_COLUMNS, str(path))
    return df


def read_hole_poses(holes_dir: Path, name: str) -> tuple[pd.DataFrame, torch.Tensor]:
    """A verified hole table and its ``(n, 6)`` float64 poses."""
    df = read_hole_table(holes_dir, name)
    return df, torch.tensor(df[POSE_COLUMNS].to_numpy(dtype="float64"))


def read_test_groups(holes_dir: Path) -> dict[int, tuple[pd.DataFrame, torch.Tensor]]:
    """Every ``test_group_<k>.parquet`` listed in ``meta.json``, by k."""
    names = sorted((n for n in read_meta(holes_dir).get("files", {}) if n.startswith("test_group_")),
                   key=lambda n: int(n.removesuffix(".parquet").rsplit("_", 1)[1]))
    if not names:
        raise InputError(f"{holes_dir}: no test groups listed in meta.json; {REBUILD}")
    return {int(n.removesuffix(".parquet").rsplit("_", 1)[1]): read_hole_poses(holes_dir, n) for n in names}
