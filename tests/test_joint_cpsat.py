"""The joint CP-SAT model of the round: its optimum against a brute force on tiny planted
instances, and what every answer must keep (conflicting pairs apart, reach, precedence).

The brute force is independent of the model: every allocation, every order per boom and every order
of each conflicting pair, each timed as the least solution of its difference constraints (Bellman-Ford
longest paths; a positive cycle: infeasible). A boom stands at a hole from its arrival until it moves
on (a wait is a later start of the move: the timeline's rule), so a conflicting pair's standing
intervals are what may not overlap.
"""

import itertools

import numpy as np
import pytest

from pipeline.rig_benchmarks.joint_cpsat import JointSettings, joint_round, standing_conflicts
from pipeline.round.problem import Instance, drill_phases

SETTINGS = JointSettings(max_deterministic_time=5.0)


def planted(seed: int, precedence=()):
    """6 holes, 2 booms: boom 0 reaches 0-3, boom 1 reaches 1-4, none reaches 5; integer seconds (the
    model's ms exactly); a planted standing-conflict table."""
    g = np.random.default_rng(seed)
    H, B = 6, 2
    reach = np.zeros((B, H), bool)
    reach[0, :4] = reach[1, 1:5] = True
    drill = g.integers(20, 60, H).astype(float)
    move = g.integers(2, 15, (B, H + 1, H + 1)).astype(float)
    move = np.maximum(move, move.transpose(0, 2, 1))  # symmetric, as joint-space moves are
    move[:, np.arange(H + 1), np.arange(H + 1)] = 0
    phases = drill_phases(np.zeros(H), collaring_s=0.0)
    phases[:, 0] = drill
    inst = Instance(("A", "B"), tuple(f"h{i}" for i in range(H)), reach, phases, move, tuple(precedence))
    table = (g.random((H, H)) < 0.45) & reach[0][:, None] & reach[1][None, :]
    np.fill_diagonal(table, False)
    return inst, {(0, 1): table}


def least_times(edges, n):
    """Least x >= 0 with x[v] >= x[u] + w for every (u, v, w); None on a positive cycle."""
    x = np.zeros(n)
    for _ in range(n + 1):
        changed = False
        for u, v, w in edges:
            if x[u] + w > x[v] + 1e-9:
                x[v], changed = x[u] + w, True
        if not changed:
            return x
    return None


def brute_force(inst: Instance, table: np.ndarray) -> float:
    H, drill, move = inst.n_holes, inst.drill_s, inst.move_s
    holes = [h for h in range(H) if inst.reach[:, h].any()]
    best = np.inf
    for alloc in itertools.product(*[np.flatnonzero(inst.reach[:, h]) for h in holes]):
        mine = [[h for h, b in zip(holes, alloc, strict=True) if b == k] for k in range(2)]
        pairs = [(i, j) for i in mine[0] for j in mine[1] if table[i, j]]
        for r0 in itertools.permutations(mine[0]):
            for r1 in itertools.permutations(mine[1]):
                # variables: start h -> h, leave h -> H + h, end b -> 2H + b
                edges = [(h, H + h, drill[h]) for h in holes]
                for b, r in enumerate((r0, r1)):
                    if not r:
                        continue
                    edges.append((2 * H + 2, r[0], move[b, H, r[0]]))  # node 2H + 2: time zero
                    for u, v in zip(r[:-1], r[1:], strict=True):
                        edges += [(H + u, v, move[b, u, v]), (v, H + u, -move[b, u, v])]  # start_v == leave_u + move
                    edges.append((H + r[-1], 2 * H + b, move[b, r[-1], H]))
                edges += [(i, j, drill[i]) for i, j in inst.precedence]
                for sides in itertools.product((0, 1), repeat=len(pairs)):
                    extra = [(H + i, j, 0.0) if s == 0 else (H + j, i, 0.0)  # i leaves before j arrives, or j before i
                             for (i, j), s in zip(pairs, sides, strict=True)]
                    x = least_times(edges + extra, 2 * H + 3)
                    if x is not None:
                        best = min(best, max(x[2 * H], x[2 * H + 1]))
    return best


def check_answer(inst, conflicts, res):
    """What every answer keeps: each reachable hole once on a boom that reaches it, conflicting pairs
    apart, precedence, and drilling within each boom's standing at the hole."""
    drilled = [h for r in res.routes for h in r]
    assert sorted(drilled) == [h for h in range(inst.n_holes) if inst.reach[:, h].any()]
    for b, r in enumerate(res.routes):
        assert inst.reach[b, r].all(), f"boom {b} got a hole it cannot reach"
    st, lv = res.start_s, res.leave_s
    assert np.all(lv[drilled] >= st[drilled] + inst.drill_s[drilled] - 1e-9)
    on = {h: b for b, r in enumerate(res.routes) for h in r}
    for (a, b), table in conflicts.items():
        for i, j in zip(*np.nonzero(table), strict=True):
            if on.get(i) == a and on.get(j) == b:
                assert lv[i] <= st[j] + 1e-9 or lv[j] <= st[i] + 1e-9, f"conflicting holes {i}, {j} overlap"
    for i, j in inst.precedence:
        assert st[j] >= st[i] + inst.drill_s[i] - 1e-9


@pytest.mark.parametrize("seed", range(3))
def test_optimum_equals_brute_force(seed):
    inst, conflicts = planted(seed)
    res = joint_round(inst, conflicts, SETTINGS)
    assert res.status == "OPTIMAL"
    assert res.makespan_s == pytest.approx(brute_force(inst, conflicts[0, 1]), abs=1e-6)
    assert res.bound_s == pytest.approx(res.makespan_s, abs=1e-6)  # proved: the bound is the optimum
    check_answer(inst, conflicts, res)
    assert 5 not in [h for r in res.routes for h in r]  # no boom reaches it: left out


def test_precedence_and_hint():
    inst, conflicts = planted(7, precedence=((4, 0), (1, 3)))  # 4 only on B, 0 only on A: across booms
    res = joint_round(inst, conflicts, SETTINGS, hint=[[0, 1, 2], [4, 3]])
    assert res.status == "OPTIMAL"
    optimum = brute_force(inst, conflicts[0, 1])
    assert res.makespan_s == pytest.approx(optimum, abs=1e-6)
    assert brute_force(inst, np.zeros_like(conflicts[0, 1])) < optimum  # the planted conflicts cost time here
    check_answer(inst, conflicts, res)


def test_standing_conflicts_from_the_oracle():
    class Standing:  # the oracle's standing matrix, (H + 1, H + 1) clearance less d_boom
        def standing(self, a, b):
            c = np.ones((4, 4))
            c[0, 1], c[2, 2], c[1, 0] = -0.1, -0.2, 0.0  # 0.0: touching d_boom is clear, as the oracle reads it
            return c

    reach = np.array([[True, True, True], [True, True, False]])
    got = standing_conflicts(Standing(), reach)[0, 1]
    want = np.zeros((3, 3), bool)
    want[0, 1] = True  # (2, 2): boom 1 cannot reach hole 2
    assert np.array_equal(got, want)
