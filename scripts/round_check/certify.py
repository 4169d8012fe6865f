"""A planned round's robustness certified exactly: d_boom for *every* choice of drilling durations, not
for sampled ones.

**Segments.** Each boom's timeline is cut into segments, each a fixed set of configurations whatever
the durations:

- every *action* (a move: its rows between its ``t_start`` and ``t_end``, whenever it starts; a drill:
  its one configuration, however long it lasts);
- every *wait that can last*: the boom standing where its previous action left it (at park before its
  first action) before an action that may be held up. Only an interlock or a zone can hold an action
  up, so these are the waits before an action that enters a zone (a section's first action) and before
  one that has an interlock whose action is not already over when the boom's previous action ends (an
  interlock after an action ``p`` of another boom, where no chain of interlocks and sequences takes
  ``p`` to the boom's previous action). Any other wait lasts no time;
- the *final stand* at park after the boom's last action, until the round ends (a boom without
  actions stands at park throughout).

**Events and "ordered".** Every segment starts and ends at an event: action k starts at ``S(k)`` and
ends at ``E(k)``; the wait before k from ``E(k - 1)`` (t = 0 before the first action) to ``S(k)``; the
final stand from ``E(last)`` to the end of the round (it never ends before anything). Segment A of boom
a is *ordered before* segment B of boom b when A's end precedes B's start (``<=``) in every execution
of the round for any positive duration of *every* action. That is decided on the dependency graph
(each boom's sequence and the interlocks): ``R[u, v]``, a path of one or more edges from u to v, i.e.
``E(u) <= S(v)`` in every execution (an action starts once its predecessors ended, and lasts > 0), and

- ``E(u) <= S(x)``  iff  ``R[u, x]``;
- ``E(u) <= E(y)``  iff  ``u = y`` or ``R[u, y]``;
- a wait before v ends at ``S(v)``; while it lasts (has a length) v is held by one of its *holders*, the
  interlocks' actions p of v that may end after v's previous action (``p`` not ``R[p, prev(v)]``), and
  ``S(v) = E(p)`` for the last of them to end. So the wait ends before ``S(x)`` whenever it lasts iff
  every holder p has ``R[p, x]``, and before ``E(y)`` iff every holder has ``p = y`` or ``R[p, y]``. A
  wait that lasts no time is one instant, where the boom is also at the end of its previous action and
  at the start of v (checked with those). A zone entry may wait for its zone, too: its wait ends before
  ``S(x)`` (``E(y)``) only for ``R[v, x]`` (``v = y`` or ``R[v, y]``);
- nothing is before t = 0 and nothing comes after the end of the round.

These are exact for free durations of every action (with the waits as said); moves keep their planned
durations, which can order a pair that the graph does not (a move of one boom ending before the other
has got through a drill and a longer move), or hold two moves in lockstep (both started by the end of
one action): such a pair is checked all the same, conservatively (a false alarm at worst, never a
missed overlap; and a clearance that rests on moves taking exactly their planned time is not taken on
trust). Two segments of different booms that are ordered neither way can overlap in
time for some durations (the pair is *unordered*); ordered ones never do. Whatever the durations,
every instant lies in a segment of each boom, and two segments that touch at one instant only need no
check: distances are continuous in time, so a round clear at every other instant is clear there too.

**Zones** (``<stem>_zones.csv``): a boom is inside a zone from the start of its section's first action
to the end of its last; no two booms are inside one zone at once. So two segments inside sections of
one zone (a section's actions, and the waits before its actions after the first) never overlap and are
not checked; the wait before a section's first action can last (the boom stands outside, waiting for
the zone). A zone can also deadlock: boom b inside its section can wait, through interlocks, for the
end of a's action that enters the same zone (``R[entry_a, last_b]``) while b may have got in first
(not ``R[entry_a, entry_b]``): reported, for every pair of sections. Circular waits through several
zones (or three booms) are found by exploring every interleaving (:mod:`round_check.interleavings`:
each boom's progress a digit, every order of entering the zones tried; not explored beyond 50 M
states, then said as not certified); the draws (:func:`round_check.execute.execute_zones`) report those
they meet too.

**The check.** Every unordered pair must keep d_boom between every configuration of one segment and
every configuration of the other (the whole swept set against the whole swept set, not only at equal
times): that is the least distance of the two episodes' sets, which :func:`round_check.episodes.floors`
certifies between samples (branch and bound over time cells, each cell a sampled configuration and the
lever-arm bound of how far any body point moves within it; a cell pair's floor is the sampled capsule
distance less both radii). A pair whose floor is below d_boom is a violation when a sample is (the two
segments do come that close, and some durations make them overlap), and "not certified" when no sample
is but the floor stays below; either fails the round (exit 1).
"""

from __future__ import annotations

import time
from itertools import combinations

import numpy as np

from .actions import Actions, Interlocks, Zones
from .episodes import Floors
from .episodes import least as least_distance
from .execute import Graph
from .interleavings import explore

MAX_LISTED = 200  # violating pairs listed in the JSON (all are counted)
MAX_MESSAGES = 20

DEFINITION = ("segments: each action, each wait that can last (before an action with an interlock on another "
              "boom's action not already over, or entering a zone) and the final stand at park; two segments of "
              "different booms are ordered when the dependency graph (sequences and interlocks) makes one end "
              "before the other starts for any positive durations of every action; every unordered pair (not "
              "both inside sections of one zone) must keep d_boom between all configurations of one and all of "
              "the other, certified between samples")


def reach(g: Graph, n: int) -> np.ndarray:
    """``(n, n)`` bool: ``R[u, v]`` iff a path of one or more edges (sequence, interlock) leads from u to v.
    Column by column in the graph's level order (each action after its predecessors), one OR per slot."""
    R = np.zeros((n + 1, n + 1), bool)  # index n: the predecessors' padding, reaches nothing
    for level in g.levels:
        for s in range(g.preds.shape[1]):
            p = g.preds[level, s]
            R[:, level] |= R[:, p]
            R[p, level] = True
    R[n, :] = False
    return R[:n, :n]


class Order:
    """Which events surely precede which (module docstring). Events: ``S(k) = k``, ``E(k) = n + k``,
    t = 0 is ``2n``, the end of the round ``2n + 1``; ``before[x, y]``: x <= y in every execution."""

    def __init__(self, acts: Actions, g: Graph, zones: Zones):
        n = len(acts)
        self.n = n
        R = reach(g, n)
        eye = np.eye(n, dtype=bool)
        prev = acts.previous
        entry = zones.entries() if len(zones) else np.zeros(0, np.int64)
        # the wait before k can last when an interlock of k may end after k's previous action: its *holders*
        holders = [[int(p) for p in g.preds[k] if p < n and p != prev[k] and (prev[k] < 0 or not R[p, prev[k]])]
                   for k in range(n)]
        lasting = np.array([bool(h) for h in holders], bool)
        lasting[entry] = True
        # a wait that lasts ends when its last holder ends: S(k) <= y for every durations that give it a length
        # iff every holder's end is <= y (S(k) = E(holder) then); a zone entry may also wait for its zone, so
        # only k's own successors are surely after it
        s_s, s_e = np.zeros((n, n), bool), np.zeros((n, n), bool)
        for k in np.flatnonzero(lasting):
            if k in entry or not holders[k]:
                s_s[k], s_e[k] = R[k] | eye[k], R[k] | eye[k]
            else:
                s_s[k] = R[holders[k]].all(0)
                s_e[k] = (R[holders[k]] | eye[holders[k]]).all(0)
        M = np.zeros((2 * n + 2, 2 * n + 2), bool)
        M[:n, :n], M[:n, n:2 * n] = s_s, s_e
        M[n:2 * n, :n], M[n:2 * n, n:2 * n] = R, R | eye
        self.before, self.R, self.entry, self.lasting, self.holders = M, R, entry, lasting, holders


class Segments:
    """One boom's segments: their episodes (``2p`` the pause before action p, ``2i + 1`` action i; see
    :mod:`round_check.episodes`), start and end events (:class:`Order`), and names."""

    def __init__(self, acts: Actions, b: int, order: Order, zones: Zones):
        n, g0 = order.n, int(acts.first[b])
        m = int(acts.first[b + 1]) - g0
        ep, s_ev, e_ev = [], [], []
        for p in range(m + 1):
            if p == m:  # the final stand (the whole round for a boom without actions)
                ep.append(2 * p)
                s_ev.append(2 * n if m == 0 else n + g0 + m - 1)
                e_ev.append(2 * n + 1)
            elif order.lasting[g0 + p]:
                ep.append(2 * p)
                s_ev.append(2 * n if p == 0 else n + g0 + p - 1)
                e_ev.append(g0 + p)
            if p < m:
                ep.append(2 * p + 1)
                s_ev.append(g0 + p)
                e_ev.append(n + g0 + p)
        self.boom, self.m, self.g0 = b, m, g0
        self.episode, self.start, self.end = np.array(ep, np.int64), np.array(s_ev, np.int64), np.array(e_ev, np.int64)
        self.zones = sorted(set(zones.zone))
        inside = np.zeros((len(self.zones), len(ep)), bool)
        for s in np.flatnonzero(zones.boom == b):
            lo, hi = int(zones.first[s]) - g0, int(zones.last[s]) - g0  # actions lo..hi, the waits before lo+1..hi
            e = self.episode
            inside[self.zones.index(zones.zone[s])] |= (e >= 2 * lo + 1) & (e <= 2 * hi + 1)
        self.inside = inside

    def name(self, acts: Actions, i: int) -> str:
        e = int(self.episode[i])
        if e % 2:
            return acts.name(self.g0 + e // 2)
        p, who = e // 2, acts.booms[self.boom]
        if p == self.m:
            return f"{who} at park after its last action" if self.m else f"{who} at park (no actions)"
        where = "at park" if p == 0 else f"where {acts.name(self.g0 + p - 1)} left it"
        return f"{who} standing {where}, before {acts.name(self.g0 + p)}"


def certify(acts: Actions, locks: Interlocks, zones: Zones, g: Graph, floors: dict[tuple[int, int], Floors],
            d_boom: float, cells: dict | None = None, tol: float = 1e-3) -> tuple[dict, list[str], list[str]]:
    """The certification (module docstring): its JSON, its violation messages and its not-certified ones.
    ``floors[(a, b)]``: the episode floors of booms a < b (rig order of ``acts.booms``); ``cells``: their
    time cells (:class:`round_check.episodes.Cells`), for the least distance over the unordered pairs to
    ``tol`` (without them, the least floor, which the floors' search leaves just above d_boom). The graph
    must have no cycle (a deadlock is reported before)."""
    t0 = time.perf_counter()
    order = Order(acts, g, zones)
    segs = [Segments(acts, b, order, zones) for b in range(len(acts.booms))]
    M = order.before
    msgs, unclear, listed, listed_unclear = [], [], [], []
    n_unordered = n_zone = n_checked = n_viol = n_unclear = 0
    least = least_s = np.inf  # over the unordered pairs checked: a certified lower bound, the least sample
    least_s_pair = None
    for a, b in combinations(range(len(acts.booms)), 2):
        A, Bs, fl = segs[a], segs[b], floors[(a, b)]
        ab = M[np.ix_(A.end, Bs.start)]  # A's segment ends before B's starts, always
        ba = M[np.ix_(Bs.end, A.start)].T
        free = ~ab & ~ba
        zoned = free & ((A.inside.T.astype(np.int64) @ Bs.inside.astype(np.int64)) > 0)  # zones in one order
        check = free & ~zoned
        n_unordered += int(free.sum())
        n_zone += int(zoned.sum())
        n_checked += int(check.sum())
        if not check.any():
            continue
        ea, eb = A.episode, Bs.episode
        floor = fl.floor[np.ix_(ea, eb)]
        below = fl.below[np.ix_(ea, eb)]
        near = fl.least[np.ix_(ea, eb)]
        at = fl.least_at[np.ix_(ea, eb)]
        if cells is not None:  # the least distance over the pair's unordered segments, to tol
            ii, jj = np.nonzero(check)
            lb, ub, at_, _ = least_distance(cells[a], cells[b], ea[ii], eb[jj], tol)
            if lb < least:
                least = lb
            if ub < least_s:
                i, j = int(np.flatnonzero(ea == at_[0])[0]), int(np.flatnonzero(eb == at_[1])[0])
                least_s, least_s_pair = ub, (A.name(acts, i), Bs.name(acts, j))
        else:
            f = np.where(check, floor, np.inf)
            least = min(least, float(f.min()))
            s_ = np.where(check, near, np.inf)
            if s_.min() < least_s:
                i, j = np.unravel_index(int(s_.argmin()), s_.shape)
                least_s, least_s_pair = float(s_[i, j]), (A.name(acts, i), Bs.name(acts, j))
        for i, j in np.argwhere(check & (floor < d_boom)):
            who = f"booms {acts.booms[a]} and {acts.booms[b]}: {A.name(acts, i)} and {Bs.name(acts, j)}"
            lo, dist, where = float(floor[i, j]), float(near[i, j]), (float(at[i, j, 0]), float(at[i, j, 1]))
            if cells is not None and len(listed) + len(listed_unclear) < MAX_LISTED:  # the pair's own least, to tol
                lo, dist, _, where = least_distance(cells[a], cells[b], ea[i:i + 1], eb[j:j + 1], tol)
            near[i, j], at[i, j] = dist, where
            entry = {"booms": [acts.booms[a], acts.booms[b]], "segments": [A.name(acts, i), Bs.name(acts, j)],
                     "episodes": [int(ea[i]), int(eb[j])], "distance_m": dist, "clearance_m": dist - d_boom,
                     "certified_floor_m": lo, "at_planned_s": list(where)}
            if below[i, j]:
                n_viol += 1
                if len(listed) < MAX_LISTED:
                    listed.append(entry)
                if len(msgs) < MAX_MESSAGES:
                    msgs.append(f"certified: {who}: no chain of actions and interlocks makes one end before the other "
                                f"starts, so they can overlap, and they come {near[i, j]:.5f} m apart (< d_boom "
                                f"{d_boom:g} m: {A.name(acts, i)} as at t={at[i, j, 0]:.4f} s, {Bs.name(acts, j)} as "
                                f"at t={at[i, j, 1]:.4f} s of the planned clock)")
            else:
                n_unclear += 1
                if len(listed_unclear) < MAX_LISTED:
                    listed_unclear.append(entry)
                if len(unclear) < MAX_MESSAGES:
                    unclear.append(f"certified: {who}: unordered, and their distance is not certified: floor "
                                   f"{floor[i, j]:.5f} m < d_boom {d_boom:g} m though every sample is clear (least "
                                   f"{near[i, j]:.5f} m)")
    if n_viol > len(msgs):
        msgs.append(f"certified: {n_viol - len(msgs)} more unordered pairs of segments come within d_boom")
    if n_unclear > len(unclear):
        unclear.append(f"certified: {n_unclear - len(unclear)} more unordered pairs not certified")
    dead = zone_deadlocks(acts, zones, order)
    every = explore(acts, locks, zones) if len(zones) else {"explored": True, "states": None, "deadlock": None}
    if every["deadlock"] is not None:  # through several zones or booms, in some order of entries
        dead.append(f"zone deadlock: in some order of entering the zones no boom can go on, standing before "
                    f"{', '.join(every['deadlock'])}")
    if not every["explored"]:
        unclear.append(f"certified: deadlock over every order of entering the zones not explored: {every['why']}")
    msgs += dead[:MAX_MESSAGES]
    out = {
        "definition": DEFINITION,
        "segments": {acts.booms[s.boom]: {"actions": s.m, "lasting_waits": int(np.sum(s.episode[:-1] % 2 == 0)),
                                          "final_stand": 1} for s in segs},
        "unordered_pairs": n_unordered, "zone_excluded_pairs": n_zone, "pairs_checked": n_checked,
        "least_certified_distance_m": None if not np.isfinite(least) else least,
        "least_certified_clearance_m": None if not np.isfinite(least) else least - d_boom,
        "least_sampled_distance_m": None if not np.isfinite(least_s) else least_s,
        "least_pair": list(least_s_pair) if least_s_pair else None,
        "least_tolerance_m": tol if cells is not None else None,
        "violating_pairs": n_viol, "violating": listed, "not_certified_pairs": n_unclear,
        "not_certified": listed_unclear, "zones": {"sections": len(zones), "zones": len(set(zones.zone)),
                                                   "file": str(zones.path) if zones.path else None,
                                                   "possible_deadlocks": len(dead),
                                                   "interleavings_explored": every["explored"],
                                                   "states": every["states"]},
        "time_s": time.perf_counter() - t0,
    }
    return out, msgs, unclear


def zone_deadlocks(acts: Actions, zones: Zones, order: Order) -> list[str]:
    """Pairs of sections of one zone that can deadlock (module docstring): b inside its section waits, by
    the interlocks, for a's action entering the zone, and b may have entered first."""
    R, out = order.R, []
    for s, t in combinations(range(len(zones)), 2):
        if zones.zone[s] != zones.zone[t] or zones.boom[s] == zones.boom[t]:
            continue
        for x, y in ((s, t), (t, s)):  # x's boom stands outside, y's is inside
            ex, ey, ly = int(zones.first[x]), int(zones.first[y]), int(zones.last[y])
            if R[ex, ly] and not R[ex, ey]:
                out.append(f"zone deadlock: {acts.booms[zones.boom[y]]} may enter {zones.section(y)} first and then "
                           f"wait inside it (before {acts.name(ly)} ends) for {acts.name(ex)}, which enters the same "
                           f"zone ({zones.section(x)}): that boom cannot go in while the other is inside")
    return out
