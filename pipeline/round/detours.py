"""Every move a round uses is clear of the boom itself and the tunnel: the straight line, or a detour.

The routing and the timeline price a move by the synchronised straight line between two joint
solutions. Before a set of routes is timed, :meth:`MoveBook.ensure` looks at every move it uses that
was not looked at before:

1. all of them at once, straight, at 1 cm of point travel (:func:`pipeline.motion.checks.
   certify_straight_moves`, the dense check of :func:`pipeline.motion.checks.check_path`): a move whose
   certified self and tunnel floors (a lower bound at every instant, not only at the samples) are at
   least the margins stays straight; where the samples are clear but a floor is short, the move is
   checked again at half the resolution (``round.refinements`` times at most);
2. each other one is planned by :func:`pipeline.motion.moves.plan_move` (``retract``: feed back,
   travel, feed forward; then ``planned``: OMPL's RRTConnect and simplifier), clear of self, tunnel
   and the other booms standing at their parks, and becomes the oracle's detour for that move
   (:meth:`pipeline.round.oracle.KinematicOracle.set_detour`): its duration goes into ``move_s``, its
   motion into the boom-boom checks of the timeline and into the trajectory rows;
3. a move no attempt made clear (or, with ``round.detours: false``, any move not certified straight) is
   ``failed``: it keeps the straight line, its rows are ``move_unclear`` in the trajectory file, and it
   is reported with the reason (``moves_not_clear`` of the round's JSON), never hidden.

Margins (:func:`pipeline.motion.checks.margins`): the trajectory rows lie on the moves' joint-space
segments, so the file passes through the motion's own configurations and keeps its self and tunnel
floors: the margins are ``round.self_margin_m`` and ``round.tunnel_margin_m`` (0 by default).

A move's answer holds for its reverse too (the same configurations backwards; a rest-to-rest path
reversed takes the same time), so both are recorded at once. The book only grows: a move looked at
keeps its answer, so a timeline timed earlier stays valid when later routes add detours, and the
routing solved after it pays the detours' real durations.

Boom-boom clearance of a straight move is not this module's business: it depends on where the
other booms are at that time, which the timeline's oracle checks (and the routing pays for a move
that another boom at park blocks: :func:`pipeline.round.planner.park_blocked`).
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import torch

from pipeline.motion.checks import certify_straight_moves, margins
from pipeline.motion.moves import PlannerSettings, plan_move
from pipeline.motion.path import Path, unwrapped
from pipeline.round.problem import Instance
from pipeline.round.settings import RoundSettings

UNKNOWN, STRAIGHT, RETRACT, PLANNED, FAILED = range(5)
KIND = {STRAIGHT: "straight", RETRACT: "retract", PLANNED: "planned", FAILED: "failed"}
KINDS = ("self", "tunnel")  # what the book certifies; boom-boom is the timeline's oracle's (module doc)


def used_moves(routes: list[list[int]], park: int, starts: list[int] | None = None) -> list[np.ndarray]:
    """Per boom, its moves ``(k, 2)`` (from node, to node) along its route, from its start node
    (``starts``; default park) to park."""
    out = []
    for b, r in enumerate(routes):
        first = park if starts is None else int(starts[b])
        nodes = np.array([first, *r, park])
        out.append(np.stack([nodes[:-1], nodes[1:]], -1) if r or first != park else np.zeros((0, 2), np.int64))
    return out


def planner_settings(settings: RoundSettings) -> PlannerSettings:
    """The detours' OMPL settings from the round's (counts by default; ``detour_plan_s`` opts in to
    wall time, the simplifier getting a tenth of it)."""
    timed = settings.detour_plan_s
    return PlannerSettings(iterations=settings.detour_iterations, simplify_steps=settings.detour_simplify_steps,
                           time_s=timed, simplify_s=None if timed is None else timed / 10, seed=settings.detour_seed,
                           box_margin=settings.detour_box, refinements=settings.refinements)


class MoveBook:
    """What is known of each boom's moves: ``status (B, H + 1, H + 1)`` (UNKNOWN, STRAIGHT, RETRACT,
    PLANNED, FAILED), the reasons of detours and failures, the certified floors ``floor[kind] (B, H + 1,
    H + 1)`` of self and tunnel clearance of each move's motion (NaN: not looked at), and the planning
    seconds spent (wall clock: for logs, never for a decision).

    A move is accepted (straight or detour) only when its certified floors are at least ``margin``
    (:func:`pipeline.motion.checks.margins` with round.self_margin_m, round.tunnel_margin_m: the
    trajectory file's rows pass through the move's own configurations, so they keep its floors)."""

    def __init__(self, oracle, n_holes: int, settings: RoundSettings | None = None):
        settings = settings or RoundSettings()
        self.oracle, self.rig, self.H = oracle, oracle.rig, n_holes
        self.resolution, self.refinements = settings.sample_m, settings.refinements
        self.tolerance = settings.traj_tol_m
        self.margin = margins(settings.traj_tol_m, False, settings.self_margin_m, settings.tunnel_margin_m)
        self.planner = planner_settings(settings)
        self.detours = settings.detours  # false: a move not certified straight is failed, not re-planned
        B = len(oracle.joints)
        self.status = np.zeros((B, n_holes + 1, n_holes + 1), np.int8)
        self.floor = {k: np.full((B, n_holes + 1, n_holes + 1), np.nan) for k in ("self", "tunnel")}
        self.reason: dict[tuple[int, int, int], str] = {}
        self.durations: dict[tuple[int, int, int], float] = {}  # (boom, from, to) -> the detour's seconds
        self.seconds = 0.0

    def apply(self, inst: Instance) -> Instance:
        """``inst`` with every detour's duration known so far (any timeline timed with this book is
        valid on it: a move's answer never changes once given)."""
        if not self.durations:
            return inst
        move_s = inst.move_s.copy()
        for (b, u, v), d in self.durations.items():
            move_s[b, u, v] = d
        return dataclasses.replace(inst, move_s=move_s)

    def ensure(self, inst: Instance, routes: list[list[int]]) -> Instance:
        """``inst`` with the durations of every detour planned for ``routes`` (module docstring)."""
        started = time.perf_counter()
        move_s, changed = inst.move_s, False
        for b, moves in enumerate(used_moves(routes, self.H, inst.starts)):
            moves = moves[moves[:, 0] != moves[:, 1]]
            todo = np.unique(moves[self.status[b, moves[:, 0], moves[:, 1]] == UNKNOWN], axis=0)
            if not len(todo):
                continue
            q = self.oracle.joints[b]
            limits = self.oracle.limits[b]
            qa = q[torch.as_tensor(todo[:, 0])]
            qb = unwrapped(qa, q[torch.as_tensor(todo[:, 1])], limits)
            checks = certify_straight_moves(self.rig, b, qa, qb, self.margin, KINDS, resolution=self.resolution,
                                            refinements=self.refinements)
            clear = checks.certified(KINDS, self.margin).numpy()
            for kind in KINDS:
                f = checks.floor[kind].numpy()
                self.floor[kind][b, todo[:, 0], todo[:, 1]] = self.floor[kind][b, todo[:, 1], todo[:, 0]] = f
            u, v = todo[clear, 0], todo[clear, 1]
            self.status[b, u, v] = self.status[b, v, u] = STRAIGHT
            for k in np.flatnonzero(~clear):
                if not changed:
                    move_s, changed = move_s.copy(), True
                self._detour(b, int(todo[k, 0]), int(todo[k, 1]), qa[k], qb[k], move_s)
        self.seconds += time.perf_counter() - started
        return dataclasses.replace(inst, move_s=move_s) if changed else inst

    def _detour(self, b: int, u: int, v: int, qa: torch.Tensor, qb: torch.Tensor, move_s: np.ndarray) -> None:
        if not self.detours:
            self.status[b, u, v] = self.status[b, v, u] = FAILED
            short = ", ".join(f"{k} {self.floor[k][b, u, v]:.4f} m" for k in KINDS
                              if not self.floor[k][b, u, v] >= self.margin[k])
            self.reason[(b, u, v)] = self.reason[(b, v, u)] = (
                f"straight: certified floor short ({short}); no detour (round.detours=false)")
            return
        m = plan_move(self.rig, b, qa, qb, self.oracle.limits[b], kinds=("retract", "planned"),
                      planner=self.planner, resolution=self.resolution, tolerance=self.tolerance,
                      margin=self.margin)
        if not m.clear:  # the straight line stays, with its own (short) floors
            self.status[b, u, v] = self.status[b, v, u] = FAILED
            self.reason[(b, u, v)] = self.reason[(b, v, u)] = m.reason
            return
        for kind in KINDS:  # a detour's floors (the reverse: the same configurations backwards)
            self.floor[kind][b, u, v] = self.floor[kind][b, v, u] = m.clearance.floors[kind]
        kind = RETRACT if m.kind == "retract" else PLANNED
        back = Path.through(m.path.waypoints.flip(0), self.oracle.limits[b])
        for (x, y), path in (((u, v), m.path), ((v, u), back)):
            self.oracle.set_detour(b, x, y, path)
            move_s[b, x, y] = self.durations[(b, x, y)] = path.duration
            self.status[b, x, y] = kind
            self.reason[(b, x, y)] = m.reason

    def carry(self, other: MoveBook, same: np.ndarray) -> None:
        """Take ``other``'s answers (straight, detour, failed) for every move between two nodes whose joints
        are the same in both books' oracles (``same (B, H + 1)`` bool): a move's answer depends on its two
        configurations alone (and on the parks, which a rig does not change). The round planned again on
        other postures (:mod:`pipeline.round.postures`) looks again only at moves with a changed end."""
        keep = same[:, :, None] & same[:, None, :] & (other.status != UNKNOWN)
        self.status[keep] = other.status[keep]
        for kind in KINDS:
            self.floor[kind][keep] = other.floor[kind][keep]
        self.reason.update({key: r for key, r in other.reason.items() if keep[key]})
        for key, d in other.durations.items():
            if keep[key]:
                self.durations[key] = d
                self.oracle.set_detour(*key, other.oracle.detour(*key))

    def floors(self, routes: list[list[int]], starts: list[int] | None = None) -> dict[str, float | None]:
        """The smallest certified floor of self and tunnel clearance over the routes' moves (m; failed
        moves included, with their straight line's floor; None when no move was looked at)."""
        out = {}
        for kind in KINDS:
            vals = [self.floor[kind][b, m[:, 0], m[:, 1]] for b, m in enumerate(used_moves(routes, self.H, starts))]
            vals = np.concatenate([v for v in vals if len(v)] or [np.zeros(0)])
            vals = vals[np.isfinite(vals)]
            out[kind] = float(vals.min()) if len(vals) else None
        return out

    def kinds(self, routes: list[list[int]], starts: list[int] | None = None
              ) -> tuple[dict[str, int], list[tuple[int, int, int]]]:
        """Counts of the routes' moves by kind, and the failed ones ``(boom, from, to)``."""
        counts = {name: 0 for name in KIND.values()}
        failed = []
        for b, moves in enumerate(used_moves(routes, self.H, starts)):
            for u, v in moves:
                if u == v:
                    continue
                s = int(self.status[b, u, v])
                counts[KIND.get(s, "unchecked")] = counts.get(KIND.get(s, "unchecked"), 0) + 1
                if s == FAILED:
                    failed.append((b, int(u), int(v)))
        return counts, failed
