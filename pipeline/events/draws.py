"""Drilling durations that are not the model's: the draws, their execution and a summary.

The draws (``conf/draws/default.yaml``), as factors of each hole's section-7 drilling time:

- ``draws`` random ones, every hole's factor uniform in ``[low, high]`` independently (a seeded numpy
  Generator: the same settings give the same draws), and, with ``stall_p`` > 0, each hole of each
  random draw stalls (its factor times ``stall_factor``) with that probability;
- every drilled hole alone at ``stall_factor`` (a jammed rod), the others at 1;
- one boom at ``slow_factor`` while the others run at ``quick_factor``, each boom in turn.

``factors`` (hole id -> factor) fixes named holes' factors in every draw (a hole known to be hard).
All are executed at once (:func:`pipeline.events.rule.execute`, vectorised over draws). The
summary gives the makespan's ratio to the nominal one (p50, p95, max), the time the booms stood before
their actions as a share of the draw's makespan (p50, p95, max) and split by cause (p50, p95: for an
order, an interlock; for a zone another boom was inside), the time they stood at park with nothing left
to do after their last action (p50, p95), and the draws that deadlock (without zones the graph is the
same for every draw, so a deadlock is all or nothing).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from pipeline.core.errors import ConfigError
from pipeline.core.settings import parse, rule
from pipeline.events.actions import Actions
from pipeline.events.rule import Execution, execute
from pipeline.events.zones import Zones

# Bounds (conf/draws/default.yaml): a draw is (holes x actions) floats, each checked for d_boom by the
# independent checker too, and a factor is a drilling duration over its model time (high=1e300 would give
# a 1.5e302 s makespan)
MAX_DRAWS = 10_000
MAX_FACTOR = 100.0


@dataclass(frozen=True)
class DrawSettings:
    """``conf/draws/<name>.yaml`` (module docstring)."""

    count: int = field(default=1000, metadata=rule(ge=0, le=MAX_DRAWS))
    low: float = field(default=0.7, metadata=rule(gt=0, le=MAX_FACTOR))
    high: float = field(default=1.5, metadata=rule(gt=0, le=MAX_FACTOR))
    seed: int = field(default=0, metadata=rule(ge=0, le=2**32 - 1))
    stall_factor: float = field(default=3.0, metadata=rule(gt=0, le=MAX_FACTOR))
    slow_factor: float = field(default=1.5, metadata=rule(gt=0, le=MAX_FACTOR))
    quick_factor: float = field(default=0.7, metadata=rule(gt=0, le=MAX_FACTOR))
    stall_p: float = field(default=0.0, metadata=rule(ge=0, le=1))
    factors: dict[str, float] = field(default_factory=dict)


def parse_draws(node: Mapping, source: str = "draws") -> DrawSettings:
    s = parse(DrawSettings, node, source)
    if s.high < s.low:
        raise ConfigError(f"{source}.high = {s.high}: must be >= {source}.low = {s.low}")
    for h, f in s.factors.items():
        try:
            ok = not isinstance(f, bool) and 0 < float(f) <= MAX_FACTOR
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise ConfigError(f"{source}.factors.{h} = {f!r}: expected a factor in (0, {MAX_FACTOR:g}]")
    return s


def fixed_factors(acts: Actions, factors: Mapping[str, float], source: str = "draws.factors") -> np.ndarray:
    """``(H,)`` the named holes' fixed factors (1 elsewhere); a name the plan lacks is a ConfigError."""
    out = np.ones(len(acts.hole_ids))
    index = {h: k for k, h in enumerate(acts.hole_ids)}
    for h, f in factors.items():
        if str(h) not in index:
            raise ConfigError(f"{source}.{h}: no hole {h!r} in the plan")
        out[index[str(h)]] = float(f)
    return out


@dataclass(frozen=True)
class Draws:
    """Factors ``(D, H)`` and a label per draw (``random``, ``stall <hole_id>``, ``slow <boom>``)."""

    factors: np.ndarray
    labels: list[str]


def draws(acts: Actions, settings: DrawSettings) -> Draws:
    """The module's draws for the holes ``acts`` drills."""
    H, B = len(acts.hole_ids), len(acts.booms)
    rng = np.random.default_rng(settings.seed)
    rand = rng.uniform(settings.low, settings.high, size=(settings.count, H))
    if settings.stall_p > 0:  # drawn after the factors: stall_p = 0 keeps the same draws
        rand = np.where(rng.random((settings.count, H)) < settings.stall_p, rand * settings.stall_factor, rand)
    drilled = np.unique(acts.hole[acts.is_drill])
    stall = np.ones((len(drilled), H))
    stall[np.arange(len(drilled)), drilled] = settings.stall_factor
    owner = np.full(H, -1)
    owner[acts.hole[acts.is_drill]] = acts.boom[acts.is_drill]
    booms = [b for b in range(B) if (owner == b).any()]
    slow = np.where(owner[None, :] == np.array(booms)[:, None], settings.slow_factor, settings.quick_factor)
    labels = (["random"] * settings.count + [f"stall {acts.hole_ids[h]}" for h in drilled]
              + [f"slow {acts.booms[b]}" for b in booms])
    fixed = fixed_factors(acts, settings.factors)
    named = fixed != 1.0
    out = np.concatenate([rand, stall, slow.reshape(-1, H)])
    out[:, named] = fixed[named]
    return Draws(out, labels)


def run(acts: Actions, interlocks: np.ndarray, drill_s: np.ndarray, d: Draws, zones: Zones | None = None
        ) -> Execution:
    """Every draw executed: drilling durations ``factors * drill_s``, with the interlocks and ``zones``."""
    return execute(acts, interlocks, d.factors * np.asarray(drill_s, float)[None, :], zones)


# the standing split by cause, keys ``<cause>_share_p50`` / ``_p95`` of the summary: waiting for an order (an
# interlock), for a zone another boom was inside; and beside the standing, the time at park after the last action
STANDING_CAUSES = ("order", "zone", "idle_after")


def summary(ex: Execution, nominal_makespan_s: float, d: Draws) -> dict:
    """Makespan ratios to the nominal round and standing shares, over the random draws and over all."""
    deadlock = bool(ex.deadlocked.any())
    span = np.where(ex.makespan > 0, ex.makespan, 1.0)
    share = ex.standing.sum(1) / span
    # standing by cause, shares of the makespan summed over booms: for an order (interlock), for a zone
    # another boom was inside; and beside it the time at park after the boom's last action
    causes = dict(zip(STANDING_CAUSES, (ex.standing_order.sum(1) / span, ex.standing_zone.sum(1) / span,
                                        ex.idle_after.sum(1) / span), strict=True))
    ratio = ex.makespan / nominal_makespan_s if nominal_makespan_s > 0 else np.ones_like(ex.makespan)
    rand = np.array([lab == "random" for lab in d.labels])

    def stats(mask):
        if not mask.any() or deadlock:
            return None
        r, s = ratio[mask], share[mask]
        return {"draws": int(mask.sum()), "makespan_ratio_p50": float(np.percentile(r, 50)),
                "makespan_ratio_p95": float(np.percentile(r, 95)), "makespan_ratio_max": float(r.max()),
                "standing_share_p50": float(np.percentile(s, 50)),
                "standing_share_p95": float(np.percentile(s, 95)), "standing_share_max": float(s.max()),
                **{f"{c}_share_p{q}": float(np.percentile(v[mask], q)) for c, v in causes.items() for q in (50, 95)}}

    return {"nominal_makespan_s": nominal_makespan_s, "draws": len(d.labels), "deadlocks": int(ex.deadlocked.sum()),
            "random": stats(rand), "all": stats(np.ones_like(rand))}
