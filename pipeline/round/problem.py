"""What a round is planned from: booms, holes, who can drill what, how long drilling and moving take.

An :class:`Instance` holds plain arrays, so the stage can fill it from any reach table:

- ``reach (B, H)`` bool: boom b can drill hole h (status ``ok``);
- ``phases (H, 3)`` s: collaring, penetration and retraction of each hole (docs/reference.md section 7:
  10 s + length at 2.5 m/min + length at 1.0 m/s; :func:`drill_phases`); ``drill_s = phases.sum(1)``;
- ``move_s (B, H + 1, H + 1)`` s: move time of boom b between its joint solutions of holes i and j,
  index ``H`` being its park (entries of holes b cannot drill are never read);
- ``precedence``: pairs ``(i, j)``, hole i finished before hole j starts (any booms);
- ``collars (H, 3)`` and ``base_y (B,)`` for the reference's baselines (side of the centre line, nearest
  collar), ``park_points (B, 3)``: where each boom's drill end is at park (nearest's first step);
- ``start (B,)``: the node each boom stands at when the round begins (None: every boom at its park).
  A round handed on after an interruption (:mod:`pipeline.events.interrupt`) starts where the booms
  stand, at holes already drilled (out of every boom's reach, so not drilled again); every round ends
  at park.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pipeline.core.errors import ConfigError


def drill_phases(lengths, collaring_s: float = 10.0, rate_m_per_min: float = 2.5, retract_m_per_s: float = 1.0):
    """``(H, 3)`` seconds of collaring, penetration and retraction for holes of ``lengths`` (m), as
    :func:`pipeline.motion.timing.drilling_time` sums them (pass a motion file's ``drilling`` values)."""
    L = np.asarray(lengths, dtype=float)
    return np.stack([np.full_like(L, collaring_s), L * 60.0 / rate_m_per_min, L / retract_m_per_s], axis=-1)


@dataclass(frozen=True)
class Instance:
    booms: tuple[str, ...]
    hole_ids: tuple[str, ...]
    reach: np.ndarray  # (B, H) bool
    phases: np.ndarray  # (H, 3) s
    move_s: np.ndarray  # (B, H + 1, H + 1) s, index H = park
    precedence: tuple[tuple[int, int], ...] = ()
    collars: np.ndarray | None = None  # (H, 3) m, rig frame
    base_y: np.ndarray | None = None  # (B,) m
    park_points: np.ndarray | None = None  # (B, 3) m
    reasons: tuple[str, ...] | None = None  # per hole: why no boom can drill it (from the reach table)
    start: tuple[int, ...] | None = None  # (B,) node each boom starts from (index H: park); None: parks

    def __post_init__(self):
        B, H = len(self.booms), len(self.hole_ids)
        if B == 0:
            raise ConfigError("a round needs at least one boom")
        if len(set(self.hole_ids)) != H:
            raise ConfigError("hole ids must be unique in a round")
        checks = {"reach": (self.reach, (B, H)), "phases": (self.phases, (H, 3)),
                  "move_s": (self.move_s, (B, H + 1, H + 1))}
        for name, (a, shape) in checks.items():
            if np.shape(a) != shape:
                raise ConfigError(f"round instance: {name} has shape {np.shape(a)}, expected {shape}")
        for name in ("collars", "base_y", "park_points"):
            a = getattr(self, name)
            shape = {"collars": (H, 3), "base_y": (B,), "park_points": (B, 3)}[name]
            if a is not None and np.shape(a) != shape:
                raise ConfigError(f"round instance: {name} has shape {np.shape(a)}, expected {shape}")
        if np.any(self.phases < 0):
            raise ConfigError("round instance: negative drilling phase")
        if self.start is not None:
            if len(self.start) != B or any(not (0 <= int(n) <= H) for n in self.start):
                raise ConfigError(f"round instance: start {self.start} is not one node (0..{H}) per boom")
        used = np.zeros((B, H + 1), bool)
        used[:, :H], used[:, H] = self.reach, True
        used[np.arange(B), self.starts] = True
        sub = self.move_s[used[:, :, None] & used[:, None, :]]
        if not np.all(np.isfinite(sub)) or np.any(sub < 0):
            raise ConfigError("round instance: move times between holes a boom can drill must be finite and >= 0")
        for i, j in self.precedence:
            if not (0 <= i < H and 0 <= j < H) or i == j:
                raise ConfigError(f"round instance: precedence ({i}, {j}) is not a pair of two holes")

    @property
    def n_booms(self) -> int:
        return len(self.booms)

    @property
    def n_holes(self) -> int:
        return len(self.hole_ids)

    @property
    def starts(self) -> list[int]:
        """The node each boom starts from (H: park)."""
        return [self.n_holes] * self.n_booms if self.start is None else [int(n) for n in self.start]

    @property
    def drill_s(self) -> np.ndarray:
        return self.phases.sum(-1)

    @property
    def drillable(self) -> np.ndarray:
        return self.reach.any(0)

    def reason(self, h: int) -> str:
        if self.reasons is not None and self.reasons[h]:
            return self.reasons[h]
        return "no boom can drill it (reach table)"


def precedence_indices(pairs: Sequence[Sequence[str]], hole_ids: Sequence[str], source: str = "round.precedence"):
    """Hole-id pairs of a config (``[[before, after], ...]``) as index pairs, naming an unknown id."""
    index = {h: k for k, h in enumerate(hole_ids)}
    out = []
    for k, (a, b) in enumerate(pairs):
        for h in (a, b):
            if h not in index:
                raise ConfigError(f"{source}[{k}] = {[a, b]!r}: no hole '{h}' in the plan")
        if index[a] == index[b]:
            raise ConfigError(f"{source}[{k}] = {[a, b]!r}: hole '{a}' cannot come before itself")
        out.append((index[a], index[b]))
    return tuple(out)
