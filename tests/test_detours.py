"""Detours of the round: a used move that breaks self or tunnel clearance is re-planned,
and the oracle, the durations and the trajectory rows follow the detour.

Independent values: the batched straight check against :func:`check_path` one move at a time, and
against a five times finer sampling; the detour's clearance re-checked by :func:`check_path`; the
oracle's positions against the path's own; the rows' interpolation against the path at the boom's
frame origins (forward kinematics).
"""

import numpy as np
import pytest
import torch

from pipeline.assembly.rig import build_rig
from pipeline.core.config import load_group_file
from pipeline.motion.checks import check_path, check_straight_moves
from pipeline.motion.moves import plan_move
from pipeline.motion.path import Path, unwrapped
from pipeline.motion.timing import move_time, rig_motions
from pipeline.plans.demo_face import demo_face
from pipeline.plans.reach import reach_table, rig_solvers
from pipeline.round.detours import FAILED, RETRACT, STRAIGHT, MoveBook
from pipeline.round.from_plan import round_instance
from pipeline.round.oracle import _positions
from pipeline.round.problem import Instance, drill_phases
from pipeline.round.seeds import balanced_strips, clear_ends, sweep_routes
from pipeline.round.settings import RoundSettings
from pipeline.solvers.hybrid import HybridSettings

D = torch.float64


@pytest.fixture(scope="module")
def demo_inputs(safety):
    rig = build_rig("twin", load_group_file("tunnel", "horseshoe"), load_group_file("safety", "paper"))
    plan = demo_face(safety=safety)
    reach = reach_table(plan, rig, rig_solvers(rig, lambda b: None, HybridSettings()), "hybrid")
    return rig, plan, reach


@pytest.fixture(scope="module")
def demo(demo_inputs):
    rig, plan, reach = demo_inputs
    motions = rig_motions(load_group_file("motion", "jumbo8"), rig.booms)
    inst, oracle, _ = round_instance(rig, plan, reach, motions, RoundSettings())
    return rig, inst, oracle


@pytest.fixture(scope="module")
def calibrated_demo(demo_inputs):
    """The demo round's instance on `twin` with boom L calibrated (error twists of 0.5 mm and mrad):
    its nodes are the nominal solutions, which is all an oracle-against-oracle test needs."""
    from pipeline.assembly.rig import rig_booms, rig_spec
    from pipeline.calibration.error_model import BoomWithErrors, ErrorLevel, draw_errors

    _, plan, reach = demo_inputs
    booms = dict(rig_booms(rig_spec("twin")))
    booms["L"] = BoomWithErrors(booms["L"], draw_errors(booms["L"], ErrorLevel(0.5, 0.5, 20.0), seed=0))
    rig = build_rig("twin", load_group_file("tunnel", "horseshoe"), load_group_file("safety", "paper"), booms=booms)
    motions = rig_motions(load_group_file("motion", "jumbo8"), rig.booms)
    inst, oracle, _ = round_instance(rig, plan, reach, motions, RoundSettings())
    assert rig.booms[0].kernel is not None and rig.booms[0].kernel.chain[-1].shape[0] > 0  # the calibrated chain
    return rig, inst, oracle


def _moves(inst, b, k):
    """Boom b's moves between consecutive holes it can drill (plan order), the first k."""
    h = np.flatnonzero(inst.reach[b])
    return np.stack([h[:-1], h[1:]], -1)[:k]


def test_straight_check_is_check_path_batched(demo):
    rig, inst, oracle = demo
    b = 0
    uv = _moves(inst, b, 16)
    q = oracle.joints[b]
    qa = q[torch.as_tensor(uv[:, 0])]
    qb = unwrapped(qa, q[torch.as_tensor(uv[:, 1])], oracle.limits[b])
    batch = check_straight_moves(rig, b, qa, qb, chunk=3000)  # several chunks: the chunking is exercised
    fine = check_straight_moves(rig, b, qa, qb, resolution=0.002)
    for k in range(len(uv)):
        one = check_path(rig, b, Path.through(torch.stack([qa[k], qb[k]]), oracle.limits[b]))
        assert float(batch.least["self"][k]) == pytest.approx(one.self, abs=1e-9)
        assert float(batch.least["tunnel"][k]) == pytest.approx(one.tunnel, abs=1e-9)
        assert float(batch.least["boom R"][k]) == pytest.approx(one.boom, abs=1e-9)
        for kind in ("self", "tunnel", "boom R"):  # the floor bounds every instant: a finer sampling
            assert float(batch.floor[kind][k]) <= float(fine.least[kind][k]) + 1e-12
    assert not bool(batch.clear().all()) or not bool(batch.certified().all())  # not vacuous on this face


def _unclear_move(rig, inst, oracle):
    """The first move between consecutive holes that breaks self or tunnel clearance and that the
    ``retract`` detour makes clear: deterministic (OMPL's time-limited search is not; its planned
    detours are tested in tests/test_moves.py)."""
    for b in range(inst.n_booms):
        uv = _moves(inst, b, 200)
        q = oracle.joints[b]
        qa = q[torch.as_tensor(uv[:, 0])]
        qb = unwrapped(qa, q[torch.as_tensor(uv[:, 1])], oracle.limits[b])
        bad = ~check_straight_moves(rig, b, qa, qb).clear(("self", "tunnel"))
        for k in torch.nonzero(bad).flatten().tolist():
            if plan_move(rig, b, qa[k], qb[k], oracle.limits[b], kinds=("retract",)).clear:
                return b, int(uv[k, 0]), int(uv[k, 1])
    raise AssertionError("the demo face has no move between consecutive holes that breaks self or tunnel "
                         "clearance and that a retract makes clear")


def test_book_detours_a_move_that_breaks_clearance_and_the_oracle_follows_it(demo):
    rig, inst, oracle = demo
    b, u, v = _unclear_move(rig, inst, oracle)
    book = MoveBook(oracle, inst.n_holes, RoundSettings())
    routes = [[] for _ in range(inst.n_booms)]
    routes[b] = [u, v]
    new = book.ensure(inst, routes)
    assert book.status[b, u, v] == RETRACT, book.reason.get((b, u, v))  # retract comes first and clears it
    assert book.status[b, inst.n_holes, u] != 0 and book.status[b, v, inst.n_holes] != 0  # park legs looked at
    assert book.status[b, v, u] == book.status[b, u, v]  # the reverse: the same configurations backwards
    path, back = oracle.detour(b, u, v), oracle.detour(b, v, u)
    straight = float(move_time(oracle.joints[b][u], oracle.joints[b][v], oracle.limits[b]))
    assert new.move_s[b, u, v] == pytest.approx(path.duration) and path.duration > straight
    assert back.duration == pytest.approx(path.duration)
    assert inst.move_s[b, u, v] == pytest.approx(straight)  # the input instance is not touched
    c = check_path(rig, b, path)  # re-checked on its own, the other boom at park
    assert c.clear and c.self >= 0 and c.tunnel >= 0, c
    m = rig.booms[b]
    with torch.inference_mode():  # the ends are the holes' configurations (up to full turns)
        for end, node in ((path.waypoints[0], u), (path.waypoints[-1], v), (back.waypoints[-1], u)):
            assert torch.allclose(m.frames(end[None]), m.frames(oracle.joints[b][node][None]), atol=1e-9)

    # the oracle's positions along the move are the detour's, not the straight line's
    t = torch.linspace(0, path.duration, 41, dtype=D)
    motion, speed = oracle.speed_bound(b, np.full(41, u), np.full(41, v))
    got = _positions(motion, torch.arange(41), t)
    assert torch.allclose(got, path.positions(t), atol=1e-12)
    assert float(speed[0]) > 0
    # a straight move beside it in the same batch keeps the straight profile
    motion, _ = oracle.speed_bound(b, np.array([u, inst.n_holes]), np.array([v, u]))
    mid = torch.tensor([path.duration / 2, 0.0], dtype=D)
    assert torch.allclose(_positions(motion, torch.arange(2), mid)[1], oracle.joints[b][inst.n_holes])

    # trajectory rows: linear in t between them, within 1 mm of the detour at every frame origin
    rt, rq = oracle.rows(b, u, v, oracle.joints[b][u])
    ts = torch.linspace(0, path.duration, 400, dtype=D)
    lin = torch.stack([torch.as_tensor(np.interp(ts.numpy(), rt, rq[:, i])) for i in range(rq.shape[1])], -1)
    with torch.inference_mode():
        err = (m.frames(lin)[..., :3, 3] - m.frames(path.positions(ts))[..., :3, 3]).norm(dim=-1).max()
    assert float(err) <= 0.001 + 1e-9
    assert rt[-1] == pytest.approx(path.duration)

    again = book.ensure(new, routes)  # known moves are not planned again
    assert again is new


def test_book_keeps_clear_moves_straight(demo):
    rig, inst, oracle = demo
    book = MoveBook(oracle, inst.n_holes, RoundSettings())
    for b in range(inst.n_booms):
        uv = _moves(inst, b, 12)
        q = oracle.joints[b]
        qa = q[torch.as_tensor(uv[:, 0])]
        qb = unwrapped(qa, q[torch.as_tensor(uv[:, 1])], oracle.limits[b])
        clear = check_straight_moves(rig, b, qa, qb).clear(("self", "tunnel")).numpy()
        routes = [[] for _ in range(inst.n_booms)]
        routes[b] = [int(h) for h in np.unique(uv)]
        book.ensure(inst, routes)
        for (u, v), ok in zip(uv, clear, strict=True):
            assert (book.status[b, u, v] == STRAIGHT) == bool(ok)
            assert (oracle.detour(b, u, v) is None) == bool(ok)


def test_sweep_strips_balance_drilling_and_keep_the_booms_apart():
    g = np.random.default_rng(3)
    H, B = 60, 3
    collars = np.stack([np.full(H, 6.5), g.uniform(-3, 3, H), g.uniform(0.5, 5, H)], 1)
    base_y = np.array([1.6, 0.0, -1.6])
    reach = np.ones((B, H), bool)
    forced = np.argsort(collars[:, 1])[-2:]
    reach[0, forced] = False  # two of the highest holes in y (boom 0's strip) boom 0 cannot drill
    move = np.ones((B, H + 1, H + 1))
    inst = Instance(("L", "M", "R"), tuple(f"h{i}" for i in range(H)), reach, drill_phases(g.uniform(2, 6, H)),
                    move, (), collars, base_y, np.zeros((B, 3)))
    strips = balanced_strips(inst)
    drill = np.array([inst.drill_s[strips == b].sum() for b in range(B)])
    assert np.ptp(drill) <= 2 * inst.drill_s.max()  # within about a hole of the mean each
    y = collars[:, 1]
    assert (strips[forced] == 1).all()  # to the boom nearest in base y that can drill them
    free = np.ones(H, bool)
    free[forced] = False
    assert y[free & (strips == 0)].min() >= y[free & (strips == 1)].max() - 1e-12  # strips in base order
    assert y[strips == 1].min() >= y[strips == 2].max() - 1e-12
    for direction in (-1, 1):
        routes = sweep_routes(inst, direction, band_m=1.0)
        assert sorted(h for r in routes for h in r) == list(range(H))
        for r in routes:  # bands visited in the sweep's direction
            key = -direction * y[r]
            band = np.floor((key - (-direction * y).min()) / 1.0)
            assert (np.diff(band) >= 0).all()


def test_clear_ends_starts_and_ends_each_route_where_park_is_not_blocked():
    """A route whose first (last) hole's move from (to) park is blocked by another boom at park takes the
    nearest hole along it whose park move is clear first (last); the rest keep their order; a route
    with clear ends and one with no clear hole stay as they are; precedence pairs hold."""
    H = 8
    blocked = np.zeros((3, H + 1, H + 1), bool)
    blocked[0, H, [0, 1]] = True  # boom 0: holes 0 and 1 not reachable from park
    blocked[0, [7, 6], H] = True  # ... and 7 and 6 not left for park
    blocked[2, H, :H] = blocked[2, :H, H] = True  # boom 2: nothing clear, nothing to choose
    routes = [list(range(H)), [3, 4, 5], [1, 2]]
    out = clear_ends(routes, blocked)
    assert out[0] == [2, 0, 1, 3, 4, 6, 7, 5]
    assert not blocked[0, H, out[0][0]] and not blocked[0, out[0][-1], H]
    assert out[1] == [3, 4, 5] and out[2] == [1, 2]
    kept = clear_ends(routes, blocked, [(0, 2)])[0]
    assert kept.index(0) < kept.index(2) and sorted(kept) == list(range(H))  # precedence 0 before 2 kept
    assert clear_ends(routes, np.zeros_like(blocked)) == routes


def test_book_refines_a_short_floor_and_fails_it_without_refinement_or_detours(demo):
    """Moves checked every 0.2 m of point travel: those whose samples are clear but whose floor is
    short (the premise) are refined and kept straight with refinements, and without refinement nor
    detours they are failed, with the reason. Every move the book keeps straight has its certified
    floors >= the margins."""
    from pipeline.motion.checks import check_straight_moves

    rig, inst, oracle = demo
    b = 0
    uv = _moves(inst, b, 40)
    q = oracle.joints[b]
    qa = q[torch.as_tensor(uv[:, 0])]
    qb = unwrapped(qa, q[torch.as_tensor(uv[:, 1])], oracle.limits[b])
    coarse = check_straight_moves(rig, b, qa, qb, resolution=0.2)
    kinds = ("self", "tunnel")
    short = (coarse.clear(kinds) & ~coarse.certified(kinds)).numpy()
    assert short.any()  # the premise
    routes = [[] for _ in range(inst.n_booms)]
    routes[b] = [int(h) for h in np.unique(uv)]
    refined = MoveBook(oracle, inst.n_holes, RoundSettings(sample_m=0.2, refinements=6, detours=False))
    refined.ensure(inst, routes)
    plain = MoveBook(oracle, inst.n_holes, RoundSettings(sample_m=0.2, refinements=0, detours=False))
    plain.ensure(inst, routes)
    for (u, v), s in zip(uv, short, strict=True):
        if s:
            assert plain.status[b, u, v] == FAILED and "certified floor short" in plain.reason[(b, u, v)]
    kept = [(u, v) for (u, v), s in zip(uv, short, strict=True) if s and refined.status[b, u, v] == STRAIGHT]
    assert kept  # refinement certified some of them
    fine = check_straight_moves(rig, b, qa, qb, resolution=0.002)  # independent: the floors bound its samples
    for k, (u, v) in enumerate(uv):
        for kind in kinds:
            assert refined.floor[kind][b, u, v] <= float(fine.least[kind][k]) + 1e-12
    for u, v in zip(*np.nonzero(refined.status[b] == STRAIGHT), strict=True):
        assert refined.floor["self"][b, u, v] >= 0 and refined.floor["tunnel"][b, u, v] >= 0
    floors = refined.floors(routes)
    assert floors["self"] is not None and floors["tunnel"] is not None


def test_failed_moves_are_marked_move_unclear_in_the_trajectory(demo):
    """Detours off: a move that breaks clearance is failed, and its rows in the trajectory file are
    ``move_unclear``, every other move's ``move``."""
    from pipeline.round.tables import trajectory_table
    from pipeline.round.timeline import resolve

    rig, inst, oracle = demo
    b, u, v = _unclear_move(rig, inst, oracle)
    routes = [[] for _ in range(inst.n_booms)]
    routes[b] = [u, v]
    book = MoveBook(oracle, inst.n_holes, RoundSettings(detours=False))
    timed = book.ensure(inst, routes)
    counts, failed = book.kinds(routes)
    assert (b, u, v) in failed and counts["failed"] == len(failed) and "round.detours=false" in book.reason[(b, u, v)]
    tl = resolve(timed, routes, oracle)
    traj = trajectory_table(timed, tl, oracle, rig.booms[0].boom.joint_names, failed)
    rows = traj[traj["boom"] == rig.names[b]].reset_index(drop=True)
    ev = rows["event"].tolist()
    assert "move_unclear" in ev
    # the rows from hole u's retract to hole v's collar are the failed move's
    i_ret = max(i for i, e in enumerate(ev) if e == "retract" and rows["hole_id"][i] == inst.hole_ids[u])
    i_col = ev.index("collar", i_ret)
    assert set(ev[i_ret + 1:i_col]) == {"move_unclear"}
    n_unclear = sum(e == "move_unclear" for e in ev)
    assert n_unclear >= i_col - i_ret - 1


@pytest.mark.parametrize("which", ["demo", "calibrated_demo"])
def test_compiled_advancement_is_the_torch_one_to_the_last_bit(which, request):
    """The oracle's advancement compiled (pipeline/round/compiled_oracle.py) against its torch version on
    the same pairs of segments: standing, straight moves, park legs and a detour, both boom orders, on the
    nominal rig and with one boom calibrated (the kernel must carry its error transforms). The first
    conflicts, least clearances and evaluation counts are equal, not close: every operation is the same
    in the same order."""
    rig, inst, oracle = request.getfixturevalue(which)
    b, u, v = _unclear_move(rig, inst, oracle)
    routes = [[] for _ in range(inst.n_booms)]
    routes[b] = [u, v]
    MoveBook(oracle, inst.n_holes, RoundSettings()).ensure(inst, routes)
    assert oracle.detour(b, u, v) is not None
    gen = np.random.default_rng(3)
    n, H = 600, inst.n_holes

    def segments(boom):
        nodes = np.append(np.flatnonzero(inst.reach[boom]), H)
        su, sv = gen.choice(nodes, n), gen.choice(nodes, n)
        still = gen.random(n) < 0.2
        sv[still] = su[still]
        if boom == b:  # the detoured move, both ways
            on, fwd = gen.random(n) < 0.2, gen.random(n) < 0.5
            su[on & fwd], sv[on & fwd] = u, v
            su[on & ~fwd], sv[on & ~fwd] = v, u
        return {"t0": gen.uniform(0, 6, n), "u": su, "v": sv}

    seg = [segments(0), segments(1)]
    lo = gen.uniform(0, 8, n)
    hi = lo + gen.uniform(0, 12, n)
    answers = {}
    for compiled in (True, False):
        oracle.compiled = compiled
        before = oracle.evaluations
        try:
            answers[compiled] = (*oracle.check(0, seg[0], 1, seg[1], lo, hi),
                                 *oracle.check(1, seg[1], 0, seg[0], lo, hi), oracle.evaluations - before)
        finally:
            oracle.compiled = True
    for got, want in zip(answers[True], answers[False], strict=True):
        np.testing.assert_array_equal(got, want)
    first, least = answers[True][:2]
    moving = ~((seg[0]["u"] == seg[0]["v"]) & (seg[1]["u"] == seg[1]["v"]))
    assert np.isfinite(first[moving]).sum() > 10 and np.isinf(first[moving]).sum() > 10  # conflicts and clear pairs
    assert np.isfinite(least[moving]).all()
