"""The actions and interlocks files of docs/reference.md section 8, read and held against the trajectory file.

Actions file: ``boom, action, kind, hole_id, t_start, t_end``; interlocks file: ``boom, action,
after_boom, after_action`` (action ``action`` of ``boom`` starts only once ``after_action`` of
``after_boom`` has ended); zones file (optional: absent or a header alone is no zone): ``zone, boom,
first_action, last_action``, one row per *section* (the boom is inside the zone from the start of
``first_action`` to the end of ``last_action``; it may start ``first_action`` only when no other boom
is inside that zone). Anything that cannot be judged is an :class:`InputError` (exit 2) naming
the file and its row (file line; the header is line 1).

Agreement with the trajectory (per boom, times within :data:`TIME_TOL`): every action starts and ends
on one of the boom's rows; a ``drill`` of hole h spans exactly h's collar row to the row ending its
retraction (collar, drill, retract, end); a ``move`` has only ``move`` / ``move_unclear`` rows strictly
inside it; between two actions, before the first (from t = 0) and after the last (to the boom's last
row) the boom stands still (a pause); every hole the boom collars is one of its drill actions. A boom
without actions stands still throughout.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from .errors import InputError
from .files import BoomRows, _numbers, _require, _table

ACTION_COLUMNS = ["boom", "action", "kind", "hole_id", "t_start", "t_end"]
INTERLOCK_COLUMNS = ["boom", "action", "after_boom", "after_action"]
ZONE_COLUMNS = ["zone", "boom", "first_action", "last_action"]
KINDS = ("move", "drill")
MOVE_EVENTS = ("move", "move_unclear")
TIME_TOL = 1e-6  # s: actions and rows are written from the same floats
HOLD_TOL = 1e-9  # rad / m: standing still is the joints written unchanged


@dataclass
class Actions:
    """Every boom's actions, numbered globally boom-major in rig order: boom ``b`` owns
    ``first[b]:first[b + 1]``, its action ``i`` is ``first[b] + i``."""

    booms: list[str]
    boom: np.ndarray  # (n,) rig index
    index: np.ndarray  # (n,) number within its boom
    kind: np.ndarray  # (n,) "move" / "drill"
    hole: np.ndarray  # (n,) hole id ("" on a move)
    t_start: np.ndarray
    t_end: np.ndarray
    line: np.ndarray  # (n,) file line
    first: np.ndarray  # (B + 1,)
    path: Path

    def __len__(self) -> int:
        return len(self.boom)

    @property
    def previous(self) -> np.ndarray:
        """The same boom's previous action, -1 for a first one."""
        prev = np.arange(len(self)) - 1
        prev[self.index == 0] = -1
        return prev

    def name(self, k: int) -> str:
        if self.kind[k] == "drill":
            what = f"drill {self.hole[k]}"
        else:  # a move goes to the hole its next action drills, or to park
            nxt = k + 1 if k + 1 < len(self) and self.boom[k + 1] == self.boom[k] else -1
            what = f"move to hole {self.hole[nxt]}" if nxt >= 0 and self.kind[nxt] == "drill" else "move to park"
        return f"{self.booms[self.boom[k]]}#{self.index[k]} ({what})"


@dataclass
class Interlocks:
    before: np.ndarray  # (m,) global action that must have ended
    after: np.ndarray  # (m,) global action that waits
    line: np.ndarray
    path: Path


def _whole(vals: np.ndarray, df: pd.DataFrame, col: str, path: Path) -> np.ndarray:
    bad = (vals != np.round(vals)) | (vals < 0)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise InputError(f"{path}: row {i + 2}: {col} = {df[col].iloc[i]!r} is not a whole number >= 0")
    return vals.astype(np.int64)


def read_actions(path: Path, booms: list[str]) -> Actions:
    df = _table(path, "actions file")
    _require(df, ACTION_COLUMNS, path)
    boom, kind, hole = (df[c].str.strip() for c in ("boom", "kind", "hole_id"))
    unknown = ~boom.isin(booms)
    if unknown.any():
        i = int(np.flatnonzero(unknown)[0])
        raise InputError(f"{path}: row {i + 2}: boom {boom.iloc[i]!r} is not a boom of the rig {booms}")
    bad = ~kind.isin(KINDS)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise InputError(f"{path}: row {i + 2}: kind {kind.iloc[i]!r} is not one of {list(KINDS)}")
    wrong = (kind == "drill") == (hole == "")
    if wrong.any():
        i = int(np.flatnonzero(wrong)[0])
        said = "a drill without hole_id" if kind.iloc[i] == "drill" else f"a move naming hole {hole.iloc[i]!r}"
        raise InputError(f"{path}: row {i + 2}: {said} (hole_id is on drill rows only)")
    num = _numbers(df, ["action", "t_start", "t_end"], path, boom)
    action = _whole(num[:, 0], df, "action", path)
    bi = boom.map({b: i for i, b in enumerate(booms)}).to_numpy(np.int64)
    order = np.lexsort((action, bi))  # boom-major, by number
    bi, action, line = bi[order], action[order], order + 2
    starts = np.searchsorted(bi, np.arange(len(booms) + 1))
    want = np.arange(len(bi)) - starts[bi]  # 0, 1, 2, ... within each boom
    off = action != want
    if off.any():
        k = int(np.flatnonzero(off)[0])
        b = booms[bi[k]]
        first = k == starts[bi[k]]
        if not first and action[k] == action[k - 1]:
            said = f"action {action[k]} is listed twice (rows {line[k - 1]} and {line[k]})"
        else:
            said = (f"action {action[k]} (row {line[k]}) is its first: expected 0" if first else
                    f"action {action[k]} (row {line[k]}) follows action {action[k - 1]}: expected {want[k]}")
        raise InputError(f"{path}: boom {b!r}: {said}; a boom's actions are numbered 0, 1, 2, ... without gaps")
    t0, t1 = num[order, 1], num[order, 2]
    back = t1 < t0 - TIME_TOL
    if back.any():
        k = int(np.flatnonzero(back)[0])
        raise InputError(f"{path}: row {line[k]}: t_end = {t1[k]!r} is before t_start = {t0[k]!r}")
    same = bi[1:] == bi[:-1]
    overlap = same & (t0[1:] < t1[:-1] - TIME_TOL)
    if overlap.any():
        k = int(np.flatnonzero(overlap)[0]) + 1
        raise InputError(f"{path}: row {line[k]}: boom {booms[bi[k]]!r} action {action[k]} starts at {t0[k]!r}, "
                         f"before its action {action[k - 1]} ends ({t1[k - 1]!r}, row {line[k - 1]})")
    return Actions(list(booms), bi, action, kind.to_numpy(str)[order], hole.to_numpy(str)[order], t0, t1, line,
                   starts, Path(path))


def read_interlocks(path: Path, acts: Actions) -> Interlocks:
    df = _table(path, "interlocks file")
    _require(df, INTERLOCK_COLUMNS, path)
    num = _numbers(df, ["action", "after_action"], path)
    ends = []
    for bcol, acol, j in (("boom", "action", 0), ("after_boom", "after_action", 1)):
        name = df[bcol].str.strip()
        bi = name.map({b: i for i, b in enumerate(acts.booms)})
        n_of = np.diff(acts.first)
        unknown = bi.isna().to_numpy()
        if unknown.any():
            i = int(np.flatnonzero(unknown)[0])
            raise InputError(f"{path}: row {i + 2}: {bcol} {name.iloc[i]!r} is not a boom of the rig {acts.booms}")
        bi = bi.to_numpy(np.int64)
        a = _whole(num[:, j], df, acol, path)
        missing = a >= n_of[bi]
        if missing.any():
            i = int(np.flatnonzero(missing)[0])
            has = f"0..{n_of[bi[i]] - 1}" if n_of[bi[i]] else "none"
            raise InputError(f"{path}: row {i + 2}: {bcol} {name.iloc[i]!r} has no action {a[i]} in {acts.path} "
                             f"(its actions: {has})")
        ends.append(acts.first[bi] + a)
    return Interlocks(ends[1], ends[0], np.arange(len(df)) + 2, Path(path))


@dataclass
class Zones:
    """Sections of zones, one per row: ``zone`` name, the boom (rig index) and its first and last action
    (global numbers). Empty when there is no zones file."""

    zone: np.ndarray  # (m,) str
    boom: np.ndarray
    first: np.ndarray
    last: np.ndarray
    line: np.ndarray
    path: Path | None

    def __len__(self) -> int:
        return len(self.zone)

    @classmethod
    def none(cls) -> Zones:
        e = np.zeros(0, np.int64)
        return cls(np.zeros(0, str), e, e, e, e, None)

    def entries(self) -> np.ndarray:
        """The actions that enter a zone (a section's first): a boom may have to stand before them."""
        return np.unique(self.first)

    def section(self, k: int) -> str:
        return f"zone {self.zone[k]!r} section (row {self.line[k]})"


def read_zones(path: Path | None, acts: Actions) -> Zones:
    """The zones file (module docstring); ``None`` or an absent file: no zone. Refused (exit 2, naming
    the file and the row): a missing column or cell, an empty zone name, a boom not of the rig, an action
    the boom does not have, ``last_action`` before ``first_action``, and two sections of one boom in one
    zone that share an action (one of them would enter a zone the boom is already inside)."""
    if path is None or not Path(path).exists():
        return Zones.none()
    df = _table(Path(path), "zones file")
    _require(df, ZONE_COLUMNS, path)
    if df.empty:
        return Zones(np.zeros(0, str), *(np.zeros(0, np.int64),) * 4, Path(path))
    zone, boom = df["zone"].str.strip(), df["boom"].str.strip()
    empty = (zone == "").to_numpy()
    if empty.any():
        i = int(np.flatnonzero(empty)[0])
        raise InputError(f"{path}: row {i + 2}: no zone named (the `zone` cell is empty)")
    bi = boom.map({b: i for i, b in enumerate(acts.booms)})
    unknown = bi.isna().to_numpy()
    if unknown.any():
        i = int(np.flatnonzero(unknown)[0])
        raise InputError(f"{path}: row {i + 2}: boom {boom.iloc[i]!r} is not a boom of the rig {acts.booms}")
    bi = bi.to_numpy(np.int64)
    num = _numbers(df, ["first_action", "last_action"], path, boom)
    first, last = _whole(num[:, 0], df, "first_action", path), _whole(num[:, 1], df, "last_action", path)
    n_of = np.diff(acts.first)
    for col, a in (("first_action", first), ("last_action", last)):
        missing = a >= n_of[bi]
        if missing.any():
            i = int(np.flatnonzero(missing)[0])
            has = f"0..{n_of[bi[i]] - 1}" if n_of[bi[i]] else "none"
            raise InputError(f"{path}: row {i + 2}: boom {boom.iloc[i]!r} has no action {a[i]} ({col}) in "
                             f"{acts.path} (its actions: {has})")
    back = last < first
    if back.any():
        i = int(np.flatnonzero(back)[0])
        raise InputError(f"{path}: row {i + 2}: last_action {last[i]} is before first_action {first[i]}")
    lines = np.arange(len(df)) + 2
    order = np.lexsort((first, bi, zone.to_numpy(str)))
    z, b, f, la = zone.to_numpy(str)[order], bi[order], first[order], last[order]
    clash = (z[1:] == z[:-1]) & (b[1:] == b[:-1]) & (f[1:] <= la[:-1])
    if clash.any():
        k = int(np.flatnonzero(clash)[0])
        raise InputError(f"{path}: rows {lines[order[k]]} and {lines[order[k + 1]]}: two sections of boom "
                         f"{acts.booms[b[k]]!r} in zone {z[k]!r} share actions ({f[k]}..{la[k]} and "
                         f"{f[k + 1]}..{la[k + 1]}); a boom's sections of one zone are apart")
    g = acts.first[bi]
    return Zones(zone.to_numpy(str), bi, g + first, g + last, lines, Path(path))


def _row_at(t: np.ndarray, when: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index of the row nearest each time, and whether it lies within :data:`TIME_TOL`."""
    i = np.clip(np.searchsorted(t, when), 1, len(t) - 1) if len(t) > 1 else np.zeros(len(when), np.int64)
    if len(t) > 1:
        i = np.where(np.abs(t[i - 1] - when) <= np.abs(t[i] - when), i - 1, i)
    return i, np.abs(t[i] - when) <= TIME_TOL


def agree(acts: Actions, rows: dict[str, BoomRows], trajectory: Path, uncollared: frozenset = frozenset()) -> None:
    """The actions tile each boom's rows as the module docstring says; else an :class:`InputError`.

    ``uncollared``: holes (a realised round's interrupted ones) whose drill action may have no collar
    row: the hole was stopped before collaring ended, and the boom stands still through the action."""
    for b, name in enumerate(acts.booms):
        r, k = rows[name], np.arange(acts.first[b], acts.first[b + 1])
        where = f"{acts.path}: boom {name!r}"
        t0, t1 = acts.t_start[k], acts.t_end[k]
        for what, when in (("t_start", t0), ("t_end", t1)):
            _, on = _row_at(r.t, when)
            if not on.all():
                i = int(np.flatnonzero(~on)[0])
                raise InputError(f"{where}, row {acts.line[k[i]]}: {what} = {when[i]!r} is not the time of any of its "
                                 f"rows in {trajectory}")
        _moves(acts, k[acts.kind[k] == "move"], r, where, trajectory)
        _drills(acts, k[acts.kind[k] == "drill"], r, where, trajectory, uncollared)
        _pauses(acts, k, r, where, trajectory)


def _drills(acts: Actions, k: np.ndarray, r: BoomRows, where: str, trajectory: Path,
            uncollared: frozenset = frozenset()) -> None:
    collars = np.flatnonzero(r.event == "collar")
    at = dict(zip(r.hole[collars], collars, strict=False))
    for i in k:  # drill actions: one per hole the boom drills
        h = acts.hole[i]
        c = at.get(h)
        if c is None and h in uncollared:  # stopped before its collar row: the boom stands still throughout
            inside = (r.t >= acts.t_start[i] - TIME_TOL) & (r.t <= acts.t_end[i] + TIME_TOL)
            if inside.any() and np.abs(r.q[inside] - r.q[np.flatnonzero(inside)[0]]).max() > HOLD_TOL:
                raise InputError(f"{where}, row {acts.line[i]}: drill of interrupted hole {h}, never collared in "
                                 f"{trajectory}: the boom moves during it ({acts.t_start[i]!r}..{acts.t_end[i]!r})")
            continue
        if c is None:
            raise InputError(f"{where}, row {acts.line[i]}: a drill of hole {h}, which the boom never collars in "
                             f"{trajectory}")
        end = c + 3
        shape = end < len(r.t) and tuple(r.event[c + 1:c + 3]) == ("drill", "retract")
        if not shape or abs(r.t[c] - acts.t_start[i]) > TIME_TOL or abs(r.t[end] - acts.t_end[i]) > TIME_TOL:
            span = f"{r.t[c]!r}..{r.t[end]!r} (rows {r.line[c]}-{r.line[end]})" if shape else f"from {r.t[c]!r}"
            raise InputError(f"{where}, row {acts.line[i]}: drill of hole {h} spans {acts.t_start[i]!r}.."
                             f"{acts.t_end[i]!r}; in {trajectory} the hole's collar to the end of its retraction "
                             f"is {span}")
        moved = np.abs(r.q[c + 1:end + 1] - r.q[c]).max() if end > c else 0.0
        if moved > HOLD_TOL:  # an executed drill lasts what the rock takes: its joints must not depend on when
            raise InputError(f"{where}, row {acts.line[i]}: drill of hole {h}: the joints change by {moved:.3g} "
                             f"between its collar and the end of its retraction in {trajectory} (rows "
                             f"{r.line[c]}-{r.line[end]}); a drill is at constant joints (reference, section 8)")
    extra = sorted(set(r.hole[collars]) - set(acts.hole[k]))
    if extra:
        raise InputError(f"{where}: collars hole(s) {extra} in {trajectory} that are no drill action of it")


def _moves(acts: Actions, k: np.ndarray, r: BoomRows, where: str, trajectory: Path) -> None:
    lo = np.searchsorted(r.t, acts.t_start[k] + TIME_TOL, side="right")
    hi = np.searchsorted(r.t, acts.t_end[k] - TIME_TOL, side="left")
    bad = np.concatenate([[0], np.cumsum(~np.isin(r.event, MOVE_EVENTS))])
    wrong = bad[np.maximum(hi, lo)] - bad[lo] > 0  # rows strictly inside that are not motion
    if wrong.any():
        i = int(np.flatnonzero(wrong)[0])
        j = lo[i] + int(np.flatnonzero(~np.isin(r.event[lo[i]:hi[i]], MOVE_EVENTS))[0])
        raise InputError(f"{where}, row {acts.line[k[i]]}: move {acts.t_start[k[i]]!r}..{acts.t_end[k[i]]!r} holds "
                         f"a {r.event[j]} row ({trajectory} row {r.line[j]}, t = {r.t[j]!r}); a move's rows "
                         f"are {' / '.join(MOVE_EVENTS)}")


def _pauses(acts: Actions, k: np.ndarray, r: BoomRows, where: str, trajectory: Path) -> None:
    w0 = np.concatenate([[r.t[0]], acts.t_end[k]])  # pause p: before action p (p = len: after the last)
    w1 = np.concatenate([acts.t_start[k], [r.t[-1]]])
    first = np.searchsorted(r.t, w0 - TIME_TOL)  # the row a pause stands at
    w = np.searchsorted(w0 - TIME_TOL, r.t, side="right") - 1
    inside = (w >= 0) & (r.t <= w1[np.maximum(w, 0)] + TIME_TOL)
    moved = np.zeros(len(r.t), bool)
    moved[inside] = np.abs(r.q[inside] - r.q[first[w[inside]]]).max(1) > HOLD_TOL
    if moved.any():
        j = int(np.flatnonzero(moved)[0])
        p = w[j]
        between = ("before its first action" if p == 0 else "after its last action" if p == len(k)
                   else f"between its actions {p - 1} and {p}")
        raise InputError(f"{where}: moves {between} ({trajectory} row {r.line[j]}, t = {r.t[j]!r}); outside its "
                         f"actions ({acts.path}) a boom stands still")
