"""The round planner's settings (``conf/round/<name>.yaml``, node ``round``): what limits each search
(counts by default, wall time opt-in), the conflict margins, the detours' budgets, precedence.

Every number that changes a round lives here, read from the composed config (docs/round.md)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from pipeline.core.errors import ConfigError
from pipeline.core.settings import parse, rule

FIRST_SOLUTIONS = ("PATH_CHEAPEST_ARC", "PARALLEL_CHEAPEST_INSERTION", "LOCAL_CHEAPEST_INSERTION",
                   "SAVINGS", "CHRISTOFIDES", "AUTOMATIC")


@dataclass(frozen=True)
class RoundSettings:
    """``conf/round/<name>.yaml``."""

    solution_limit: int = field(default=200, metadata=rule(ge=1))
    search_checks: int = field(default=200_000, metadata=rule(ge=1))
    time_limit_s: float | None = field(default=None, metadata=rule(gt=0))
    first_solution: str = field(default="PARALLEL_CHEAPEST_INSERTION", metadata=rule(choices=FIRST_SOLUTIONS))
    span_cost: int = field(default=100, metadata=rule(ge=0))
    routing: bool = True  # false: no OR-Tools solve; the round is the best of the seeds (a quick re-plan)
    reopt_rounds: int = field(default=4, metadata=rule(ge=0))
    waits: str = field(default="greedy", metadata=rule(choices=("exact", "greedy", "best")))
    waits_deterministic_s: float = field(default=5.0, metadata=rule(gt=0))
    waits_rounds: int = field(default=30, metadata=rule(ge=1))
    waits_seed: int = field(default=0, metadata=rule(ge=0))
    max_repairs: int = field(default=300, metadata=rule(ge=0))
    escalations: int = field(default=4, metadata=rule(ge=0))
    sample_m: float = field(default=0.01, metadata=rule(gt=0))
    traj_tol_m: float = field(default=0.001, metadata=rule(gt=0))
    refinements: int = field(default=4, metadata=rule(ge=0))
    self_margin_m: float = field(default=0.0, metadata=rule(ge=0))
    tunnel_margin_m: float = field(default=0.0, metadata=rule(ge=0))
    precedence: list[list[str]] = field(default_factory=list)
    blocked_penalty_s: float = field(default=600.0, metadata=rule(ge=0))
    blocked_neighbours: int = field(default=12, metadata=rule(ge=1))
    blocked_screen_m: float = field(default=0.05, metadata=rule(gt=0))
    detours: bool = True
    detour_iterations: int = field(default=5000, metadata=rule(ge=1))
    detour_simplify_steps: int = field(default=40, metadata=rule(ge=0))
    detour_seed: int = field(default=0, metadata=rule(ge=0))
    detour_plan_s: float | None = field(default=None, metadata=rule(gt=0))
    detour_box: float | None = field(default=0.1, metadata=rule(gt=0))
    budget_s: float | None = field(default=None, metadata=rule(gt=0))
    stop_ratio: float = field(default=1.02, metadata=rule(ge=1))
    sweep_band_m: float = field(default=1.0, metadata=rule(gt=0))
    sweep_more_bands_m: list[float] = field(default_factory=lambda: [0.75, 1.5, 2.0])  # more sweeps, other bands
    clear_ends: bool = True  # each sweep also timed with its ends clear of the other booms' parks
    postures: int = field(default=8, metadata=rule(ge=1))  # ok solutions kept per hole and boom (1: the reach table's)
    posture_starts: int = field(default=32, metadata=rule(ge=0))  # random starts per hole and boom that find them
    posture_gap_s: float = field(default=2.0, metadata=rule(gt=0))  # two kept differ by at least this move time (s)
    posture_conflict_s: float = field(default=60.0, metadata=rule(ge=0))  # the choice's price of a standing conflict
    posture_unclear_s: float = field(default=30.0, metadata=rule(ge=0))  # ... of a straight move that needs a detour
    posture_rounds: int = field(default=2, metadata=rule(ge=1))  # plannings on chosen postures, while each is better
    posture_seed: int = field(default=0, metadata=rule(ge=0))

    @property
    def reproducible(self) -> bool:
        """No wall-time limit is set: the same inputs give the same round on any machine."""
        return self.time_limit_s is None and self.detour_plan_s is None and self.budget_s is None


def parse_round(node: Mapping, source: str = "conf/round") -> RoundSettings:
    s = parse(RoundSettings, node, source)
    for k, band in enumerate(s.sweep_more_bands_m):
        if isinstance(band, bool) or not isinstance(band, (int, float)) or not band > 0 or band == float("inf"):
            raise ConfigError(f"{source}.sweep_more_bands_m[{k}] = {band!r}: expected a band width > 0 (m)")
    for k, pair in enumerate(s.precedence):
        if len(pair) != 2:
            raise ConfigError(f"{source}.precedence[{k}] = {pair!r}: expected [hole_id_before, hole_id_after]")
        if str(pair[0]) == str(pair[1]):
            raise ConfigError(f"{source}.precedence[{k}] = {pair!r}: hole '{pair[0]}' cannot come before itself")
    return s
