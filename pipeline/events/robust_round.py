"""The planned round made robust for the ``schedule`` stage: interlocks, the re-timed nominal round, the
Monte Carlo of drilling durations, and one realised round to look at.

:func:`robust_finish` returns the hook :func:`pipeline.round.from_plan.schedule_round` calls once the
round is planned (``finish``): it builds the interlocks and chooses the zones
(:func:`~pipeline.events.interlocks.robust_round`, :mod:`pipeline.events.zone_choice`),
hands back the re-timed nominal timeline (the one the trajectory file is written from, which the
execution rule reproduces exactly with the reference's durations) and keeps what the stage writes: the
actions, interlocks and zones tables, the draws' summary, and the slowest random draw as a realised round.

:func:`robust_choice` returns the hook that keeps one of several such rounds (``choose``): the planner's
best and the candidates of about its makespan, each finished. It compares them on draws of their own
(the ``draws`` settings with the next seed), not on the draws the summary reports, so the reported
figures of the round kept are not the ones it was picked on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd

from pipeline.events.actions import actions_table, interlocks_table
from pipeline.events.draws import Draws, DrawSettings, draws, run, summary
from pipeline.events.interlocks import RobustRound, robust_round
from pipeline.events.rule import Execution, realised
from pipeline.events.zone_choice import ZoneSettings
from pipeline.events.zones import zones_table
from pipeline.round.problem import Instance
from pipeline.round.timeline import Timeline


@dataclass
class Executed:
    """What the stage writes of the executed round (:func:`robust_finish`)."""

    robust: RobustRound
    actions: pd.DataFrame
    interlocks: pd.DataFrame
    zones: pd.DataFrame
    draws: Draws
    execution: Execution
    summary: dict
    realised: tuple[Instance, Timeline] | None = None  # the slowest random draw
    realised_label: str = ""
    extra: dict = field(default_factory=dict)


def pick_draws(settings: DrawSettings) -> DrawSettings:
    """The random draws candidates are compared on: the stage's, seeded with the next seed."""
    return replace(settings, seed=(settings.seed + 1) % 2**32)


def robust_finish(settings: DrawSettings, say=None, zones: ZoneSettings | None = None, choosing: bool = False):
    """``finish(inst, timeline, oracle) -> (timeline, Executed)`` for ``schedule_round``; ``zones``: how
    the zones are chosen (None: the defaults of ``conf/zones/default.yaml``); ``choosing``: also execute
    the round on the draws :func:`robust_choice` compares on (``Executed.extra["pick"]``)."""
    say = say or (lambda _m: None)
    zones = zones if zones is not None else ZoneSettings()

    def finish(inst: Instance, tl: Timeline, oracle):
        rr = robust_round(inst, tl, oracle, zone_search=(zones, settings))
        nominal = rr.timeline
        nominal.repairs, nominal.sequential = tl.repairs, tl.sequential  # the plan's waits, now interlocks
        nominal.conflicts_left = int(rr.stats["conflicts_left"])
        least = rr.stats["min_clearance_m"]
        nominal.min_clearance = math.inf if least is None else float(least)
        say(f"interlocks: {rr.stats['interlocks']} ({rr.stats['conflicting_pairs']} conflicting pairs of actions, "
            f"{rr.stats['overlapping_in_plan']} serialised), {len(rr.zones.names)} zone(s); nominal makespan "
            f"{nominal.makespan:.1f} s")
        d = draws(rr.actions, settings)
        ex = run(rr.actions, rr.interlocks, inst.drill_s, d, rr.zones)
        s = summary(ex, nominal.makespan, d)
        s["interlocks"] = {k: v for k, v in rr.stats.items() if not k.endswith("_s")}
        s["robust"] = rr.problem is None
        s["problem"] = rr.problem
        s["plan_makespan_s"] = tl.makespan
        out = Executed(rr, actions_table(rr.actions), interlocks_table(rr.actions, rr.interlocks),
                       zones_table(rr.actions, rr.zones), d, ex, s)
        out.extra["timings"] = {k: v for k, v in rr.stats.items() if k.endswith("_s")}
        if choosing:
            dp = draws(rr.actions, pick_draws(settings))
            out.extra["pick"] = summary(run(rr.actions, rr.interlocks, inst.drill_s, dp, rr.zones), nominal.makespan,
                                        dp)
        rand = np.flatnonzero([lab == "random" for lab in d.labels])
        if ex.deadlock is None and len(rand):
            k = int(rand[np.argmax(ex.makespan[rand])])
            out.realised, out.realised_label = realised(inst, rr.actions, ex, k), f"random draw {k}"
        return nominal, out

    return finish


def robust_choice(slack: float, min_gain: float):
    """``choose(executed) -> (index, record)`` for ``schedule_round``: of rounds finished with
    ``choosing`` (the planner's best first, then by planned makespan), the first unless another is
    robust, deadlocks in no draw, is within ``slack`` (a share) of the first's nominal makespan and of its
    draws' p95 makespan, and stands less: in order, a round replaces the one kept so far when the p95 of
    its standing share on the compare draws is lower, by at least ``min_gain`` (a share of the makespan),
    so a longer round is kept only for a real gain."""

    def figures(e: Executed):
        p = e.extra["pick"]
        nominal = p["nominal_makespan_s"]
        if p["random"] is None:  # a deadlocked draw, or no random draw
            return None
        r = p["random"]
        return {"nominal_s": nominal, "p95_makespan_s": r["makespan_ratio_p95"] * nominal,
                "standing_p95": r["standing_share_p95"], "robust": bool(e.summary["robust"])}

    def choose(executed: list[Executed]) -> tuple[int, dict]:
        fig = [figures(e) for e in executed]
        first = fig[0]
        best = 0
        if first is not None:
            for k, f in enumerate(fig[1:], start=1):
                if (f is None or not f["robust"] or f["nominal_s"] > first["nominal_s"] * (1 + slack)
                        or f["p95_makespan_s"] > first["p95_makespan_s"] * (1 + slack)):
                    continue
                gain = fig[best]["standing_p95"] - f["standing_p95"]
                if gain > 0 and gain >= min_gain:
                    best = k
        return best, {"compared_on": "random draws of the next seed", "figures": fig}

    return choose


def robust_hooks(settings: DrawSettings, zones: ZoneSettings | None, candidates: int, slack: float, min_gain: float,
                 say=None):
    """``(finish, choose)`` for ``schedule_round``: the round made robust, and (``candidates`` > 1, the
    ``round.robust_*`` settings) the choice among the rounds of about the best's makespan."""
    choosing = candidates > 1
    return robust_finish(settings, say, zones, choosing), (robust_choice(slack, min_gain) if choosing else None)


def realised_makespans_figure(ex: Executed, title: str = ""):
    """Realised makespans of the draws against the nominal round: a histogram per kind of draw."""
    return makespans_figure(ex.execution.makespan, ex.draws.labels, ex.summary["nominal_makespan_s"], title)


def makespans_figure(span: np.ndarray, draw_labels: list[str], nominal: float, title: str = "", realised=None):
    """Makespans of draws (labels ``random``, ``stall <hole>``, ``slow <boom>``) against the nominal
    one; ``realised``: (makespan, label) of one executed round, marked."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7.5, 4.2))
    ax = fig.add_subplot(1, 1, 1)
    labels = np.array([lab.split(" ")[0] for lab in draw_labels])
    for kind, colour in (("random", "tab:blue"), ("stall", "tab:orange"), ("slow", "tab:red")):
        m = labels == kind
        if m.any():
            ax.hist(span[m], bins=40, alpha=0.6, color=colour,
                    label={"random": "each hole 0.7-1.5x", "stall": "one hole 3x", "slow": "one boom slow"}[kind]
                    + f" ({int(m.sum())})")
    ax.axvline(nominal, color="k", lw=1.2, label=f"nominal {nominal:.0f} s")
    if realised is not None:
        ax.axvline(realised[0], color="tab:green", lw=1.5, ls="--", label=f"{realised[1]} {realised[0]:.0f} s")
    ax.set_xlabel("realised makespan (s), executed by events with the interlocks")
    ax.set_ylabel("draws")
    ax.set_title(title or "the round executed under drawn drilling times")
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig
