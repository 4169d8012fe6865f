"""The round planner's settings (``conf/round/<name>.yaml``, node ``round``): what limits each search
(counts by default, wall time opt-in), the conflict margins, the detours' budgets, precedence.

Every number that changes a round lives here, read from the composed config (docs/round.md)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from pipeline.core.errors import ConfigError
from pipeline.core.settings import parse, rule

# Bounds (conf/round/default.yaml names them): beyond them a search only runs out of time or memory (for example
# round.postures=1e5 planned for 509 s, then asked for 2.56 TB); each is far above any value measured useful.
DAY_S = 86_400.0  # wall-time limits (opt-in): a day
SEED_MAX = 2**31 - 1  # OR-Tools', CP-SAT's and OMPL's seeds are 32-bit
MAX_BAND_M = 20.0  # a sweep band wider than any drift

FIRST_SOLUTIONS = ("PATH_CHEAPEST_ARC", "PARALLEL_CHEAPEST_INSERTION", "LOCAL_CHEAPEST_INSERTION",
                   "SAVINGS", "CHRISTOFIDES", "AUTOMATIC")


@dataclass(frozen=True)
class RoundSettings:
    """``conf/round/<name>.yaml``."""

    solution_limit: int = field(default=200, metadata=rule(ge=1, le=10_000_000))
    search_checks: int = field(default=200_000, metadata=rule(ge=1, le=1_000_000_000))
    time_limit_s: float | None = field(default=None, metadata=rule(gt=0, le=DAY_S))
    first_solution: str = field(default="PARALLEL_CHEAPEST_INSERTION", metadata=rule(choices=FIRST_SOLUTIONS))
    span_cost: int = field(default=100, metadata=rule(ge=0, le=1_000_000))
    routing: bool = True  # false: no OR-Tools solve; the round is the best of the seeds (a quick re-plan)
    reopt_rounds: int = field(default=4, metadata=rule(ge=0, le=100))
    waits: str = field(default="greedy", metadata=rule(choices=("exact", "greedy", "best")))
    waits_deterministic_s: float = field(default=5.0, metadata=rule(gt=0, le=3600))
    waits_rounds: int = field(default=30, metadata=rule(ge=1, le=1000))
    waits_seed: int = field(default=0, metadata=rule(ge=0, le=SEED_MAX))
    max_repairs: int = field(default=300, metadata=rule(ge=0, le=100_000))
    escalations: int = field(default=4, metadata=rule(ge=0, le=1000))
    sample_m: float = field(default=0.01, metadata=rule(ge=0.001, le=0.5))
    traj_tol_m: float = field(default=0.001, metadata=rule(ge=1e-5, le=0.1))
    refinements: int = field(default=4, metadata=rule(ge=0, le=10))
    self_margin_m: float = field(default=0.0, metadata=rule(ge=0, le=10))
    tunnel_margin_m: float = field(default=0.0, metadata=rule(ge=0, le=10))
    precedence: list[list[str]] = field(default_factory=list)
    blocked_penalty_s: float = field(default=600.0, metadata=rule(ge=0, le=1e6))
    blocked_neighbours: int = field(default=12, metadata=rule(ge=1, le=1000))
    blocked_screen_m: float = field(default=0.05, metadata=rule(ge=0.001, le=1))
    detours: bool = True
    detour_iterations: int = field(default=5000, metadata=rule(ge=1, le=1_000_000))
    detour_simplify_steps: int = field(default=40, metadata=rule(ge=0, le=10_000))
    detour_seed: int = field(default=0, metadata=rule(ge=0, le=SEED_MAX))
    detour_plan_s: float | None = field(default=None, metadata=rule(gt=0, le=3600))
    detour_box: float | None = field(default=0.1, metadata=rule(gt=0, le=10))
    budget_s: float | None = field(default=None, metadata=rule(gt=0, le=DAY_S))
    stop_ratio: float = field(default=1.02, metadata=rule(ge=1, le=10))
    sweep_band_m: float = field(default=1.0, metadata=rule(gt=0, le=MAX_BAND_M))
    sweep_more_bands_m: list[float] = field(default_factory=lambda: [0.75, 1.5, 2.0])  # more sweeps, other bands
    clear_ends: bool = True  # each sweep also timed with its ends clear of the other booms' parks
    # ok solutions kept per hole and boom (1: the reach table's)
    postures: int = field(default=8, metadata=rule(ge=1, le=64))
    posture_starts: int = field(default=32, metadata=rule(ge=0, le=1024))  # random starts per hole and boom
    posture_gap_s: float = field(default=2.0, metadata=rule(gt=0, le=3600))  # two kept differ by this move time (s)
    # the choice's price of a standing conflict, and of a straight move that needs a detour (s)
    posture_conflict_s: float = field(default=60.0, metadata=rule(ge=0, le=1e6))
    posture_unclear_s: float = field(default=30.0, metadata=rule(ge=0, le=1e6))
    posture_rounds: int = field(default=2, metadata=rule(ge=1, le=10))  # plannings on chosen postures, while better
    posture_seed: int = field(default=0, metadata=rule(ge=0, le=SEED_MAX))
    # rounds made robust and compared: the best and others within robust_slack of its makespan (1: the best)
    robust_candidates: int = field(default=4, metadata=rule(ge=1, le=50))
    robust_slack: float = field(default=0.005, metadata=rule(ge=0, le=1))
    robust_min_gain: float = field(default=0.005, metadata=rule(ge=0, le=1))  # standing p95 a round must cut
    robust_bands_m: list[float] = field(default_factory=lambda: [0.5, 1.25, 1.75, 2.5])  # more sweeps to compare

    @property
    def reproducible(self) -> bool:
        """No wall-time limit is set: the same inputs give the same round on any machine."""
        return self.time_limit_s is None and self.detour_plan_s is None and self.budget_s is None


def parse_round(node: Mapping, source: str = "conf/round") -> RoundSettings:
    s = parse(RoundSettings, node, source)
    for name in ("sweep_more_bands_m", "robust_bands_m"):
        bands = getattr(s, name)
        if len(bands) > 20:
            raise ConfigError(f"{source}.{name}: {len(bands)} bands, at most 20 (each is another sweep timed)")
        for k, band in enumerate(bands):
            if (isinstance(band, bool) or not isinstance(band, (int, float)) or not band > 0
                    or not band <= MAX_BAND_M):
                raise ConfigError(f"{source}.{name}[{k}] = {band!r}: expected a band width in (0, {MAX_BAND_M:g}] m")
    for k, pair in enumerate(s.precedence):
        if len(pair) != 2:
            raise ConfigError(f"{source}.precedence[{k}] = {pair!r}: expected [hole_id_before, hole_id_after]")
        if str(pair[0]) == str(pair[1]):
            raise ConfigError(f"{source}.precedence[{k}] = {pair!r}: hole '{pair[0]}' cannot come before itself")
    return s
