"""Exact waits for fixed routes (pipeline.round.waits): CP-SAT's schedule against a brute
force over every order of the conflicting segment pairs, computed here from scratch."""

import itertools
import math

import numpy as np
import pytest
from test_round import SetOracle, synthetic

from pipeline.round.settings import RoundSettings
from pipeline.round.timeline import resolve, scan
from pipeline.round.waits import exact_waits, place_waits


def integer_ms(inst):
    """The same instance with every duration a whole number of milliseconds (so the model's ceil and
    floor are exact and its optimum is the true one)."""
    from dataclasses import replace
    return replace(inst, move_s=np.round(inst.move_s, 3), phases=np.round(inst.phases, 3))


def brute_force(inst, routes, bad):
    """The shortest conflict-free makespan of ``routes`` (two booms) with waits before moves: every
    order of every pair of segments whose nodes conflict (the set oracle's rule: a standing's node,
    or either end of a move), each schedule the earliest one by longest paths (independent code)."""
    H = inst.n_holes
    segs = []  # per boom: (kind, k, nodes)
    for r in routes:
        nodes = [H, *r, H]
        s = [("stand", -1, {H})]
        for k in range(len(r) + 1):
            s.append(("move", k, {nodes[k], nodes[k + 1]}))
            s.append(("stand", k, {nodes[k + 1]}))
        segs.append((nodes, s))
    pairs = [(p, q) for p in segs[0][1] for q in segs[1][1]
             if any((x, y) in bad for x in p[2] for y in q[2])]
    best = math.inf
    for order in itertools.product((0, 1), repeat=len(pairs)):
        starts = [np.zeros(len(r) + 1) for r in routes]
        for _ in range(200):  # longest path by relaxation; a cycle never settles: infeasible
            old = [s.copy() for s in starts]
            for b, r in enumerate(routes):
                nodes = segs[b][0]
                for k in range(1, len(r) + 1):
                    ready = starts[b][k - 1] + inst.move_s[b, nodes[k - 1], nodes[k]] + inst.drill_s[r[k - 1]]
                    starts[b][k] = max(starts[b][k], ready)

            for (p, q), o in zip(pairs, order, strict=True):
                first, fb, then, tb = (p, 0, q, 1) if o == 0 else (q, 1, p, 0)
                end = _span(inst, fb, segs[fb][0], starts[fb], first)[1]
                kind, k, _ = then
                if math.isinf(end):
                    starts[tb][:] = math.inf
                    continue
                # the later segment starts after the first ends: delay the move that starts it
                m = k if kind == "move" else k
                if kind == "stand" and k < 0:  # the first standing starts at 0: cannot follow anything
                    starts[tb][:] = math.inf
                    continue
                lead = (inst.move_s[tb, segs[tb][0][k], segs[tb][0][k + 1]] if kind == "stand" else 0.0)
                starts[tb][m] = max(starts[tb][m], end - lead)
            if all(np.array_equal(a, b) for a, b in zip(old, starts, strict=True)) or any(
                    np.isinf(s).any() for s in starts):
                break
        else:
            continue
        if any(np.isinf(s).any() for s in starts):
            continue
        ends = [starts[b][-1] + inst.move_s[b, segs[b][0][-2], H] for b in range(2)]
        best = min(best, max(ends))
    return best, len(pairs)


def _span(inst, b, nodes, starts, seg):
    """(start, end) of one segment of boom b, whose route visits ``nodes``, with move starts ``starts``."""
    kind, k, _ = seg
    if kind == "move":
        return starts[k], starts[k] + inst.move_s[b, nodes[k], nodes[k + 1]]
    t0 = 0.0 if k < 0 else starts[k] + inst.move_s[b, nodes[k], nodes[k + 1]]
    t1 = math.inf if k == len(nodes) - 2 else starts[k + 1]
    return t0, t1


@pytest.mark.parametrize("seed", range(2))  # one, then two conflicting hole pairs
def test_exact_waits_are_the_brute_force_optimum(seed):
    g = np.random.default_rng(7 + seed)
    inst = integer_ms(synthetic(H=6, B=2, seed=seed))
    routes = [[h for h in range(6) if h % 2 == 0 and inst.reach[0, h]],
              [h for h in range(6) if h % 2 == 1 and inst.reach[1, h]]]
    assert routes[0] and routes[1]
    # one or two conflicting hole pairs: 9 or more segment pairs (standing and the moves in and out)
    bad = {(int(g.choice(routes[0])), int(g.choice(routes[1]))) for _ in range(1 + seed % 2)}
    oracle = SetOracle({(0, 1): bad})
    want, n_pairs = brute_force(inst, routes, bad)
    assert 0 < n_pairs <= 15 and math.isfinite(want)
    res = exact_waits(inst, routes, oracle)
    assert res.status == "optimal" and res.conflicts_left == 0
    assert scan(res.timeline, oracle) is None  # conflict-free, by the timeline's own scan
    assert res.timeline.makespan == pytest.approx(want, abs=1e-4)
    assert res.bound_s <= res.timeline.makespan + 1e-3  # the certificate bounds the answer


@pytest.mark.parametrize("seed", range(3))
def test_exact_waits_never_lose_to_the_greedy_repair(seed):
    g = np.random.default_rng(100 + seed)
    inst = synthetic(H=24, B=2, seed=seed)
    bad = {(0, 1): {(int(i), int(j)) for i, j in g.integers(0, inst.n_holes, (3 * inst.n_holes, 2))}}
    oracle = SetOracle(bad)
    routes = [[h for h in range(24) if inst.reach[0, h] and (h % 2 == 0 or not inst.reach[1, h])],
              [h for h in range(24) if inst.reach[1, h] and h % 2 == 1 and not
               (inst.reach[0, h] and h % 2 == 0)]]
    routes[1] = [h for h in routes[1] if h not in routes[0]]
    greedy = resolve(inst, routes, oracle)
    tl = place_waits(inst, routes, oracle, RoundSettings(waits="best"))
    assert scan(tl, oracle) is None and tl.conflicts_left == 0
    assert tl.makespan <= greedy.makespan + 1e-9
    exact = place_waits(inst, routes, oracle, RoundSettings(waits="exact"))
    assert exact.waits["method"] == "exact" and exact.waits["status"] in ("optimal", "feasible")
    for rec in exact.repairs:  # every wait names the segment it waits for, of the other boom
        assert rec["wait_s"] > 0 and rec["booms"][0] != rec["booms"][1]


def test_greedy_is_the_default_and_unknown_methods_are_refused():
    from pipeline.core.config import load_group_file
    from pipeline.core.errors import ConfigError
    from pipeline.round.settings import parse_round
    assert parse_round(load_group_file("round", "default")).waits == "greedy"
    with pytest.raises(ConfigError, match="waits"):
        parse_round({"waits": "fastest"})


CHILD = """
import signal, sys
sys.path.insert(0, "tests")
import numpy as np
from test_round import SetOracle, synthetic
from pipeline.round.waits import exact_waits
def stop(*_):
    print("handler", flush=True)
    sys.exit(7)
signal.signal(signal.SIGINT, stop)
inst = synthetic(H=30, B=2, seed=0)
g = np.random.default_rng(0)
oracle = SetOracle({(0, 1): {(int(i), int(j)) for i, j in g.integers(0, 30, (90, 2))}})
routes = [[h for h in range(30) if inst.reach[0, h] and h % 2 == 0],
          [h for h in range(30) if inst.reach[1, h] and (h % 2 == 1 or not inst.reach[0, h])]]
print("solving", flush=True)
while True:  # CP-SAT solves back to back: the signal lands inside one almost surely
    exact_waits(inst, routes, oracle, deterministic_s=5.0)
"""


def test_ctrl_c_during_the_exact_waits_reaches_the_callers_handler():
    """CP-SAT catches SIGINT by default (and the process then dies with 130, past the stage's handler,
    leaving its MLflow run RUNNING): the waits' solver must leave it to the caller."""
    import signal
    import subprocess
    import sys
    import time

    from pipeline.core.config import PROJECT_ROOT
    proc = subprocess.Popen([sys.executable, "-c", CHILD], cwd=PROJECT_ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        assert proc.stdout.readline().strip() == "solving"
        time.sleep(1.0)
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=60)
    finally:
        proc.kill()  # a solver that ate the signal would solve on
    assert proc.returncode == 7 and "handler" in out, (proc.returncode, out)
