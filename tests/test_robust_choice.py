"""Choosing the round that stands least (docs/round.md, "Choosing the round that stands least"): which
candidates of the planning are compared, which one is kept, and on which draws."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from pipeline.events.draws import DrawSettings
from pipeline.events.robust_round import pick_draws, robust_choice
from pipeline.round.planner import RoundPlan, near_best, time_more_sweeps
from pipeline.round.timeline import Timeline


def _tl(makespan: float, hole: int, conflicts: int = 0, failed: int = 0, sequential: bool = False) -> Timeline:
    return Timeline(routes=[[hole], []], move_start=[np.array([0.0, makespan - 1.0]), np.array([0.0])],
                    arrive=[np.array([1.0, makespan]), np.array([1.0])], park=9, conflicts_left=conflicts,
                    failed_moves=failed, sequential=sequential)


def _plan(best: Timeline, timed: dict) -> RoundPlan:
    return RoundPlan(best, [], 0.0, 1, timed=timed)


def test_near_best_keeps_the_best_first_then_the_shortest_as_good_on_every_count():
    best = _tl(1000.0, 0)
    timed = {"seed a": _tl(1004.0, 1), "seed b": _tl(1002.0, 2), "same routes": _tl(1001.0, 0),
             "too long": _tl(1006.0, 3), "a conflict left": _tl(1000.5, 4, conflicts=1),
             "a failed move": _tl(1000.5, 5, failed=1), "one boom at a time": _tl(1000.5, 6, sequential=True),
             "routing 0": _tl(1003.0, 7)}
    got = near_best(_plan(best, timed), 0.005, 10)
    assert [label for label, _ in got] == ["best", "seed b", "routing 0", "seed a"]
    assert got[0][1] is best
    assert [label for label, _ in near_best(_plan(best, timed), 0.005, 2)] == ["best", "seed b"]
    assert [label for label, _ in near_best(_plan(best, timed), 0.0, 10)] == ["best"]


def test_near_best_of_a_best_with_a_conflict_left_compares_only_rounds_as_bad():
    best = _tl(1000.0, 0, conflicts=2)
    timed = {"clear": _tl(1001.0, 1), "as bad": _tl(1002.0, 2, conflicts=2)}
    assert [label for label, _ in near_best(_plan(best, timed), 0.01, 10)] == ["best", "as bad"]


def _executed(nominal: float, p95_ratio: float, standing: float, robust: bool = True, deadlocked: bool = False):
    random = None if deadlocked else {"makespan_ratio_p95": p95_ratio, "standing_share_p95": standing}
    return SimpleNamespace(extra={"pick": {"nominal_makespan_s": nominal, "random": random}},
                           summary={"robust": robust})


def test_the_round_kept_stands_least_within_the_slack_of_the_best():
    choose = robust_choice(0.005, 0.0)
    best = _executed(1000.0, 1.10, 0.20)
    k, record = choose([best, _executed(1001.0, 1.10, 0.12), _executed(1003.0, 1.09, 0.05),
                        _executed(1004.0, 1.10, 0.09)])
    assert k == 2
    assert [f["standing_p95"] for f in record["figures"]] == [0.20, 0.12, 0.05, 0.09]
    # equal standing: the earlier (shorter) round stays
    assert choose([best, _executed(1003.0, 1.10, 0.05), _executed(1004.0, 1.10, 0.05)])[0] == 1
    assert choose([best, _executed(1000.0, 1.10, 0.20)])[0] == 0


def test_a_longer_round_is_kept_only_for_a_gain_of_at_least_min_gain():
    best = _executed(1000.0, 1.10, 0.20)
    rounds = [best, _executed(1002.0, 1.10, 0.094), _executed(1004.0, 1.10, 0.091)]
    assert robust_choice(0.005, 0.005)(rounds)[0] == 1  # 0.3 points more for 0.2 % longer: not bought
    assert robust_choice(0.005, 0.002)(rounds)[0] == 2
    assert robust_choice(0.005, 0.2)(rounds)[0] == 0
    assert robust_choice(0.005, 0.106)(rounds)[0] == 1


@pytest.mark.parametrize("other, why", [
    (_executed(1005.1, 1.10, 0.01), "nominal makespan beyond the slack"),
    (_executed(1000.0, 1.106, 0.01), "draws' p95 makespan beyond the slack"),
    (_executed(1000.0, 1.10, 0.01, robust=False), "not robust"),
    (_executed(1000.0, 1.10, 0.01, deadlocked=True), "a draw deadlocks"),
])
def test_a_round_that_stands_less_is_passed_over_when(other, why):
    choose = robust_choice(0.005, 0.0)
    assert choose([_executed(1000.0, 1.10, 0.20), other])[0] == 0, why


def test_the_best_is_kept_when_its_own_draws_deadlock():
    # nothing to hold the others against: the planner's best stands as the stage would report it alone
    choose = robust_choice(0.005, 0.0)
    assert choose([_executed(1000.0, 1.10, 0.20, deadlocked=True), _executed(1000.0, 1.10, 0.01)])[0] == 0


def test_rounds_are_compared_on_draws_other_than_the_ones_reported():
    from pipeline.events.actions import Actions
    from pipeline.events.draws import draws

    acts = Actions(booms=("L", "R"), hole_ids=("H1", "H2"), boom=np.array([0, 0, 0, 1, 1, 1]),
                   index=np.array([0, 1, 2, 0, 1, 2]), kind=np.array(["move", "drill", "move"] * 2),
                   hole=np.array([-1, 0, -1, -1, 1, -1]), src=np.array([2, 0, 0, 2, 1, 1]),
                   dst=np.array([0, 0, 2, 1, 1, 2]), t_start=np.zeros(6), t_end=np.ones(6))
    s = DrawSettings(count=50, seed=7)
    reported, compared = draws(acts, s), draws(acts, pick_draws(s))
    assert pick_draws(s).seed == 8 and pick_draws(DrawSettings(seed=2**32 - 1)).seed == 0
    assert reported.factors.shape == compared.factors.shape
    assert not np.allclose(reported.factors[:50], compared.factors[:50])


def test_more_sweeps_are_timed_as_the_planner_times_a_candidate_and_each_set_of_routes_once():
    from test_round import FAST, SetOracle, synthetic

    from pipeline.round.planner import plan_round, seed_routes, timed_routes

    inst = synthetic(H=24, B=2, seed=3)
    oracle = SetOracle({(0, 1): {(2, 5), (7, 7)}, (1, 0): {(5, 2), (7, 7)}})  # planted conflicts
    rp = plan_round(inst, oracle, FAST)
    before = dict(rp.timed)
    n = time_more_sweeps(rp, oracle, FAST, [0.5, 1.0, 3.0])
    new = {k: tl for k, tl in rp.timed.items() if k not in before}
    assert n == len(new) > 0
    assert all(tl is before[k] for k, tl in before.items() if k in rp.timed)  # the planning's own untouched
    # the 1 m sweeps are the planning's own seeds: not timed again
    assert not any("band 1 m" in k for k in new)
    routes = [tl.routes for tl in rp.timed.values()]
    assert all(sum(r == x for x in routes) == 1 for r in routes)  # each set of routes once
    for kind, tl in new.items():
        direction, band = kind.split(", band ")
        expected = timed_routes(inst, oracle, FAST, None, seed_routes(inst, direction, float(band.split()[0])))
        assert tl.routes == expected.routes and tl.makespan == pytest.approx(expected.makespan, abs=1e-9)
        assert tl.conflicts_left == expected.conflicts_left


@pytest.mark.parametrize("node, match", [
    ({"robust_bands_m": [1.0, 0]}, r"round.robust_bands_m\[1\] = 0.0: expected a band width in \(0, 20\] m"),
    ({"robust_bands_m": [True]}, r"round.robust_bands_m\[0\] = True"),
    ({"robust_bands_m": [0.5] * 21}, r"round.robust_bands_m: 21 bands, at most 20"),
    ({"robust_candidates": 0}, r"round.robust_candidates = 0"),
    ({"robust_slack": -0.1}, r"round.robust_slack"),
    ({"robust_min_gain": 2}, r"round.robust_min_gain"),
])
def test_the_choices_settings_are_bounded_and_named(node, match):
    from pipeline.core.errors import ConfigError
    from pipeline.round.settings import parse_round

    with pytest.raises(ConfigError, match=match):
        parse_round(node, "round")
