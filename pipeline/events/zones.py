"""Zones (docs/reference.md, section 9): where either of two booms may go first, whichever arrives first.

A zone has one *section* per boom that takes part (two or more booms): that boom's actions
``first .. last`` (inclusive). A boom is *inside* the zone from the start of its section's first action
to the end of its last, and it may start a section's first action only while no other boom is inside
(:func:`pipeline.events.rule.execute`). Two sections of one zone therefore never run at once, in
either order, which is what lets a zone replace the interlocks that fixed one order.

The file ``<stem>_zones.csv`` has the columns ``zone, boom, first_action, last_action`` (each boom's own
action numbers, as in the actions file). A round with no zone writes the header alone.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from pipeline.core.errors import InputError
from pipeline.events.actions import Actions, _number, _read, _row

ZONE_COLUMNS = ["zone", "boom", "first_action", "last_action"]


@dataclass(frozen=True)
class Zones:
    """Sections, one per row: the zone's name and the section's first and last action (global numbers;
    the boom is ``Actions.boom[first]``)."""

    zone: tuple[str, ...] = ()
    first: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    last: np.ndarray = field(default_factory=lambda: np.zeros(0, int))

    def __len__(self) -> int:
        return len(self.zone)

    @property
    def names(self) -> list[str]:
        """The zones' names, in order of first appearance."""
        return list(dict.fromkeys(self.zone))


NO_ZONES = Zones()


def check_zones(acts: Actions, zones: Zones, source: str = "zones") -> None:
    """Raise :class:`InputError` for a section that is not a range of one boom's actions, a zone with a
    boom twice or with fewer than two booms (the place named)."""
    first, last = np.asarray(zones.first, int), np.asarray(zones.last, int)
    if len(first) != len(zones.zone) or len(last) != len(zones.zone):
        raise InputError(f"{source}: {len(zones.zone)} zone names for {len(first)} first and {len(last)} last actions")
    K = len(acts)
    for s, (z, f, la) in enumerate(zip(zones.zone, first, last, strict=True)):
        if not (0 <= f < K and 0 <= la < K) or acts.boom[f] != acts.boom[la] or la < f:
            raise InputError(f"{source}: section {s} of zone {z!r}: actions {f}..{la} are not a range of one "
                             "boom's actions")
    for z in zones.names:
        booms = [int(acts.boom[f]) for f, name in zip(first, zones.zone, strict=True) if name == z]
        if len(set(booms)) != len(booms):
            twice = next(acts.booms[b] for b in booms if booms.count(b) > 1)
            raise InputError(f"{source}: zone {z!r} has two sections of boom {twice!r}: one per boom")
        if len(booms) < 2:
            raise InputError(f"{source}: zone {z!r} has one boom only; a zone is shared by two or more booms")


def zones_table(acts: Actions, zones: Zones) -> pd.DataFrame:
    """The zones file of ``zones`` (the header alone for none), sorted by zone and rig order."""
    order = sorted(range(len(zones)), key=lambda s: (zones.zone[s], int(acts.boom[zones.first[s]])))
    return pd.DataFrame({
        "zone": [zones.zone[s] for s in order],
        "boom": [acts.booms[acts.boom[zones.first[s]]] for s in order],
        "first_action": [int(acts.index[zones.first[s]]) for s in order],
        "last_action": [int(acts.index[zones.last[s]]) for s in order]}, columns=ZONE_COLUMNS)


def read_zones(path, actions: pd.DataFrame, acts: Actions, actions_path="actions") -> Zones:
    """A zones file against its actions table (:func:`pipeline.events.actions.read_actions`, and the
    same actions as :class:`Actions`): every cell filled, every action one of its boom's, each section
    a range (``last_action >= first_action``), one section per boom and two or more booms per zone.
    An :class:`InputError` names the file and the row of the first problem."""
    df = _read(path, ZONE_COLUMNS)
    index = {(b, int(a)): k for k, (b, a) in enumerate(zip(actions["boom"], actions["action"], strict=True))}
    booms = set(actions["boom"])
    for i in range(len(df)):
        for col in ("zone", "boom"):
            if not df[col].iloc[i].strip():
                raise InputError(f"{_row(path, i)}: empty {col}")
    f_num = _number(df, "first_action", path, integer=True)
    l_num = _number(df, "last_action", path, integer=True)
    first, last = np.zeros(len(df), int), np.zeros(len(df), int)
    seen: dict[tuple[str, str], int] = {}
    for i in range(len(df)):
        where, zone, boom = _row(path, i), df["zone"].iloc[i].strip(), df["boom"].iloc[i].strip()
        if boom not in booms:
            raise InputError(f"{where}: boom = {boom!r}: no such boom in {actions_path} ({sorted(booms)})")
        for col, num in (("first_action", f_num[i]), ("last_action", l_num[i])):
            if (boom, num) not in index:
                raise InputError(f"{where}: {col} = {num}: boom {boom!r} has no action {num} in {actions_path}")
        if l_num[i] < f_num[i]:
            raise InputError(f"{where}: last_action = {l_num[i]} is before first_action = {f_num[i]}")
        if (zone, boom) in seen:
            raise InputError(f"{where}: boom {boom!r} has a second section in zone {zone!r} (row "
                             f"{seen[(zone, boom)] + 2}); a zone has one section per boom")
        seen[(zone, boom)] = i
        first[i], last[i] = index[(boom, f_num[i])], index[(boom, l_num[i])]
    zones = Zones(tuple(z.strip() for z in df["zone"]), first, last)
    for z in zones.names:
        if sum(name == z for name in zones.zone) < 2:
            row = zones.zone.index(z)
            raise InputError(f"{_row(path, row)}: zone {z!r} has one boom only; a zone is shared by two or more "
                             "booms")
    check_zones(acts, zones, str(path))
    return zones


def entry_orders(acts: Actions, zones: Zones) -> np.ndarray:
    """``(n, 2)`` interlocks that fix each zone's entry order as the actions' planned times have it (the
    nominal round): the section entered first ends before the next one's first action starts, and so on
    (a tie: the rig's first boom first, the rule's tie-break). Every execution with them is one of the
    round's with its zones (the sections never overlap), and the nominal round satisfies them, so they
    close no cycle: the round, its zones fixed, is robust as the round with zones was proved."""
    out = []
    for name in zones.names:
        s = [i for i, z in enumerate(zones.zone) if z == name]
        f, la = np.asarray(zones.first)[s], np.asarray(zones.last)[s]
        order = np.lexsort((acts.boom[f], acts.t_start[f]))
        out += [(int(la[i]), int(f[j])) for i, j in zip(order[:-1], order[1:], strict=True)]
    return np.array(out, int).reshape(-1, 2)
