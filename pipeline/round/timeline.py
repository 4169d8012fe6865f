"""The joint timeline of all booms, its boom-boom conflicts, and their resolution by waits.

A boom's route (hole indices) becomes: standing at park, then per hole a move (the synchronised
straight line, ``move_s``) and the drilling (collaring, penetration, retraction; the boom holds the
hole's joints), then the move back to park, where it stays. A wait is a later start of a move: the
boom stands at its previous node until then. Precedence pairs (i before j) delay j's move so that it
arrives when i is finished (a fixed point over the booms; a cycle of precedences and route orders
is an error).

**Conflicts.** Segments of two booms that run at the same time are checked in time order by the
oracle (:mod:`pipeline.round.oracle`); the earliest conflict is resolved first.

**Repair rule.** Of the two segments in conflict, the one that began later gives way: the move that
leads into it (the move itself, or the move into that standing place) starts when the other
segment ends ("delay the later boom's move until the conflicting interval is over"). When the other
segment is a boom's last standing at park, which never ends, that boom's move home gives way
instead and starts when the first segment ends. Ties go against the boom of the higher index. The
boom giving way stands at its previous node (where that move starts) during the other's segment; if
that place is in the other's way and the other's previous place is not in the way of the first
segment, they swap roles (without this, two booms whose places block each other's moves take turns
forever: R cannot reach its hole while L stands at its own, L cannot go on while R moves).

**Why it ends.** Every repair moves one move's start strictly later (to the end of a segment that
ran past the conflict instant, so after the move's old start), and nothing ever moves a start
earlier. Two booms can still take turns (each one's giving way puts it in the other's way), so
when one move of boom g gives way to boom e for the third time and more, it waits for the end of
e's next segment, then the one after, and so on up to e's return to park (it cannot escalate past
e's last segment, so this ends too); of two booms only the first to escalate does, the other keeps
plain waits. The loop stops at the first conflict-free timeline; after ``max_repairs`` repairs, or
when an escalation would pass e's return to park or ``round.escalations`` steps (a deadlock: g's place
blocks e's next move and e's place blocks g's, which no wait parts), the timeline falls back to one
boom at a time: each boom drills its whole route
from park to park while every other boom stands at park. That timeline has no moving x moving or
drilling x drilling pairs at all; it is conflict-free when every hole and every move of each boom is
clear of the other booms at park (parks are clear of each other: the rig checks it at load), which
holds when the reach table was solved with the other booms at park as obstacles. It is checked with
the oracle like any other, and whatever conflict is left is counted in ``conflicts_left``, never
hidden.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from pipeline.core.errors import ConfigError
from pipeline.round.problem import Instance

ESCALATIONS = 4  # default of round.escalations: waits for the other boom's later segments before giving up


@dataclass
class Timeline:
    """Per boom: its route, the start of every move (the last one home) and its arrival."""

    routes: list[list[int]]
    move_start: list[np.ndarray]
    arrive: list[np.ndarray]
    park: int  # the park node index (H)
    start: list[int] | None = None  # per boom the node it starts from (None: park)
    # per boom, when each hole's drilling starts (None: on arrival, as the planner times it; a round
    # executed by events may stand at a hole, waiting at an interlock, before drilling it)
    drill_start: list[np.ndarray] | None = None
    repairs: list[dict] = field(default_factory=list)
    conflicts_left: int = 0
    sequential: bool = False
    min_clearance: float = math.inf  # smallest sampled boom-boom clearance (m, less d_boom)
    failed_moves: int = 0  # moves nothing made clear of self and tunnel (set by the planner's timer)
    waits: dict = field(default_factory=dict)  # how the waits were placed (method, and the exact solver's certificate)

    @property
    def makespan(self) -> float:
        return max((float(a[-1]) for a in self.arrive), default=0.0)

    def start_node(self, b: int) -> int:
        return self.park if self.start is None else int(self.start[b])

    def drill_at(self, b: int, k: int) -> float:
        """When boom b starts drilling the k-th hole of its route."""
        return float(self.arrive[b][k] if self.drill_start is None else self.drill_start[b][k])


def simulate(inst: Instance, routes: list[list[int]], not_before: list[np.ndarray] | None = None) -> Timeline:
    """Earliest times of every move given the routes, the waits ``not_before[b][k]`` (earliest start
    of boom b's move k) and the instance's precedence pairs."""
    H, drill = inst.n_holes, inst.drill_s
    nb = not_before or [np.zeros(len(r) + 1) for r in routes]
    preds: dict[int, list[int]] = {}
    drillable = inst.drillable
    for i, j in inst.precedence:
        if drillable[i] and drillable[j]:
            preds.setdefault(j, []).append(i)
    end = np.full(H, -np.inf)
    for _ in range(H + 2):  # a fixed point: each pass can only push ends later (a chain per pass)
        starts, arrives, new_end = [], [], end.copy()
        for b, route in enumerate(routes):
            t, node = 0.0, inst.starts[b]
            ms, ar = np.empty(len(route) + 1), np.empty(len(route) + 1)
            for k, tgt in enumerate([*route, H]):
                mv = float(inst.move_s[b, node, tgt])
                start = max(t, float(nb[b][k]))
                for p in preds.get(tgt, ()):
                    start = max(start, end[p] - mv)
                ms[k], ar[k] = start, start + mv
                if tgt != H:
                    t = new_end[tgt] = ar[k] + drill[tgt]
                node = tgt
            starts.append(ms)
            arrives.append(ar)
        if np.array_equal(new_end, end):
            return Timeline([list(r) for r in routes], starts, arrives, H,
                            start=None if inst.start is None else inst.starts)
        end = new_end
    raise ConfigError("round: the precedence pairs and the booms' hole orders form a cycle (a hole would have "
                      "to wait for itself); check round.precedence")


def segments(tl: Timeline, b: int) -> dict[str, np.ndarray]:
    """Boom b's segments in time order: ``t0, t1, u, v`` (u == v: standing), ``k`` (the move that
    leads into it; -1 for the first standing, at park or the boom's start node) and ``p`` (the node that
    move starts from). The last one (at park) ends at inf."""
    H, route, ms, ar = tl.park, tl.routes[b], tl.move_start[b], tl.arrive[b]
    nodes = [tl.start_node(b), *route, H]
    rows = []
    prev_end = 0.0
    for k in range(len(route) + 1):
        if ms[k] > prev_end or k == 0:
            rows.append((prev_end, ms[k], nodes[k], nodes[k], k - 1))
        if ar[k] > ms[k]:
            rows.append((ms[k], ar[k], nodes[k], nodes[k + 1], k))
        prev_end = ar[k]
    rows.append((ar[-1], math.inf, H, H, len(route)))
    rows = [r for r in rows if r[1] > r[0] or r[1] == math.inf]
    a = np.array(rows, dtype=float).reshape(-1, 5)
    k = a[:, 4].astype(int)
    prev = np.array(nodes)[np.clip(k, 0, None)]  # where the leading move starts (park before the first)
    return {"t0": a[:, 0], "t1": a[:, 1], "u": a[:, 2].astype(int), "v": a[:, 3].astype(int), "k": k, "p": prev}


def _overlaps(sa: dict, sb: dict, since: float):
    """Index pairs (i of a, j of b) of segments running at the same time, with hi > ``since``."""
    j_lo = np.searchsorted(sb["t1"], sa["t0"], side="right")
    j_hi = np.searchsorted(sb["t0"], sa["t1"], side="left")
    n = np.clip(j_hi - j_lo, 0, None)
    i = np.repeat(np.arange(len(sa["t0"])), n)
    j = np.concatenate([np.arange(lo, hi) for lo, hi in zip(j_lo, j_hi, strict=True) if hi > lo] or [np.zeros(0, int)])
    lo = np.maximum(sa["t0"][i], sb["t0"][j])
    hi = np.minimum(sa["t1"][i], sb["t1"][j])
    keep = (hi > lo) & (hi > since)
    return i[keep], j[keep], lo[keep], hi[keep]


def scan(tl: Timeline, oracle, since: float = -math.inf, full: bool = False, chunk: int = 32):
    """The earliest conflict of the timeline after ``since`` (None if none) as a dict; with ``full``,
    every pair is checked and ``(earliest, n_conflicts, min_clearance)`` is returned."""
    B = len(tl.routes)
    segs = [segments(tl, b) for b in range(B)]
    found = []
    for a in range(B):
        for b in range(a + 1, B):
            i, j, lo, hi = _overlaps(segs[a], segs[b], since)
            found.append((a, b, i, j, lo, hi))
    order = [(lo_k, a, b, i_k, j_k, hi_k) for a, b, i, j, lo, hi in found
             for lo_k, i_k, j_k, hi_k in zip(lo, i, j, hi, strict=True)]
    order.sort(key=lambda r: r[0])
    best, n_bad, least = None, 0, math.inf
    for s in range(0, len(order), chunk):
        part = order[s:s + chunk]
        if not full and best is not None and part[0][0] >= best["t"]:
            break
        for a in range(B):
            for b in range(a + 1, B):
                rows = [r for r in part if r[1] == a and r[2] == b]
                if not rows:
                    continue
                i = np.array([r[3] for r in rows])
                j = np.array([r[4] for r in rows])
                lo = np.array([r[0] for r in rows])
                hi = np.array([r[5] for r in rows])
                sa = {k: segs[a][k][i] for k in segs[a]}
                sb = {k: segs[b][k][j] for k in segs[b]}
                first, low = oracle.check(a, sa, b, sb, lo, hi)
                least = min(least, float(low.min()))
                bad = np.isfinite(first)
                n_bad += int(bad.sum())
                if bad.any():
                    m = int(np.argmin(first))
                    if best is None or first[m] < best["t"]:
                        best = {"t": float(first[m]), "a": a, "b": b, "seg_a": {k: v[m] for k, v in sa.items()},
                                "seg_b": {k: v[m] for k, v in sb.items()}}
    return (best, n_bad, least) if full else best


@dataclass(frozen=True)
class Segment:
    """Segment ``k`` of one boom's timeline: a move (``move``: its move k) or a standing (move k leads
    into it; -1 is the first standing, at the boom's start node; ``len(route)`` the last, at park)."""

    boom: int
    move: bool
    k: int


def conflicting_segments(tl: Timeline, oracle) -> tuple[list[tuple[Segment, Segment]], float]:
    """Every pair of segments of two booms that run at the same time and conflict (one oracle batch
    per boom pair; the lower boom first), and the smallest clearance sampled (as :func:`scan`'s)."""
    B = len(tl.routes)
    segs = [segments(tl, b) for b in range(B)]
    out, least = [], math.inf
    for a in range(B):
        for b in range(a + 1, B):
            i, j, lo, hi = _overlaps(segs[a], segs[b], -math.inf)
            if not len(i):
                continue
            first, low = oracle.check(a, {k: v[i] for k, v in segs[a].items()}, b,
                                      {k: v[j] for k, v in segs[b].items()}, lo, hi)
            least = min(least, float(np.min(low)))
            bad = np.isfinite(first)
            sa, sb = segs[a], segs[b]
            out += [(Segment(a, bool(sa["u"][x] != sa["v"][x]), int(sa["k"][x])),
                     Segment(b, bool(sb["u"][y] != sb["v"][y]), int(sb["k"][y])))
                    for x, y in zip(i[bad], j[bad], strict=True)]
    return out, least


def _clear(oracle, a: int, seg_a: dict, b: int, seg_b: dict, lo: float, hi: float) -> bool:
    """Whether one pair of segments is clear over [lo, hi] (the oracle takes booms in index order)."""
    if a > b:
        a, seg_a, b, seg_b = b, seg_b, a, seg_a
    one = lambda s: {k: np.array([v]) for k, v in s.items()}  # noqa: E731
    first, _ = oracle.check(a, one(seg_a), b, one(seg_b), np.array([lo]), np.array([hi]))
    return not np.isfinite(first[0])


def _repair(tl: Timeline, c: dict, oracle) -> tuple[int, int, float, dict] | None:
    """(boom, move index, new earliest start, record) that resolves conflict ``c`` (the module's rule);
    None when neither side has a move to delay (both stand at park from the start: the rig's parks
    are clear, so only a caller's oracle can say so)."""
    sides = [(c["a"], c["seg_a"], c["b"], c["seg_b"]), (c["b"], c["seg_b"], c["a"], c["seg_a"])]
    # The later-begun segment gives way; ties against the higher boom index.
    sides.sort(key=lambda s: (s[1]["t0"], s[0]))
    (e, seg_e, g, seg_g) = sides[0][0], sides[0][1], sides[1][0], sides[1][1]
    if math.isinf(seg_e["t1"]):  # the earlier one is a boom done at park: it goes home after the other
        g, seg_g, e, seg_e = e, seg_e, g, seg_g
    # The one giving way stands at its previous node (where its leading move starts) meanwhile. If that
    # place is in the other's way and the other's previous place is not in its own, they swap roles
    # (else two booms whose places block each other's moves take turns forever).
    stand = lambda s: {"t0": s["t0"], "t1": s["t1"], "u": s["p"], "v": s["p"], "k": s["k"], "p": s["p"]}  # noqa: E731
    if (not math.isinf(seg_g["t1"]) and seg_g["k"] >= 0 and seg_e["k"] >= 0
            and not _clear(oracle, g, stand(seg_g), e, seg_e, seg_e["t0"], min(seg_e["t1"], seg_g["t1"]))
            and _clear(oracle, e, stand(seg_e), g, seg_g, seg_g["t0"], seg_g["t1"])):
        g, seg_g, e, seg_e = e, seg_e, g, seg_g
    boom, k, until = g, int(seg_g["k"]), float(seg_e["t1"])
    if k < 0:  # the giving way segment is the first standing at park: cannot be delayed, delay the other
        boom, k, until = e, int(seg_e["k"]), float(seg_g["t1"])
    if k < 0 or math.isinf(until):
        return None
    kind = "standing" if seg_e["u"] == seg_e["v"] and seg_g["u"] == seg_g["v"] else "moving"
    rec = {"boom": boom, "move": k, "t": c["t"], "until": until, "kind": kind,
           "nodes": (int(seg_g["v"]), int(seg_e["v"])) if boom == g else (int(seg_e["v"]), int(seg_g["v"])),
           "booms": (g, e) if boom == g else (e, g)}
    return boom, k, until, rec


def _escalate(tl: Timeline, fix, seen: dict, escalations: int = ESCALATIONS):
    """The same move of boom g giving way to boom e again: from the third time on, it waits for the
    end of e's n-th next segment instead (n = repeats - 2), up to e's return to park; None past that.
    The first boom to escalate against another is the only one of the two that does (were both to,
    each would wait for the other's later and later segments)."""
    boom, k, until, rec = fix
    other = rec["booms"][1]
    key = (boom, k, other)
    seen[key] = n = seen.get(key, 0) + 1
    yielding = seen.setdefault("yielding", set())
    if n <= 2 or (other, boom) in yielding:  # only one of two booms yields more and more to the other
        return fix
    yielding.add((boom, other))
    seg = segments(tl, other)
    last = len(seg["t0"]) - 1  # e's final standing at park
    at = int(np.searchsorted(seg["t1"], until - 1e-9))  # the segment whose end was ``until``
    if at + n - 2 > last or n - 2 > escalations:
        return None
    nxt = at + n - 2
    later = float(seg["t1"][nxt]) if nxt < last else float(seg["t0"][last])  # the last: e back at park
    rec["until"] = until = max(until, later)
    rec["escalated"] = n - 2
    return boom, k, until, rec


def sequential(inst: Instance, routes: list[list[int]], order: list[int] | None = None) -> Timeline:
    """One boom at a time, each from its start (park) to park, in ``order`` (default: boom order)."""
    nb = [np.zeros(len(r) + 1) for r in routes]
    t = 0.0
    for b in order if order is not None else range(len(routes)):
        nb[b][0] = t
        tl = simulate(inst, routes, nb)
        t = float(tl.arrive[b][-1]) if routes[b] or inst.starts[b] != inst.n_holes else t
    tl = simulate(inst, routes, nb)
    tl.sequential = True
    return tl


def sequential_clearest(inst: Instance, routes: list[list[int]], oracle) -> Timeline:
    """The one-boom-at-a-time fallback. From park the boom order does not matter (the others stand at
    park, clear of every hole: the module docstring). A round handed on starts with the booms standing
    at holes, where one may be in another's way: every order of the booms is tried (B! orders, B <= 3
    on a carrier) and the one with the fewest conflicts (then the shortest) kept."""
    if inst.start is None or len(routes) < 2:
        return sequential(inst, routes)
    from itertools import permutations

    best, key = None, None
    for order in permutations(range(len(routes))):
        tl = sequential(inst, routes, list(order))
        _, n_bad, _ = scan(tl, oracle, full=True)
        if key is None or (n_bad, tl.makespan) < key:
            best, key = tl, (n_bad, tl.makespan)
    return best


def resolve(inst: Instance, routes: list[list[int]], oracle, max_repairs: int = 300, measure: bool = True,
            escalations: int = ESCALATIONS) -> Timeline:
    """The routes' timeline with waits inserted until no conflict is left (module docstring;
    ``escalations``: round.escalations)."""
    nb = [np.zeros(len(r) + 1) for r in routes]
    tl = simulate(inst, routes, nb)
    repairs, since, seen = [], -math.inf, {}
    for _ in range(max_repairs + 1):
        c = scan(tl, oracle, since)
        if c is None:
            break
        fix = _repair(tl, c, oracle) if len(repairs) < max_repairs else None
        if fix is not None:
            fix = _escalate(tl, fix, seen, escalations)
        if fix is None:
            tl = sequential_clearest(inst, routes, oracle)
            break
        boom, k, until, rec = fix
        rec["wait_s"] = until - float(tl.move_start[boom][k])
        repairs.append(rec)
        nb[boom][k] = max(nb[boom][k], until)
        new = simulate(inst, routes, nb)
        changed = [np.flatnonzero(o != n) for o, n in zip(tl.move_start, new.move_start, strict=True)]
        since = min((float(o[ch].min()) for o, ch in zip(tl.move_start, changed, strict=True) if len(ch)),
                    default=since)
        tl = new
    tl.repairs = repairs
    if measure:
        _, tl.conflicts_left, tl.min_clearance = scan(tl, oracle, full=True)
    return tl


def boom_times(inst: Instance, tl: Timeline, b: int) -> dict[str, float]:
    """Drilling, moving and waiting seconds of boom b (waiting: standing between drilling and its
    next move, or at park before its first one; not the idle time at park once it is done)."""
    route, ms, ar = tl.routes[b], tl.move_start[b], tl.arrive[b]
    drilling = float(inst.drill_s[route].sum()) if route else 0.0
    moving = float((ar - ms).sum())
    ready = np.concatenate([[0.0], ar[:-1] + inst.drill_s[route]]) if route else np.zeros(1)
    return {"drilling_s": drilling, "moving_s": moving, "waiting_s": float((ms - ready).sum()),
            "holes": len(route), "end_s": float(ar[-1])}
