"""Checks on the rows themselves: joint limits, joint speeds, park at both ends, the planner's own
flags, every plan hole drilled once at its joints for its model time, and the makespan.

Each check returns messages naming the boom, the time and the hole (:class:`Context`).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from .files import BoomRows, Plan
from .settings import RigBoom, Settings

TURN = 2.0 * math.pi
LIMIT_TOL = 1e-9  # rad / m: a joint solved exactly onto its stop reads back within rounding
SPEED_TOL = 1e-9  # relative
PARK_TOL = 1e-6  # rad / m: parks are written from degrees
HOLD_TOL = 1e-9  # rad / m: the joints held through drilling are written unchanged
TIME_TOL = 1e-6  # s
MAX_PER_CHECK = 20  # messages per check and boom; the count of the rest is given


class Context:
    """What a boom is doing at a time: the hole it drills, or the hole it moves to."""

    def __init__(self, rows: BoomRows):
        self.rows = rows
        n = len(rows.t)
        pos = np.where(rows.event == "collar", np.arange(n), n)
        upcoming = np.minimum.accumulate(pos[::-1])[::-1]  # index of the next collar row (n: none)
        self.next = np.append(rows.hole, "park")[upcoming]

    def at(self, t: float) -> str:
        r = self.rows
        k = int(np.clip(np.searchsorted(r.t, t, side="right") - 1, 0, len(r.t) - 1))
        if r.event[k] in ("collar", "drill", "retract"):
            return f"hole {r.hole[k]} ({r.event[k]})"
        if k + 1 < len(r.t):
            return f"moving to hole {self.next[k + 1]}" if self.next[k + 1] != "park" else "moving to park"
        return "at its end"


def _wrap(q: np.ndarray, boom: RigBoom) -> np.ndarray:
    """Full-turn joints taken modulo a turn into their range; the others as written."""
    lo = boom.model.lo
    return np.where(boom.model.full_turn, lo + np.mod(q - lo, TURN), q)


def _fmt(j: int, v: float, boom: RigBoom) -> str:
    return f"{math.degrees(v):.4f} deg" if boom.model.revolute[j] else f"{v:.6f} m"


def _capped(msgs: list[str], what: str, boom: str) -> list[str]:
    if len(msgs) > MAX_PER_CHECK:
        return msgs[:MAX_PER_CHECK] + [f"boom {boom}: {len(msgs) - MAX_PER_CHECK} more {what}"]
    return msgs


def limits(boom: RigBoom, r: BoomRows, ctx: Context) -> list[str]:
    m = boom.model
    w = _wrap(r.q, boom)
    bad = (w < m.lo - LIMIT_TOL) | (w > m.hi + LIMIT_TOL)
    msgs = [f"boom {boom.name}, t={r.t[i]:.3f} s, {ctx.at(r.t[i])}: {m.joint_names[j]} = {_fmt(j, r.q[i, j], boom)} "
            f"outside its range [{_fmt(j, m.lo[j], boom)}, {_fmt(j, m.hi[j], boom)}] (row {r.line[i]})"
            for i, j in np.argwhere(bad)]
    return _capped(msgs, "rows beyond a joint limit", boom.name)


def speeds(boom: RigBoom, r: BoomRows, ctx: Context) -> tuple[list[str], float]:
    """A joint faster than its speed between two rows (linear in between: a constant speed)."""
    if len(r.t) < 2:
        return [], 0.0
    ratio = np.abs(np.diff(r.q, axis=0)) / np.diff(r.t)[:, None] / boom.speed
    bad = ratio > 1.0 + SPEED_TOL
    msgs = [f"boom {boom.name}, t={r.t[i]:.3f}..{r.t[i + 1]:.3f} s, {ctx.at(r.t[i])}: {boom.model.joint_names[j]} at "
            f"{ratio[i, j]:.4f} x its speed (rows {r.line[i]}-{r.line[i + 1]})" for i, j in np.argwhere(bad)]
    return _capped(msgs, "joint speeds over the limit", boom.name), float(ratio.max())


def park(boom: RigBoom, r: BoomRows, holes_given: int) -> list[str]:
    msgs = []
    if abs(r.t[0]) > TIME_TOL:
        msgs.append(f"boom {boom.name}: does not start at t = 0 (its first row, row {r.line[0]}, is at "
                    f"t={r.t[0]:.6f} s)")
    for k, where in ((0, "start"), (-1, "end")):
        off = np.abs(_wrap(r.q[k], boom) - _wrap(boom.park, boom))
        off = np.where(boom.model.full_turn, np.minimum(off, TURN - off), off)
        if (off > PARK_TOL).any():
            j = int(off.argmax())
            msgs.append(f"boom {boom.name}, t={r.t[k]:.3f} s: does not {where} at its park (row {r.line[k]}: "
                        f"{boom.model.joint_names[j]} = {_fmt(j, r.q[k, j], boom)}, "
                        f"park {_fmt(j, boom.park[j], boom)})")
    if holes_given and np.abs(r.q - r.q[0]).max() <= HOLD_TOL:
        msgs.append(f"boom {boom.name}: never leaves park, though the round table gives it {holes_given} hole(s)")
    return msgs


def unclear_moves(boom: RigBoom, r: BoomRows, ctx: Context) -> list[str]:
    """The planner's own flag: a move it could not clear (``move_unclear`` rows), one message per stretch."""
    flag = (r.event == "move_unclear").astype(np.int8)
    edges = np.diff(np.concatenate([[0], flag, [0]]))
    msgs = [f"boom {boom.name}, t={r.t[a]:.3f}..{r.t[b - 1]:.3f} s, {ctx.at(r.t[a])}: move not cleared by the planner "
            f"(event move_unclear, rows {r.line[a]}-{r.line[b - 1]})"
            for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True)]
    return _capped(msgs, "unclear moves", boom.name)


def holes(st: Settings, rows: dict[str, BoomRows], table: pd.DataFrame, plan: Plan, collar_tol_m: float,
          angle_tol_rad: float, realised: bool = False) -> tuple[list[str], dict]:
    """Every plan hole drilled once (or reported not drilled), at joints that put the drill end on its
    collar along its direction, held still for exactly the model time.

    ``realised`` (an executed round, docs/reference.md section 8): a drill lasts what the rock took, so its collaring,
    drilling and retraction are the model's parts times one common factor f > 0 (each part within
    :data:`TIME_TOL` of f times its model part, f = the drill's duration over its model duration); a hole
    the table reports ``interrupted`` is drilled at most once (any factor), by its boom at its times."""
    msgs, stats = [], {}
    where = {h: i for i, h in enumerate(plan.ids)}
    drilled: dict[str, list[tuple[str, float]]] = {}
    factors: dict[str, float] = {}
    for boom in st.booms:
        r = rows[boom.name]
        ks = np.flatnonzero(r.event == "collar")
        name = boom.name
        # the collar row, then drill, retract and the row ending the retraction, one hole throughout
        ok_shape = ks + 3 < len(r.t)
        for k in ks[~ok_shape]:
            msgs.append(f"boom {name}, t={r.t[k]:.3f} s, hole {r.hole[k]}: collar row (row {r.line[k]}) without its "
                        "drill, retract and end rows")
        ks = ks[ok_shape]
        seq_ok = ((r.event[ks + 1] == "drill") & (r.event[ks + 2] == "retract") & (r.hole[ks + 1] == r.hole[ks])
                  & (r.hole[ks + 2] == r.hole[ks]))
        for k in ks[~seq_ok]:
            msgs.append(f"boom {name}, t={r.t[k]:.3f} s, hole {r.hole[k]}: collar row (row {r.line[k]}) "
                        "not followed by this hole's drill and retract rows")
        ks = ks[seq_ok]
        paired = np.zeros(len(r.t), bool)
        paired[np.concatenate([ks, ks + 1, ks + 2])] = True
        for k in np.flatnonzero(np.isin(r.event, ["drill", "retract"]) & ~paired):
            msgs.append(f"boom {name}, t={r.t[k]:.3f} s, hole {r.hole[k]}: a {r.event[k]} row (row {r.line[k]}) "
                        "without its collar row")
        ids = r.hole[ks]
        for h, k in zip(ids, ks, strict=True):
            drilled.setdefault(h, []).append((name, float(r.t[k])))
        # held still from the collar row to the end of retraction
        span = np.stack([np.abs(r.q[ks + i] - r.q[ks]).max(1) for i in (1, 2, 3)], 1).max(1) if len(ks) else np.zeros(0)
        for k, moved in zip(ks[span > HOLD_TOL], span[span > HOLD_TOL], strict=True):
            msgs.append(f"boom {name}, t={r.t[k]:.3f} s, hole {r.hole[k]}: joints move between the collar row "
                        f"and the end of retraction (rows {r.line[k]}-{r.line[k + 3]}, by up to {moved:.3g})")
        # model time, part by part
        pi = np.array([where.get(h, -1) for h in ids], dtype=np.int64)
        known = pi >= 0
        if len(ks):
            L = np.full(len(ks), np.nan)
            L[known] = np.linalg.norm(plan.toe[pi[known]] - plan.collar[pi[known]], axis=1)
            spec = st.drill_times(L)
            parts = np.stack([r.t[ks + 1] - r.t[ks], r.t[ks + 2] - r.t[ks + 1], r.t[ks + 3] - r.t[ks + 2]], 1)
            # planned: the model's parts themselves; realised: the model's parts times the drill's own factor
            f = parts.sum(1) / spec.sum(1) if realised else np.ones(len(ks))
            off = np.abs(parts - f[:, None] * spec).max(1) > TIME_TOL
            for i in np.flatnonzero(off & np.isfinite(L)):
                k = ks[i]
                head = (f"boom {name}, t={r.t[k]:.3f} s, hole {r.hole[k]}: collaring, drilling, retraction last "
                        f"{parts[i, 0]:.6f} + {parts[i, 1]:.6f} + {parts[i, 2]:.6f} s")
                if realised:
                    with np.errstate(divide="ignore", invalid="ignore"):
                        own = parts[i] / spec[i]
                    msgs.append(f"{head}: not the model's parts {spec[i, 0]:.6f} + {spec[i, 1]:.6f} + {spec[i, 2]:.6f} "
                                f"s of its {L[i]:.4f} m times one factor (the whole drill {f[i]:.6f}x, the parts "
                                f"{own[0]:.6f}x, {own[1]:.6f}x, {own[2]:.6f}x)")
                else:
                    msgs.append(f"{head}; the model time for its {L[i]:.4f} m is {spec[i, 0]:.6f} + {spec[i, 1]:.6f} "
                                f"+ {spec[i, 2]:.6f} s")
            for i in np.flatnonzero(np.isfinite(L)):
                factors.setdefault(str(ids[i]), float(f[i]))
            # pose: drill end on the collar, feed along the hole
            H, z = boom.model.tool_pose(r.q[ks])
            H = H + boom.base
            c_err = np.full(len(ks), np.nan)
            a_err = np.full(len(ks), np.nan)
            ok = known & np.isfinite(L) & (L > 0)
            u = (plan.toe[pi[ok]] - plan.collar[pi[ok]]) / L[ok, None]
            c_err[ok] = np.linalg.norm(H[ok] - plan.collar[pi[ok]], axis=1)
            a_err[ok] = np.arctan2(np.linalg.norm(np.cross(z[ok], u), axis=1), np.einsum("ij,ij->i", z[ok], u))
            for i in np.flatnonzero(ok & ((c_err > collar_tol_m) | (a_err > angle_tol_rad))):
                k = ks[i]
                msgs.append(f"boom {name}, t={r.t[k]:.3f} s, hole {r.hole[k]}: drilled at joints that put the drill "
                            f"end {c_err[i] * 1e3:.4f} mm from its collar and the feed "
                            f"{math.degrees(a_err[i]):.5f} deg off its direction (tolerance "
                            f"{collar_tol_m * 1e3:g} mm, {math.degrees(angle_tol_rad):.5f} deg)")
            for i in np.flatnonzero(~ok):
                k = ks[i]
                msgs.append(f"boom {name}, t={r.t[k]:.3f} s, hole {r.hole[k]}: drilled, but the plan has no readable "
                            "hole of that id")
            stats[name] = {"holes_drilled": int(len(ks)),
                           "collar_error_max_mm": float(np.nanmax(c_err) * 1e3) if ok.any() else None,
                           "angle_error_max_deg": float(math.degrees(np.nanmax(a_err))) if ok.any() else None}
        else:
            stats[name] = {"holes_drilled": 0, "collar_error_max_mm": None, "angle_error_max_deg": None}
        # the round table's account of this boom's holes
        done = pd.DataFrame({"hole_id": ids, "k": ks}).merge(table, on="hole_id", how="left")
        k = done["k"].to_numpy()
        timed = ("ok", "interrupted") if realised else ("ok",)  # an interrupted hole: drilled (partly) at its times
        listed = done["status"].isin(timed).to_numpy()
        for h, s in zip(done["hole_id"][~listed], done["status"][~listed], strict=True):
            said = "lists no such hole" if pd.isna(s) else f"says {s}"
            msgs.append(f"boom {name}, hole {h}: drilled, but the round table {said}")
        if listed.any():
            d = done[listed]
            kk = k[listed]
            off = ((d["boom"].to_numpy() != name) | (np.abs(d["t_start_s"].to_numpy() - r.t[kk]) > TIME_TOL)
                   | (np.abs(d["t_end_s"].to_numpy() - r.t[kk + 3]) > TIME_TOL))
            for i in np.flatnonzero(off):
                row, kx = d.iloc[i], kk[i]
                msgs.append(f"boom {name}, t={r.t[kx]:.3f} s, hole {row['hole_id']}: drilled {r.t[kx]:.6f}.."
                            f"{r.t[kx + 3]:.6f} s, the round table says boom {row['boom']} "
                            f"{row['t_start_s']:.6f}..{row['t_end_s']:.6f} s")
    status = dict(zip(table["hole_id"], table["status"], strict=True))
    for h, by in drilled.items():
        if len(by) > 1:
            each = ", ".join(f"boom {b} at t={t:.3f} s" for b, t in sorted(by, key=lambda x: x[1]))
            if status.get(h) == "interrupted":
                msgs.append(f"hole {h}: interrupted, yet drilled {len(by)} times ({each}); an interrupted hole is "
                            "reported, drilled at most once and never again by any boom")
            else:
                msgs.append(f"hole {h}: drilled {len(by)} times ({each})")
    given = dict(zip(table["hole_id"], table["boom"], strict=True))
    for h in plan.ids:
        if h in drilled or not h:
            continue
        if h not in status:
            msgs.append(f"hole {h}: neither drilled nor reported in the round table")
        elif status[h] == "ok":
            msgs.append(f"hole {h}: never drilled, though the round table says boom {given[h]} drilled it")
    for h in table["hole_id"]:
        if h not in where:
            msgs.append(f"hole {h}: in the round table but not in the plan")
    reported = sum(1 for h in plan.ids if status.get(h) in ("unreachable", "invalid", "interrupted"))
    stats["_holes"] = {"plan": len(plan.ids), "drilled": len(drilled), "reported_not_drilled": int(reported)}
    if realised:
        stopped = [h for h in plan.ids if status.get(h) == "interrupted"]
        stats["_holes"]["interrupted"] = [{"hole_id": h, "boom": given[h], "drilled": h in drilled,
                                           "factor": factors.get(h)} for h in stopped]
        stats["_factors"] = {"min": min(factors.values(), default=None), "max": max(factors.values(), default=None),
                             "per_hole": factors}
    return msgs, stats


def makespan(rows: dict[str, BoomRows], summary: dict, path) -> tuple[list[str], float]:
    last = max(float(r.t[-1]) for r in rows.values())
    said = float(summary["makespan_s"])
    if abs(said - last) > TIME_TOL:
        return [f"makespan: {path} says {said:.6f} s, the trajectory file's last row is at {last:.6f} s"], last
    return [], last
