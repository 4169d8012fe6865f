"""The round's problem on disk (``<stem>_problem.npz``): what a round was planned on, for ``execute``.

A round interrupted on the rig is planned again from where the booms stand, over the same holes and the
same joint solutions (:mod:`pipeline.events.interrupt`). Those solutions cost the reach table's IK solve
(the network, then the hybrid solver, per boom), and solving again could land on other postures than
the planned round drilled. So the schedule stage writes the problem beside the round and the execute
stage loads it: no network, no IK, the planned postures exactly.

The file is a numpy ``.npz`` read with ``allow_pickle=False`` (no code runs on load), its arrays:

- ``booms (B,)`` and ``hole_ids (H,)``: text, the rig's booms and the plan's holes, in order;
- ``joint_names (n,)``: text, the boom's joints;
- ``reach (B, H)`` bool: boom b drills hole h ok (the reach table's status);
- ``joints (B, H, n)`` float64: each boom's solution of each hole, in its own base frame and SI units;
  a hole of the round at the joints the round drills it with (the posture it chose), NaN where the
  boom has no solution;
- ``reasons (H,)``: text, why no boom can drill a hole ("" where some boom can).

:func:`load_problem` refuses, naming the file and the key, a file that is not such an archive, misses
a key, has another shape or type, or was planned for other booms, holes or joints.
"""

from __future__ import annotations

import zipfile
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.core.errors import InputError

VERSION = 1
KEYS = ("version", "booms", "hole_ids", "joint_names", "reach", "joints", "reasons")


@dataclass(frozen=True)
class RoundProblem:
    booms: tuple[str, ...]
    hole_ids: tuple[str, ...]
    joint_names: tuple[str, ...]
    reach: np.ndarray  # (B, H) bool
    joints: np.ndarray  # (B, H, n) float64
    reasons: tuple[str, ...]


def save_problem(problem: RoundProblem, path) -> None:
    """Write ``problem`` to ``path`` (.npz, compressed, no object arrays)."""
    with open(path, "wb") as f:
        np.savez_compressed(f, version=np.int64(VERSION), booms=np.array(problem.booms, dtype=str),
                            hole_ids=np.array(problem.hole_ids, dtype=str),
                            joint_names=np.array(problem.joint_names, dtype=str),
                            reach=np.asarray(problem.reach, bool), joints=np.asarray(problem.joints, np.float64),
                            reasons=np.array(problem.reasons, dtype=str))


def load_problem(path: str | Path, booms: Sequence[str], hole_ids: Sequence[str],
                 joint_names: Sequence[str]) -> RoundProblem:
    """The problem in ``path``, checked against the rig's ``booms``, the plan's ``hole_ids`` and the boom's
    ``joint_names``; :class:`InputError` naming the file and what differs otherwise."""
    path = Path(path)

    def bad(why: str) -> InputError:
        return InputError(f"{path}: {why}; not the problem this round was planned on (re-run schedule)")

    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in KEYS if k not in z.files]
            if missing:
                raise bad(f"no {missing[0]!r} array")
            a = {k: z[k] for k in KEYS}
    except InputError:
        raise
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as e:
        raise InputError(f"{path}: cannot read it as a round problem ({' '.join(str(e).split())}); "
                         "re-run schedule") from None
    if a["version"].shape != () or int(a["version"]) != VERSION:
        raise bad(f"version {a['version']!r}, this stage reads version {VERSION}")
    for key in ("booms", "hole_ids", "joint_names", "reasons"):
        if a[key].ndim != 1 or a[key].dtype.kind != "U":
            raise bad(f"{key!r} is not a list of names")
    for key, want in (("booms", booms), ("hole_ids", hole_ids), ("joint_names", joint_names)):
        got = a[key].tolist()
        if got != [str(x) for x in want]:
            raise bad(f"{key!r} {got[:6]}{'...' if len(got) > 6 else ''} differs from this run's "
                      f"{list(want)[:6]}{'...' if len(want) > 6 else ''}")
    B, H, n = len(booms), len(hole_ids), len(joint_names)
    if a["reach"].dtype != bool or a["reach"].shape != (B, H):
        raise bad(f"'reach' is {a['reach'].dtype} {a['reach'].shape}, expected bool ({B}, {H})")
    if a["joints"].dtype != np.float64 or a["joints"].shape != (B, H, n):
        raise bad(f"'joints' is {a['joints'].dtype} {a['joints'].shape}, expected float64 ({B}, {H}, {n})")
    if a["reasons"].shape != (H,):
        raise bad(f"'reasons' has {a['reasons'].shape[0]} entries for {H} holes")
    unsolved = a["reach"] & ~np.isfinite(a["joints"]).all(axis=-1)
    if unsolved.any():
        b, h = np.argwhere(unsolved)[0]
        raise bad(f"boom {booms[b]} drills hole {hole_ids[h]} ok but has no finite joints for it")
    return RoundProblem(tuple(booms), tuple(map(str, hole_ids)), tuple(joint_names), a["reach"], a["joints"],
                        tuple(a["reasons"].tolist()))
