"""The planner's move book on disk (``<stem>_moves.npz``): what a round that is handed on re-uses.

Planning a round certifies every move it looks at and plans detours (OMPL) for those that are not
clear straight: most of the planning time. A round interrupted on the rig is re-planned from where
the booms stand (:mod:`pipeline.events.interrupt`) over the same holes and joint solutions, so the
schedule stage writes its :class:`pipeline.round.detours.MoveBook` with the round and the execute stage
reads it back: only moves never looked at are certified or planned again.

The file is a numpy ``.npz`` read with ``allow_pickle=False`` (no code runs on load): each boom's
joint solutions (the book is valid only for them), the status and certified floors of every move,
the detours' waypoints and the reasons, the certified sweep results of the round's action pairs (the
interlocks' conflicts, :mod:`pipeline.events.conflicts`: the hand-on's new plan shares most of its
actions with the planned round), and the settings all of it was made under (sample spacing,
refinements, margins, the oracle's margin and d_boom, detour settings). :func:`load_book` refuses,
with the reason, a file whose joints or settings differ from the caller's: a certificate for another
margin is no certificate.
"""

from __future__ import annotations

import json
import zipfile
import zlib
from pathlib import Path as FilePath

import numpy as np
import torch

from pipeline.core.errors import InputError
from pipeline.motion.path import Path
from pipeline.round.detours import KINDS, MoveBook
from pipeline.round.settings import RoundSettings

VERSION = 1


def _meta(book: MoveBook) -> dict:
    p = book.planner
    rig = book.oracle.rig
    d_boom = [float(rig.pair(a, b).d_boom) for a in range(len(rig)) for b in range(a + 1, len(rig))]
    return {"version": VERSION, "resolution": book.resolution, "refinements": book.refinements,
            "oracle": {"sample_m": float(book.oracle.sample_m), "margin": float(book.oracle.margin), "d_boom": d_boom},
            "tolerance": book.tolerance, "margin": {k: float(v) for k, v in book.margin.items()},
            "detours": bool(book.detours),
            "planner": {"iterations": p.iterations, "simplify_steps": p.simplify_steps, "seed": p.seed,
                        "box_margin": p.box_margin, "time_s": p.time_s}}


def save_book(book: MoveBook, path) -> None:
    """Write ``book`` (its oracle's joints, statuses, floors, detours, reasons) to ``path`` (.npz)."""
    joints = np.stack([q.numpy() for q in book.oracle.joints])
    keys, lengths, points = [], [], []
    for b, paths in enumerate(book.oracle.detours):
        for (u, v), p in sorted(paths.items()):
            keys.append((b, u, v))
            w = p.waypoints.detach().cpu().numpy()
            lengths.append(len(w))
            points.append(w)
    rk = sorted(book.reason)
    n = joints.shape[-1]
    pk = sorted(book.oracle.sweep_pairs)  # certified sweep results of action pairs (events/conflicts.py)
    pair_key = np.asarray([[int(x) for x in ka + kb] for ka, kb in pk], np.int64).reshape(-1, 10)
    pair_val = np.asarray([book.oracle.sweep_pairs[k] for k in pk], float).reshape(-1, 2)
    with open(path, "wb") as f:
        np.savez_compressed(
            f, meta=np.array(json.dumps(_meta(book))), joints=joints, status=book.status,
            **{f"floor_{k}": book.floor[k] for k in KINDS},
            detour_key=np.asarray(keys, np.int64).reshape(-1, 3), detour_len=np.asarray(lengths, np.int64),
            detour_points=np.concatenate(points) if points else np.zeros((0, n)),
            duration_key=np.asarray(sorted(book.durations), np.int64).reshape(-1, 3),
            duration_s=np.asarray([book.durations[k] for k in sorted(book.durations)], float),
            reason_key=np.asarray(rk, np.int64).reshape(-1, 3), reason_text=np.asarray([book.reason[k] for k in rk],
                                                                                      dtype=str),
            pair_key=pair_key, pair_value=pair_val)


def _check_arrays(path, data: dict, book: MoveBook, joints_n: int) -> None:
    """Every array :func:`save_book` writes is there with its shape; else an :class:`InputError` naming the file
    and the array (a malformed book is refused, never a traceback)."""
    def bad(name, why):
        raise InputError(f"{path}: {name}: {why}; not a move book this execute stage can read (re-run schedule)")

    for name in ("meta", "joints", "status", *(f"floor_{k}" for k in KINDS), "detour_key", "detour_len",
                 "detour_points", "duration_key", "duration_s", "reason_key", "reason_text"):
        if name not in data:
            bad(name, "missing")
    if data["meta"].shape != ():
        bad("meta", f"shape {data['meta'].shape}, expected one text")
    for k in KINDS:
        if data[f"floor_{k}"].shape != book.floor[k].shape or data[f"floor_{k}"].dtype.kind != "f":
            bad(f"floor_{k}", f"shape {data[f'floor_{k}'].shape} ({data[f'floor_{k}'].dtype}), expected "
                              f"{book.floor[k].shape} floats")
    for name, cols in (("detour_key", 3), ("duration_key", 3), ("reason_key", 3)):
        if data[name].ndim != 2 or data[name].shape[1] != cols or data[name].dtype.kind not in "iu":
            bad(name, f"shape {data[name].shape} ({data[name].dtype}), expected (n, {cols}) integers")
    for key, val in (("duration_key", "duration_s"), ("reason_key", "reason_text"), ("detour_key", "detour_len")):
        if data[val].ndim != 1 or len(data[val]) != len(data[key]):
            bad(val, f"shape {data[val].shape}, expected one entry per row of {key} ({len(data[key])})")
    lengths = data["detour_len"]
    points = data["detour_points"]
    if (lengths.dtype.kind not in "iu" or (lengths < 0).any() or points.ndim != 2 or points.shape[1] != joints_n
            or int(lengths.sum()) != len(points)):
        bad("detour_points", f"shape {points.shape} for detour lengths summing to {int(lengths.sum())}, expected "
                             f"(sum, {joints_n})")
    B = book.status.shape[0] if book.status.ndim else 0
    if len(data["detour_key"]) and not ((data["detour_key"][:, 0] >= 0) & (data["detour_key"][:, 0] < B)).all():
        bad("detour_key", f"a boom index outside 0..{B - 1}")
    if "pair_key" in data or "pair_value" in data:
        pk, pv = data.get("pair_key", np.zeros((0, 10))), data.get("pair_value", np.zeros((0, 2)))
        if pk.ndim != 2 or pk.shape[1] != 10 or pv.ndim != 2 or pv.shape[1] != 2 or len(pk) != len(pv):
            bad("pair_key", f"shapes {pk.shape} and pair_value {pv.shape}, expected (n, 10) and (n, 2)")


def load_book(path, oracle, n_holes: int, settings: RoundSettings) -> tuple[MoveBook | None, str]:
    """The book of ``path`` for ``oracle`` (its detours set on the oracle), or None and why not."""
    path = FilePath(path)
    if not path.is_file():
        return None, f"{path}: no move book (every move is looked at again)"
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as e:  # truncated, not an .npz, pickled
        raise InputError(f"{path}: cannot read it as a move book ({type(e).__name__}: {e})") from None
    book = MoveBook(oracle, n_holes, settings)
    _check_arrays(path, data, book, joints_n=int(oracle.joints[0].shape[-1]) if len(oracle.joints) else 0)
    try:
        meta = json.loads(str(data["meta"]))
    except (ValueError, RecursionError) as e:
        raise InputError(f"{path}: meta: not JSON ({e})") from None
    if meta != json.loads(json.dumps(_meta(book))):
        return None, f"{path}: made under other settings ({meta}); every move is looked at again"
    joints = np.stack([q.numpy() for q in oracle.joints])
    if data["joints"].shape != joints.shape or not np.array_equal(data["joints"], joints):
        return None, f"{path}: made for other joint solutions; every move is looked at again"
    if data["status"].shape != book.status.shape:
        raise InputError(f"{path}: status has shape {data['status'].shape}, expected {book.status.shape}")
    book.status[...] = data["status"]
    for k in KINDS:
        book.floor[k][...] = data[f"floor_{k}"]
    book.durations = {tuple(int(x) for x in k): float(d) for k, d in zip(data["duration_key"], data["duration_s"],
                                                                          strict=True)}
    offsets = np.concatenate([[0], np.cumsum(data["detour_len"])])
    paths = {}
    for i, (b, u, v) in enumerate(data["detour_key"]):  # a few dozen detours
        w = torch.as_tensor(data["detour_points"][offsets[i]:offsets[i + 1]], dtype=oracle.joints[b].dtype)
        p = Path.through(w, oracle.limits[b])
        if abs(p.duration - book.durations.get((int(b), int(u), int(v)), np.nan)) > 1e-9:
            return None, f"{path}: detour ({b}, {u}, {v}) does not retrace its duration; every move is looked at again"
        paths[(int(b), int(u), int(v))] = p
    for (b, u, v), p in paths.items():
        oracle.set_detour(b, u, v, p)
    for key, (least, lower) in zip(data.get("pair_key", np.zeros((0, 10), np.int64)),
                                   data.get("pair_value", np.zeros((0, 2))), strict=True):
        k = [int(x) for x in key]
        oracle.sweep_pairs[((k[0], bool(k[1]), k[2], k[3], bool(k[4])), (k[5], bool(k[6]), k[7], k[8], bool(k[9])))] = (
            float(least), float(lower))
    book.reason = {tuple(int(x) for x in k): str(t) for k, t in zip(data["reason_key"], data["reason_text"],
                                                                     strict=True)}
    return book, (f"{path}: {len(data['detour_key'])} detours, {int((book.status > 0).sum())} moves and "
                  f"{len(oracle.sweep_pairs)} swept action pairs known")
