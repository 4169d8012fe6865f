"""A planned timeline as each boom's actions (docs/reference.md, section 8), and the actions and interlocks files.

Boom b with route ``h_0 .. h_{n-1}`` has actions ``0 .. 2n``: ``move`` park -> h_0, ``drill`` h_0,
``move`` h_0 -> h_1, ..., ``drill`` h_{n-1}, ``move`` h_{n-1} -> park. Planned times: a move is
``[move_start, arrive]``, a drill ``[arrive, arrive + drill_s]``; a pause (a later move start) is not
an action. A boom with no hole has no action (it stays at park). A round handed on
(``Timeline.start``) starts each boom's first move where the boom stands. Actions are numbered globally in
boom-major order (``Actions.boom``, ``Actions.index`` give the file's ``boom, action``).

Interlocks are edges ``(before, after)`` of global action numbers: ``after`` may start only once
``before`` has ended. In the file a row ``boom, action, after_boom, after_action`` says action
``action`` of ``boom`` waits for action ``after_action`` of ``after_boom``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.core.errors import InputError
from pipeline.events.graph import find_cycle
from pipeline.round.problem import Instance
from pipeline.round.timeline import Timeline

ACTION_COLUMNS = ["boom", "action", "kind", "hole_id", "t_start", "t_end"]
INTERLOCK_COLUMNS = ["boom", "action", "after_boom", "after_action"]
KINDS = ("move", "drill")


@dataclass(frozen=True)
class Actions:
    """Every boom's actions, boom-major: per action its boom (index), number within the boom, kind,
    hole (drill; -1 for a move), the nodes it goes from and to (index H: park; a drill: its hole
    twice) and its planned times."""

    booms: tuple[str, ...]
    hole_ids: tuple[str, ...]
    boom: np.ndarray
    index: np.ndarray
    kind: np.ndarray  # "move" / "drill"
    hole: np.ndarray
    src: np.ndarray
    dst: np.ndarray
    t_start: np.ndarray
    t_end: np.ndarray

    def __len__(self) -> int:
        return len(self.boom)

    @property
    def is_drill(self) -> np.ndarray:
        return self.kind == "drill"

    @property
    def duration(self) -> np.ndarray:
        return self.t_end - self.t_start

    @property
    def previous(self) -> np.ndarray:
        """The same boom's previous action (-1 for a first one)."""
        prev = np.arange(len(self)) - 1
        prev[self.index == 0] = -1
        return prev

    def sequence_edges(self) -> np.ndarray:
        """``(n, 2)`` within-boom edges (previous, next): implicit in the rule, explicit for graphs."""
        prev = self.previous
        k = np.flatnonzero(prev >= 0)
        return np.stack([prev[k], k], 1)

    def of(self, boom: int, index: int) -> int:
        """The global number of action ``index`` of boom ``boom`` (-1 if there is none)."""
        k = np.flatnonzero((self.boom == boom) & (self.index == index))
        return int(k[0]) if len(k) else -1

    def name(self, k: int) -> str:
        what = f"{self.kind[k]} {self.hole_ids[self.hole[k]]}" if self.is_drill[k] else (
            f"move {self._node(self.src[k])} -> {self._node(self.dst[k])}")
        return f"{self.booms[self.boom[k]]}#{self.index[k]} ({what})"

    def _node(self, n: int) -> str:
        return "park" if n == len(self.hole_ids) else self.hole_ids[n]


def actions_of(inst: Instance, tl: Timeline) -> Actions:
    """The actions of a timeline, with its planned times (module docstring)."""
    H, drill = inst.n_holes, inst.drill_s
    cols = {k: [] for k in ("boom", "index", "kind", "hole", "src", "dst", "t_start", "t_end")}

    def add(b, i, kind, hole, src, dst, t0, t1):
        for k, v in zip(cols, (b, i, kind, hole, src, dst, t0, t1), strict=True):
            cols[k].append(v)

    for b, route in enumerate(tl.routes):
        first = tl.start_node(b)
        if not route and first == H:
            continue
        nodes = [first, *route, H]
        i = 0
        for k in range(len(route) + 1):
            add(b, i, "move", -1, nodes[k], nodes[k + 1], float(tl.move_start[b][k]), float(tl.arrive[b][k]))
            i += 1
            if k < len(route):
                h = route[k]
                t = tl.drill_at(b, k)
                add(b, i, "drill", h, h, h, t, t + float(drill[h]))
                i += 1
    arr = {k: np.asarray(v, dtype=float if k.startswith("t_") else (object if k == "kind" else int))
           for k, v in cols.items()}
    arr["kind"] = arr["kind"].astype(str) if len(arr["kind"]) else np.zeros(0, dtype="<U5")
    return Actions(tuple(inst.booms), tuple(inst.hole_ids), **arr)


def actions_from_table(df: pd.DataFrame, booms, hole_ids, source: str = "actions") -> Actions:
    """An actions table read back (:func:`read_actions`) as :class:`Actions` over the plan's holes.
    Booms in ``booms`` order; a move goes from where the boom's previous action left it (park before
    the first) to the hole its next drill is at (park after the last). Raises :class:`InputError` for
    a boom or hole the rig or plan does not have."""
    booms, hole_ids = tuple(booms), tuple(hole_ids)
    H, b_of, h_of = len(hole_ids), {b: k for k, b in enumerate(booms)}, {h: k for k, h in enumerate(hole_ids)}
    for name, known, col in (("boom", b_of, "boom"), ("hole", h_of, "hole_id")):
        bad = [v for v in df[col] if v and v not in known]
        if bad:
            raise InputError(f"{source}: {name} {bad[0]!r} is not in the {'rig' if col == 'boom' else 'plan'}")
    order = np.lexsort((df["action"].to_numpy(int), [b_of[b] for b in df["boom"]]))
    d = df.iloc[order].reset_index(drop=True)
    boom = np.array([b_of[b] for b in d["boom"]], int)
    kind = d["kind"].astype(str).to_numpy()
    hole = np.array([h_of[h] if h else -1 for h in d["hole_id"]], int)
    src, dst = np.full(len(d), H), np.full(len(d), H)
    for b in np.unique(boom):  # a few booms
        mine = np.flatnonzero(boom == b)
        at = H
        for i, k in enumerate(mine):  # where each action starts and ends (an action's own count)
            if kind[k] == "drill":
                src[k] = dst[k] = at = hole[k]
            else:
                nxt = mine[i + 1] if i + 1 < len(mine) else -1
                src[k], dst[k] = at, hole[nxt] if nxt >= 0 and kind[nxt] == "drill" else H
                at = dst[k]
    return Actions(booms, hole_ids, boom, d["action"].to_numpy(int), kind, hole, src, dst,
                   d["t_start"].to_numpy(float), d["t_end"].to_numpy(float))


def actions_table(acts: Actions) -> pd.DataFrame:
    """The reference's actions file: ``boom, action, kind, hole_id, t_start, t_end``."""
    return pd.DataFrame({
        "boom": [acts.booms[b] for b in acts.boom], "action": acts.index.astype(int), "kind": acts.kind,
        "hole_id": [acts.hole_ids[h] if h >= 0 else "" for h in acts.hole],
        "t_start": acts.t_start, "t_end": acts.t_end})


def interlocks_table(acts: Actions, edges: np.ndarray) -> pd.DataFrame:
    """The reference's interlocks file from edges ``(before, after)``, sorted by the waiting action."""
    e = np.asarray(edges, int).reshape(-1, 2)
    e = e[np.lexsort((e[:, 0], e[:, 1]))]
    before, after = e[:, 0], e[:, 1]
    return pd.DataFrame({"boom": [acts.booms[b] for b in acts.boom[after]], "action": acts.index[after].astype(int),
                         "after_boom": [acts.booms[b] for b in acts.boom[before]],
                         "after_action": acts.index[before].astype(int)})


def _read(path, columns: list[str]) -> pd.DataFrame:
    path = Path(path)
    try:
        df = pd.read_csv(path, dtype=str, keep_default_na=False)
    except (OSError, pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read it as CSV ({e})") from e
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise InputError(f"{path}: missing column(s) {missing}; expected {columns}")
    return df


def _row(path, i: int) -> str:
    return f"{path}: row {i + 2}"  # the header is line 1


def _number(df, col, path, integer=False) -> np.ndarray:
    out = np.empty(len(df), dtype=float)
    for i, v in enumerate(df[col]):
        try:
            x = float(v)
        except ValueError:
            x = np.nan
        if not np.isfinite(x) or (integer and (x != int(x) or x < 0)):
            kind = "a whole number >= 0" if integer else "a finite number"
            raise InputError(f"{_row(path, i)}: {col} = {v!r}: expected {kind}")
        out[i] = x
    return out.astype(int) if integer else out


def read_actions(path) -> pd.DataFrame:
    """An actions file, checked: its columns, kinds, numbers (finite, ``t_end >= t_start``), a hole on
    every drill and none on a move, each boom's actions numbered 0, 1, ... in file order and in time.
    An :class:`InputError` names the file and the row of the first problem."""
    df = _read(path, ACTION_COLUMNS)
    action = _number(df, "action", path, integer=True)
    t0, t1 = _number(df, "t_start", path), _number(df, "t_end", path)
    last: dict[str, tuple[int, float]] = {}
    for i, (boom, kind, hole) in enumerate(zip(df["boom"], df["kind"], df["hole_id"], strict=True)):
        where = _row(path, i)
        if not boom:
            raise InputError(f"{where}: empty boom")
        if kind not in KINDS:
            raise InputError(f"{where}: kind = {kind!r}: expected one of {list(KINDS)}")
        if (kind == "drill") != bool(hole):
            raise InputError(f"{where}: a {kind} " + ("needs a hole_id" if kind == "drill" else "names no hole_id"))
        if t1[i] < t0[i]:
            raise InputError(f"{where}: t_end = {t1[i]} is before t_start = {t0[i]}")
        n, end = last.get(boom, (-1, -np.inf))
        if action[i] != n + 1:
            raise InputError(f"{where}: boom {boom!r} action {action[i]} follows action {n}: expected {n + 1} "
                             "(each boom's actions are numbered 0, 1, 2, ... in order)")
        if t0[i] < end - 1e-9:
            raise InputError(f"{where}: boom {boom!r} action {action[i]} starts at {t0[i]}, before its previous "
                             f"action ends ({end})")
        last[boom] = (action[i], t1[i])
    out = df[ACTION_COLUMNS].copy()
    out["action"], out["t_start"], out["t_end"] = action, t0, t1
    return out


def read_interlocks(path, actions: pd.DataFrame, actions_path="actions") -> np.ndarray:
    """An interlocks file against its actions table (:func:`read_actions`): every row names an action
    that exists on both sides, and the interlocks with each boom's sequence form no cycle (a round that
    could never finish). Returns edges ``(before, after)`` as row numbers of ``actions``; an
    :class:`InputError` names the file and the row of the first problem (for a cycle, a row on it)."""
    df = _read(path, INTERLOCK_COLUMNS)
    index = {(b, int(a)): k for k, (b, a) in enumerate(zip(actions["boom"], actions["action"], strict=True))}
    booms = set(actions["boom"])
    a_num = _number(df, "action", path, integer=True)
    b_num = _number(df, "after_action", path, integer=True)
    edges = np.zeros((len(df), 2), int)
    for i in range(len(df)):
        where = _row(path, i)
        for bcol, num in (("boom", a_num[i]), ("after_boom", b_num[i])):
            boom = df[bcol].iloc[i]
            if boom not in booms:
                raise InputError(f"{where}: {bcol} = {boom!r}: no such boom in {actions_path} ({sorted(booms)})")
            if (boom, num) not in index:
                raise InputError(f"{where}: boom {boom!r} has no action {num} in {actions_path}")
        edges[i] = index[(df["after_boom"].iloc[i], b_num[i])], index[(df["boom"].iloc[i], a_num[i])]
        if edges[i, 0] == edges[i, 1]:
            raise InputError(f"{where}: action {a_num[i]} of boom {df['boom'].iloc[i]!r} waits for itself")
    same = (actions["boom"].to_numpy()[1:] == actions["boom"].to_numpy()[:-1])
    seq = np.stack([np.flatnonzero(same), np.flatnonzero(same) + 1], 1)
    cycle = find_cycle(len(actions), np.concatenate([seq, edges]))
    if cycle is not None:
        on = set(zip(cycle, cycle[1:] + cycle[:1], strict=True))
        row = next(i for i, (u, v) in enumerate(edges) if (int(u), int(v)) in on)
        names = " -> ".join(f"{actions['boom'].iloc[k]}#{actions['action'].iloc[k]}" for k in [*cycle, cycle[0]])
        raise InputError(f"{_row(path, row)}: the interlocks form a cycle ({names}): the round would deadlock")
    return edges
