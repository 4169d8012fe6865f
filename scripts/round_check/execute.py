"""The execution rule of docs/reference.md section 8, the checker's own: an action starts once its boom's previous
action and every action it is interlocked after have ended; a move keeps its planned duration, a drill
takes its drawn one. Vectorised over draws: actions are taken level by level of the dependency graph
(sequence and interlock edges), so the loop runs over the graph's depth, never over draws.

With zones (:class:`round_check.actions.Zones`) the rule has one more condition: an action that enters
a zone (a section's first action) starts only when no other boom is inside that zone; two booms ready to
enter one zone at the same instant are let in in rig order (the lower boom first), the other waits. That
makes the execution depend on which boom comes first, so it is run draw by draw, as events
(:func:`execute_zones`; the plain rule keeps the vectorised form); a draw in which every boom left waits
for another is a deadlock of that draw.

The draws: the model durations; ``n`` draws with every hole's drilling uniform in
0.7-1.5x its model time; every hole alone at 3x (the others at 1x); each boom in turn at 1.5x while the
others run at 0.7x.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from .actions import Actions, Interlocks, Zones
from .errors import InputError
from .files import _require, _table

RANDOM = (0.7, 1.5)
STALL = 3.0
SLOW, QUICK = 1.5, 0.7
DRAW_COLUMNS = ["draw", "label", "hole_id", "factor"]


@dataclass
class Graph:
    levels: list[np.ndarray]  # actions, level by level (each after every action it depends on)
    preds: np.ndarray  # (n, width) actions each must wait for; n (a column of zeros) pads
    cycle: list[int] | None  # a deadlock: actions, each waiting for the next, the last for the first


def graph(acts: Actions, locks: Interlocks) -> Graph:
    n = len(acts)
    prev = acts.previous
    seq = np.flatnonzero(prev >= 0)
    before = np.concatenate([prev[seq], locks.before])
    after = np.concatenate([seq, locks.after])
    deg = np.bincount(after, minlength=n)
    width = max(int(deg.max()) if n else 0, 1)
    preds = np.full((n, width), n, np.int64)
    order = np.argsort(after, kind="stable")
    slot = np.arange(len(after)) - np.searchsorted(after[order], after[order])
    preds[after[order], slot] = before[order]
    succ_order = np.argsort(before, kind="stable")
    succ_start = np.searchsorted(before[succ_order], np.arange(n + 1))
    left, levels, done = deg.copy(), [], 0
    level = np.flatnonzero(left == 0)
    while len(level):  # Kahn's algorithm, one level at a time
        levels.append(level)
        done += len(level)
        lo, cnt = succ_start[level], succ_start[level + 1] - succ_start[level]
        at = np.repeat(lo - np.cumsum(cnt) + cnt, cnt) + np.arange(int(cnt.sum()))  # every level node's successors
        nxt = after[succ_order[at]]
        np.subtract.at(left, nxt, 1)
        level = np.unique(nxt[left[nxt] == 0])
    cycle = None
    if done < n:  # what is left waits, directly or not, on itself: walk back to a repeat
        stuck = left > 0
        u, seen = int(np.flatnonzero(stuck)[0]), []
        while u not in seen:
            seen.append(u)
            u = int(next(p for p in preds[u] if p < n and stuck[p]))
        cycle = seen[seen.index(u):]  # each waits for the next one, the last for the first
    return Graph(levels, preds, cycle)


def execute(g: Graph, duration: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and end ``(draws, n)`` of every action under ``duration (draws, n)``."""
    d, n = duration.shape
    end = np.zeros((d, n + 1))  # column n: "nothing to wait for", ends at t = 0
    start = np.zeros((d, n))
    for level in g.levels:
        start[:, level] = end[:, g.preds[level]].max(-1)
        end[:, level] = start[:, level] + duration[:, level]
    return start, end[:, :n]


def execute_zones(acts: Actions, g: Graph, zones: Zones, duration: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, list[list[int] | None]]:
    """Start and end ``(draws, n)`` under the rule with zones (module docstring), and per draw None or
    the actions the booms stand before when no boom can go on (a deadlock; their starts and ends NaN)."""
    d, n = duration.shape
    B = len(acts.booms)
    preds = [[int(p) for p in row if p < n] for row in g.preds]
    enters: dict[int, list[int]] = {}
    leaves: dict[int, list[int]] = {}
    for s, (f, la) in enumerate(zip(zones.first, zones.last, strict=True)):
        enters.setdefault(int(f), []).append(s)
        leaves.setdefault(int(la), []).append(s)
    start, end = np.full((d, n), np.nan), np.full((d, n), np.nan)
    stuck: list[list[int] | None] = []
    for i in range(d):
        nxt = acts.first[:-1].copy()
        running = np.full(B, -1)
        inside: dict[str, set[int]] = {}  # zone -> booms inside
        done = np.zeros(n, bool)
        t = 0.0
        while True:
            moved = True
            while moved:  # start whatever may start at t, booms in rig order
                moved = False
                for b in range(B):
                    k = int(nxt[b])
                    if running[b] >= 0 or k >= acts.first[b + 1] or not all(done[p] for p in preds[k]):
                        continue
                    zs = [zones.zone[s] for s in enters.get(k, ())]
                    if any(inside.get(z, set()) - {b} for z in zs):
                        continue
                    for z in zs:
                        inside.setdefault(z, set()).add(b)
                    start[i, k], end[i, k] = t, t + duration[i, k]
                    running[b], moved = k, True
            if (running < 0).all():
                left = [int(nxt[b]) for b in range(B) if nxt[b] < acts.first[b + 1]]
                stuck.append(left or None)
                break
            t = float(min(end[i, k] for k in running if k >= 0))
            for b in range(B):
                k = int(running[b])
                if k >= 0 and end[i, k] <= t:
                    done[k], running[b], nxt[b] = True, -1, nxt[b] + 1
                    for s in leaves.get(k, ()):
                        inside[zones.zone[s]].discard(b)
    return start, end, stuck


@dataclass
class Draws:
    labels: list[str]
    factor: np.ndarray  # (draws, holes): drilling time over its model time
    holes: list[str]
    kinds: list[str] = field(default_factory=list)  # a draws file's label kind per draw, "" for the checker's own

    def __post_init__(self):
        self.kinds = self.kinds or [""] * len(self.labels)

    def __add__(self, other: Draws) -> Draws:
        assert self.holes == other.holes
        return Draws(self.labels + other.labels, np.concatenate([self.factor, other.factor]), self.holes,
                     self.kinds + other.kinds)


def draws(holes: list[str], boom_of: np.ndarray, booms: list[str], n: int, seed: int, fixed: bool) -> Draws:
    """The nominal draw first; then ``n`` random ones; with ``fixed``, each hole alone at 3x and each
    boom slow while the others are quick (``boom_of``: the boom index that drills each hole)."""
    H = len(holes)
    parts, labels = [np.ones((1, H))], ["nominal (model durations)"]
    rng = np.random.default_rng(seed)
    parts.append(rng.uniform(*RANDOM, (n, H)))
    labels += [f"random {i} (seed {seed})" for i in range(n)]
    if fixed:
        stall = np.ones((H, H))
        np.fill_diagonal(stall, STALL)
        parts.append(stall)
        labels += [f"hole {h} at {STALL:g}x" for h in holes]
        slow = np.where(boom_of[None, :] == np.arange(len(booms))[:, None], SLOW, QUICK)
        parts.append(slow)
        labels += [f"boom {b} at {SLOW:g}x, the others at {QUICK:g}x" for b in booms]
    return Draws(labels, np.concatenate(parts), list(holes))


def label_kind(label: str) -> str:
    """A draws file label's kind, its first word (``stall H12`` -> ``stall``; ``random`` -> ``random``)."""
    words = label.split()
    return words[0] if words else "(no label)"


def read_draws(path: Path, plan_ids: list[str], holes: list[str]) -> tuple[Draws, dict]:
    """A draws file (``draw, label, hole_id, factor``; long format, one row per draw and hole, a hole not
    listed for a draw at 1x) as :class:`Draws` over ``holes`` (the round's drilled holes), in the order
    draws first appear. A listed plan hole the round does not drill is counted and has no effect.
    Refused (:class:`InputError`, naming the file and the row): a missing column or cell, a hole not
    in the plan, a factor not a finite number > 0, a (draw, hole_id) listed twice, one draw under two
    labels, no rows."""
    df = _table(Path(path), "draws file")
    _require(df, DRAW_COLUMNS, path)
    if df.empty:
        raise InputError(f"{path}: no draws (no rows)")
    draw, label, hole = (df[c].str.strip() for c in ("draw", "label", "hole_id"))
    empty = (draw == "").to_numpy()
    if empty.any():
        i = int(np.flatnonzero(empty)[0])
        raise InputError(f"{path}: row {i + 2}: no draw named (the `draw` cell is empty)")
    unknown = ~hole.isin(plan_ids).to_numpy()
    if unknown.any():
        i = int(np.flatnonzero(unknown)[0])
        raise InputError(f"{path}: row {i + 2}: hole_id {hole.iloc[i]!r} is not a hole of the plan "
                         f"({int(unknown.sum())} such row(s))")
    num = pd.to_numeric(df["factor"].str.strip(), errors="coerce").to_numpy(float)
    bad = ~(np.isfinite(num) & (num > 0))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise InputError(f"{path}: row {i + 2}: factor = {df['factor'].iloc[i]!r} is not a finite number > 0 (a "
                         f"drilling duration over its model time; {int(bad.sum())} such row(s))")
    twice = pd.DataFrame({"d": draw, "h": hole}).duplicated(keep=False).to_numpy()
    if twice.any():
        rows = np.flatnonzero(twice & (draw == draw.iloc[int(np.flatnonzero(twice)[0])]).to_numpy()
                              & (hole == hole.iloc[int(np.flatnonzero(twice)[0])]).to_numpy()) + 2
        raise InputError(f"{path}: rows {', '.join(map(str, rows))}: draw {draw.iloc[rows[0] - 2]!r} lists hole "
                         f"{hole.iloc[rows[0] - 2]!r} more than once")
    names = list(dict.fromkeys(draw))  # draws in the order they first appear
    first = pd.DataFrame({"d": draw, "l": label}).drop_duplicates()
    split = first["d"].duplicated(keep=False).to_numpy()
    if split.any():
        d = first["d"].iloc[int(np.flatnonzero(split)[0])]
        rows = np.flatnonzero((draw == d).to_numpy())
        lab = {label.iloc[i] for i in rows}
        raise InputError(f"{path}: draw {d!r} has {len(lab)} labels {sorted(lab)} (rows "
                         f"{', '.join(str(i + 2) for i in rows[:6])}): one label per draw")
    labels = dict(zip(first["d"], first["l"], strict=True))
    col = {h: j for j, h in enumerate(holes)}
    factor = np.ones((len(names), len(holes)))
    di = draw.map({d: i for i, d in enumerate(names)}).to_numpy(np.int64)
    hj = hole.map(col).to_numpy(float)  # NaN: a plan hole this round does not drill
    used = np.isfinite(hj)
    factor[di[used], hj[used].astype(np.int64)] = num[used]
    out = Draws([f"file draw {d} ({labels[d]})" for d in names], factor, list(holes),
                [label_kind(labels[d]) for d in names])
    return out, {"path": str(path), "draws": len(names), "rows": int(len(df)),
                 "rows_of_holes_not_drilled": int((~used).sum())}
