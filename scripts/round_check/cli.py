"""The command: read, check, print one JSON object; exit 0 clean, 1 violations (or a clearance that
cannot be certified), 2 an input that cannot be judged (a file, an argument or a setting, named on stderr),
3 a failure of the checker's own (its traceback on stderr): never reported as clean or as violations.

The JSON names the tunnel checked against (``tunnel``: the horseshoe's width and wall height, or a
profile's file and vertex count) and, where a plan is checked, the navigation that took it into the rig
frame (``navigation``: the pose given, or the points fit's rms, worst point and pose).

A planned set with an actions file is also *certified* (:mod:`round_check.certify`): d_boom between every
two segments of two booms that some drilling durations can make overlap, exactly, whatever the draws;
the JSON's ``execution.certified`` says what was checked and what failed."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
import traceback
from pathlib import Path

import numpy as np

from . import rules
from .actions import agree, read_actions, read_interlocks, read_zones
from .certify import certify
from .distance import SURFACES
from .errors import InputError
from .execute import draws, graph, read_draws
from .executed import check as check_executed
from .executed import episode_floors
from .files import read_plan, read_round_table, read_summary, read_trajectory
from .paths import project_path
from .realised import follow
from .settings import differences, settings
from .sweep import Sweep

# The exit codes, one meaning each: the numbers of the stages' table (pipeline/core/exit_codes.py, which this
# checker does not import; tests/test_exit_codes.py holds the two together).
EXIT_CLEAN = 0  # no violation, every clearance certified
EXIT_VIOLATIONS = 1  # violations found, or a clearance that cannot be certified: the JSON says which
EXIT_INPUT = 2  # an input (file, argument, setting) the checker cannot judge: named on stderr
EXIT_INTERNAL = 3  # the checker itself failed (a bug, or memory): its traceback on stderr; no verdict

USAGE = """python scripts/check_round.py <stem>_trajectory.csv [hydra overrides, as the stage's: rig=twin ...]
        [--round F] [--summary F] [--plan F] [--spacing-m 0.005] [--collar-tol-mm 0.1] [--angle-tol-deg A]
        [--levels 4] [--trajectory-only] [--actions F] [--interlocks F] [--zones F] [--execute N] [--seed S]
        [--draws F] [--realised] [--other-tunnel]"""


# a set's file names after its stem: the planned set, and the realised one the execute stage writes
NAMES = {False: {"trajectory": "_trajectory.csv", "round": "_round.csv", "summary": "_round.json",
                 "actions": "_actions.csv", "interlocks": "_interlocks.csv", "zones": "_zones.csv"},
         True: {"trajectory": "_executed_trajectory.csv", "round": "_executed_round.csv", "summary": "_executed.json",
                "actions": "_executed_actions.csv", "interlocks": "_executed_interlocks.csv",
                "zones": "_executed_zones.csv"}}


def _sibling(trajectory: Path, realised: bool, which: str) -> Path | None:
    """``<stem><suffix>`` beside ``<stem>_trajectory.csv`` (realised: ``<stem>_executed_trajectory.csv``)."""
    own = NAMES[realised]["trajectory"]
    if not trajectory.name.endswith(own):
        return None
    return trajectory.with_name(trajectory.name[: -len(own)] + NAMES[realised][which])


def _siblings(trajectory: Path, round_csv, summary, plan, realised: bool = False):
    if _sibling(trajectory, realised, "round") is None and (round_csv is None or summary is None):
        raise InputError(f"{trajectory}: not named <stem>{NAMES[realised]['trajectory']}: give --round and --summary")
    round_csv = Path(round_csv) if round_csv else _sibling(trajectory, realised, "round")
    summary = Path(summary) if summary else _sibling(trajectory, realised, "summary")
    real = _sibling(trajectory, True, "summary")
    if not realised and not summary.exists() and real is not None and real.exists():
        raise InputError(f"{trajectory}: a realised set ({real.name} beside it, no {summary.name}): check it with "
                         "--realised")
    return round_csv, summary, plan


def _planned_with(doc: dict, path: Path, st, other_tunnel: bool = False):
    """The round's ``planned_with`` (rig, booms, tunnel) held to the composed settings': an :class:`InputError`
    naming each difference, else ``"matches"`` (``"not recorded"`` for a JSON from before it was written).
    ``other_tunnel``: a tunnel other than the planned one is what is asked for (a what-if: the drift as
    surveyed); then both are returned, for the report. Another rig is refused always."""
    planned = doc.get("planned_with")
    if planned is None:
        return "not recorded"
    if not isinstance(planned, dict) or not isinstance(planned.get("rig"), dict):
        raise InputError(f"{path}: planned_with = {str(planned)[:200]!r}: expected the rig and tunnel record")
    rig = differences(planned["rig"], st.record["rig"], "rig")
    tunnel = differences(planned.get("tunnel"), st.record["tunnel"], "tunnel")
    diff = rig + ([] if other_tunnel else tunnel)
    if diff:
        shown = "; ".join(diff[:6]) + (f"; and {len(diff) - 6} more" if len(diff) > 6 else "")
        raise InputError(f"{path}: the round was planned with another {'rig' if rig else 'tunnel'} than the settings "
                         f"compose ({shown}): pass the stage's own overrides (rig=..., tunnel=..., tunnel.file=...)"
                         + ("" if rig else ", or --other-tunnel to check it in this tunnel on purpose"))
    if tunnel:
        return {"tunnel": "other than planned (--other-tunnel)", "planned": planned.get("tunnel"),
                "checked": st.record["tunnel"]}
    return "matches"


def _plan_path(summary: dict, path: Path, plan) -> Path:
    if plan:
        return Path(plan)
    p = summary.get("plan")
    if not isinstance(p, str) or not p:
        raise InputError(f"{path}: no `plan` field naming the drill plan: give --plan")
    holes = summary.get("plan_holes")
    if p.lower().endswith(".xml") and isinstance(holes, str) and holes and Path(holes).name == holes:
        # an IREDES plan: the holes the execute stage read from it, as CSV, beside the JSON (docs/round.md)
        return path.parent / holes
    p = Path(p)
    return project_path(p)  # as the stage resolves a relative plan: in the checkout (else the working directory)


def _in_rig_frame(plan, nav):
    """The plan's collars and toes in the rig frame: with ``navigation`` set, the plan is in its own frame and
    the checker's transform (:mod:`round_check.navigation`) takes it over; without, as read."""
    if nav.doc.get("given") is None:
        return plan
    return dataclasses.replace(plan, collar=nav.to_rig(plan.collar), toe=nav.to_rig(plan.toe))


def _minima(values: np.ndarray, mask) -> float | None:
    """The least value, or None where there is none or no floor could be claimed (-inf: a body sampled
    outside the profile, a violation reported on its own)."""
    v = values[mask]
    return float(v.min()) if v.size and np.isfinite(v.min()) else None


def _report_clearances(sw: Sweep, res, st) -> tuple[dict, dict]:
    keys = sw.keys
    booms, pairs = {}, {}
    for bi, b in enumerate(st.booms):
        own = {}
        sel = np.array([k.kind == "self" and k.booms == (bi,) for k in keys])
        if sel.any():
            own["self_m"] = {"sampled": _minima(res.sampled, sel), "certified": _minima(res.certified, sel)}
        tun = {}
        for s in SURFACES:
            sel = np.array([k.kind == "tunnel" and k.booms == (bi,) and k.surface == s for k in keys])
            tun[s] = {"sampled": _minima(res.sampled, sel), "certified": _minima(res.certified, sel)}
        own["tunnel_m"] = tun
        booms[b.name] = own
    for ki, k in enumerate(keys):
        if k.kind == "boom":
            a, c = (st.booms[i].name for i in k.booms)
            pairs[f"{a}-{c}"] = {"distance_m": {"sampled": float(res.sampled[ki] + st.d_boom),
                                                "certified": _minima(res.certified + st.d_boom, ki)},
                                 "at_s": float(res.sampled_at[ki])}
    return booms, pairs


def _describe(k, st) -> str:
    if k.kind == "self":
        return f"boom {st.booms[k.booms[0]].name}", "self clearance"
    if k.kind == "tunnel":
        b = st.booms[k.booms[0]]
        return f"boom {b.name}", f"{k.surface} clearance of the {b.model.bodies[k.body].name}"
    a, c = (st.booms[i].name for i in k.booms)
    return f"booms {a} and {c}", "boom-boom clearance (distance - d_boom)"


def _messages(sw: Sweep, res, st, ctx) -> tuple[list[str], list[str]]:
    # stretches cut by chunk edges share the edge instant: join them
    runs = sorted(res.runs)
    joined = []
    for r in runs:
        if joined and joined[-1][0] == r[0] and r[1] <= joined[-1][2]:
            p = joined[-1]
            worse = r if r[4] < p[4] else p
            joined[-1] = (p[0], p[1], max(p[2], r[2]), worse[3], worse[4])
        else:
            joined.append(r)
    viol, count = [], {}
    for k, t0, t1, tw, worst in joined:
        count[k] = count.get(k, 0) + 1
        if count[k] > rules.MAX_PER_CHECK:
            continue
        who, what = _describe(sw.keys[k], st)
        where = "; ".join(f"boom {st.booms[i].name} {ctx[st.booms[i].name].at(tw)}" for i in sw.keys[k].booms)
        viol.append(f"{who}, t={t0:.3f}..{t1:.3f} s ({where}): {what} {worst:.5f} m < 0 at t={tw:.4f} s")
    viol += [f"{_describe(sw.keys[k], st)[0]}: {n - rules.MAX_PER_CHECK} more stretches below its clearance"
             for k, n in count.items() if n > rules.MAX_PER_CHECK]
    unclear = []
    for k, t0, t1, f in sorted(res.unclear)[: 5 * rules.MAX_PER_CHECK]:
        who, what = _describe(sw.keys[k], st)
        where = "; ".join(f"boom {st.booms[i].name} {ctx[st.booms[i].name].at(t0)}" for i in sw.keys[k].booms)
        unclear.append(f"{who}, t={t0:.4f}..{t1:.4f} s ({where}): {what} not certified: its floor is {f:.5f} m after "
                       f"{sw.levels} refinements, though every sample is clear")
    if len(res.unclear) > 5 * rules.MAX_PER_CHECK:
        unclear.append(f"{len(res.unclear) - 5 * rules.MAX_PER_CHECK} more intervals not certified")
    return viol, unclear


def check(trajectory, overrides=(), round_csv=None, summary=None, plan=None, spacing_m: float = 0.005,
          collar_tol_mm: float = 0.1, angle_tol_deg: float | None = None, levels: int = 4,
          trajectory_only: bool = False, actions=None, interlocks=None, execute: int | None = None,
          seed: int = 0, realised: bool = False, draws_file=None, zones=None, other_tunnel: bool = False) -> dict:
    """Check one round's files; returns the report (raises :class:`InputError` on input it cannot judge).

    ``trajectory_only``: the motion alone (clearances, limits, speeds, park, the planner's flags), for a
    trajectory file without its round table, JSON and plan; no hole and no makespan is checked.
    ``realised``: an executed round's set (``<stem>_executed_trajectory.csv`` and its siblings,
    :mod:`round_check.realised`). ``draws_file``: a planned round executed under exactly that file's
    draws (and the nominal one; with ``execute``, the checker's own too)."""
    _arguments(spacing_m, collar_tol_mm, angle_tol_deg, levels, execute, seed)
    if realised and (execute is not None or draws_file):
        # a realised set ran once, under the rock's durations: it is judged at its own times
        raise InputError(f"{'--execute' if execute is not None else '--draws'} with --realised: drawn durations are "
                         "for a planned round's actions; a realised set is checked at the times it was executed "
                         "(drop one of the two)")
    if trajectory_only and (execute is not None or actions or interlocks or draws_file or zones):
        raise InputError("--trajectory-only checks the motion alone: no --actions, --interlocks, --zones, --execute "
                         "or --draws")
    trajectory = Path(trajectory)
    if not trajectory.is_file():
        raise InputError(f"{trajectory}: no such trajectory file")
    st = settings(list(overrides))
    if trajectory_only:
        return _motion(st, trajectory, spacing_m, levels, None, {"checked": "trajectory only: no hole, round "
                                                                            "table or makespan check"})
    round_csv, summary_path, plan = _siblings(trajectory, round_csv, summary, plan, realised)
    doc = read_summary(summary_path)
    if doc.get("rig") not in (None, st.rig):
        raise InputError(f"{summary_path}: the round was planned for rig {doc['rig']!r}, the settings compose rig "
                         f"{st.rig!r}: pass rig={doc['rig']} (and the stage's other overrides)")
    same = _planned_with(doc, summary_path, st, other_tunnel)
    if realised and doc.get("realised") is not True:
        raise InputError(f"{summary_path}: no \"realised\": true: not a realised set (a planned one is checked "
                         "without --realised)")
    if not realised and doc.get("realised") is True:
        raise InputError(f"{summary_path}: \"realised\": true: an executed round's set: check it with --realised")
    rows = read_trajectory(trajectory, {b.name: b.model.joint_names for b in st.booms})
    table = read_round_table(round_csv, realised)
    plan_path = _plan_path(doc, summary_path, plan)
    holes_plan = _in_rig_frame(read_plan(plan_path), st.navigation)
    depth = max((b.model.preview_depth for b in st.booms), default=0.0) or 1.0
    collar_tol = collar_tol_mm * 1e-3
    # the matching angle: the direction error that moves the preview point (paper 000 eq. 3) by the collar tolerance
    angle_tol = math.radians(angle_tol_deg) if angle_tol_deg is not None else collar_tol / depth

    stopped = frozenset(table["hole_id"][table["status"] == "interrupted"])
    # input errors before any sweep; drawn durations (--execute, even 0, or --draws) need an actions file
    wants = execute is not None or bool(draws_file)
    execution = _read_execution(st, trajectory, rows, actions, interlocks, 0 if wants else None, realised, zones)
    file_draws = None
    if draws_file:
        acts = execution[0]
        file_draws = read_draws(Path(draws_file), holes_plan.ids, list(acts.hole[acts.kind == "drill"]))
    given = table[table["status"] == "ok"]["boom"].value_counts().to_dict()
    report = _motion(st, trajectory, spacing_m, levels, given, {}, rows)
    msgs, hole_stats = rules.holes(st, rows, table, holes_plan, collar_tol, angle_tol, realised)
    for b in st.booms:
        report["booms"][b.name].update(hole_stats.get(b.name, {}))
    mk, _ = rules.makespan(rows, doc, summary_path)
    report["violations"] = msgs + mk + report["violations"]
    if not isinstance(execution, tuple):
        report["execution"] = execution
    elif realised:
        follow_msgs, report["execution"] = follow(*execution, rows, trajectory, stopped)
        report["violations"] += follow_msgs
    else:
        report["execution"] = _execution(st, rows, holes_plan, *execution, execute, seed, spacing_m, levels, report,
                                         file_draws)
    if realised:
        report["realised"] = {"factor": {k: hole_stats["_factors"][k] for k in ("min", "max")},
                              "factor_per_hole": hole_stats["_factors"]["per_hole"],
                              "interrupted": hole_stats["_holes"].pop("interrupted")}
    report.update({"round": str(round_csv), "summary": str(summary_path), "plan": str(plan_path),
                   "navigation": st.navigation.doc, "planned_with": same,
                   "collar_tol_mm": collar_tol_mm, "angle_tol_deg": math.degrees(angle_tol),
                   "json_makespan_s": float(doc["makespan_s"]), "holes": hole_stats["_holes"]})
    return report


# bounds of the arguments (docs/round.md, "Output and exit codes"): outside them a check would only run out of
# memory or time (--spacing-m 1e-9 samples every body point each nanometre), never judge better
SPACING_M = (1e-3, 1.0)
MAX_DRAWS = 10_000  # --execute: random draws, each swept for d_boom (the stage's draws.count has the same bound)
MAX_SEED = 2**32 - 1


def _arguments(spacing_m, collar_tol_mm, angle_tol_deg, levels, execute, seed) -> None:
    """Each argument within its range, before any file is read: an :class:`InputError` naming it otherwise."""
    def number(v):
        return not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)

    def whole(v):
        return not isinstance(v, bool) and isinstance(v, int)

    if not (number(spacing_m) and SPACING_M[0] <= spacing_m <= SPACING_M[1]):
        raise InputError(f"--spacing-m = {spacing_m!r}: must be a number in [{SPACING_M[0]:g}, {SPACING_M[1]:g}] m "
                         "(the most a body point moves between two samples; the certificate refines where needed)")
    if not (number(collar_tol_mm) and collar_tol_mm > 0):
        raise InputError(f"--collar-tol-mm = {collar_tol_mm!r}: must be a number > 0")
    if angle_tol_deg is not None and not (number(angle_tol_deg) and 0 < angle_tol_deg <= 180):
        raise InputError(f"--angle-tol-deg = {angle_tol_deg!r}: must be a number in (0, 180]")
    if not (whole(levels) and 0 <= levels <= 10):
        raise InputError(f"--levels = {levels!r}: must be an integer in 0..10")
    if execute is not None and not (whole(execute) and 0 <= execute <= MAX_DRAWS):
        raise InputError(f"--execute = {execute!r}: must be a whole number of draws in 0..{MAX_DRAWS}")
    if not (whole(seed) and 0 <= seed <= MAX_SEED):
        raise InputError(f"--seed = {seed!r}: must be a whole number in 0..{MAX_SEED} (numpy's seed)")


def _read_execution(st, trajectory: Path, rows, actions, interlocks, execute, realised: bool = False, zones=None):
    """(actions, interlocks, zones) read (and, for a planned round, held against the trajectory), or a note why
    none is checked. A realised round's disagreements are its violations (:func:`follow`), not input errors.
    The zones file: ``--zones``, else ``<stem>_zones.csv`` when it is there; none is no zone."""
    a_path = Path(actions) if actions else _sibling(trajectory, realised, "actions")
    if not actions and (a_path is None or not a_path.exists()):
        if execute is not None or interlocks or zones:
            raise InputError(f"{a_path or trajectory}: no actions file to execute: give --actions")
        return {"checked": False, "why": f"no actions file ({a_path or 'give --actions'})"}
    i_path = Path(interlocks) if interlocks else _sibling(trajectory, realised, "interlocks")
    if i_path is None:
        raise InputError(f"{trajectory}: not named <stem>{NAMES[realised]['trajectory']}: give --interlocks")
    if zones and not Path(zones).is_file():
        raise InputError(f"{zones}: no such zones file")
    z_path = Path(zones) if zones else _sibling(trajectory, realised, "zones")
    acts = read_actions(a_path, [b.name for b in st.booms])
    if not realised:
        agree(acts, rows, trajectory)
    return acts, read_interlocks(i_path, acts), read_zones(z_path, acts)


def _execution(st, rows, plan, acts, locks, zones, execute, seed, spacing_m, levels, report, file_draws=None) -> dict:
    L = np.linalg.norm(plan.toe - plan.collar, axis=1)
    spec = dict(zip(plan.ids, st.drill_times(L).sum(1), strict=True))
    spec = {h: float(v) for h, v in spec.items() if np.isfinite(v)}
    drill = acts.kind == "drill"
    dr = draws(list(acts.hole[drill]), acts.boom[drill], acts.booms, execute or 0, seed, execute is not None)
    if file_draws is not None:
        dr = dr + file_draws[0]
    g = graph(acts, locks)
    t0 = time.perf_counter()
    floors = episode_floors(st, rows, acts)
    t_floors = time.perf_counter() - t0
    cert = None
    if g.cycle is None:  # a deadlock is reported by the execution below, and nothing is certified
        cert, c_msgs, c_unclear = certify(acts, locks, zones, g, floors[2], st.d_boom, floors[1])
        cert["time_s"] = {"episode_floors": t_floors, "ordering_and_pairs": cert["time_s"]}
        report["violations"] += c_msgs
        report["not_certified"] += c_unclear
    out = check_executed(st, rows, acts, locks, g, dr, spec, spacing_m, levels, zones, floors)
    if file_draws is not None:
        out["draws_file"] = file_draws[1]
    report["violations"] += out.pop("messages")
    report["not_certified"] += out.pop("unclear")
    return {"checked": True, "seed": seed, "certified": cert, **out}


def _motion(st, trajectory, spacing_m, levels, given, head, rows=None) -> dict:
    """The checks of the motion itself: park, limits, speeds, the planner's flags, certified clearances."""
    if rows is None:
        rows = read_trajectory(trajectory, {b.name: b.model.joint_names for b in st.booms})
    given = given or {}
    ctx = {b.name: rules.Context(rows[b.name]) for b in st.booms}
    violations, booms_out = [], {}
    for b in st.booms:
        r = rows[b.name]
        violations += rules.park(b, r, int(given.get(b.name, 0)))
        violations += rules.limits(b, r, ctx[b.name])
        msgs, ratio = rules.speeds(b, r, ctx[b.name])
        violations += msgs
        violations += rules.unclear_moves(b, r, ctx[b.name])
        booms_out[b.name] = {"rows": int(len(r.t)), "end_s": float(r.t[-1]), "speed_ratio_max": ratio}
    sw = Sweep(st, rows, spacing_m, levels=levels)
    res = sw.run()
    clear, pairs = _report_clearances(sw, res, st)
    sampled, unclear = _messages(sw, res, st, ctx)
    violations += sampled
    for b in st.booms:
        booms_out[b.name].update(clear[b.name])
    return {
        "trajectory": str(trajectory), **head, "rig": st.rig, "tunnel": st.tunnel.describe(), "d_boom_m": st.d_boom,
        "safety_m": st.safety,
        "convention": "clearance = distance - radii - safety distance (boom-boom: distance - radii, against d_boom); "
                      ">= 0 passes",
        "spacing_m": spacing_m, "instants": res.instants, "refined_instants": res.refined,
        "makespan_s": max(float(r.t[-1]) for r in rows.values()), "booms": booms_out, "pairs": pairs,
        "min_boom_distance_m": min((p["distance_m"]["sampled"] for p in pairs.values()), default=None),
        "min_boom_distance_certified_m": min((p["distance_m"]["certified"] for p in pairs.values()
                                              if p["distance_m"]["certified"] is not None), default=None),
        "violations": violations, "not_certified": unclear,
    }


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # bad arguments: exit 2 with one line, like every input error
        print(f"check_round: {message}\nusage: {USAGE}", file=sys.stderr)
        raise SystemExit(EXIT_INPUT)


def main(argv=None) -> int:
    ap = _Parser(description="Check a round's files independently of the planner.", usage=USAGE)
    ap.add_argument("trajectory", type=Path)
    ap.add_argument("overrides", nargs="*", help="Hydra overrides, the stage's own (rig=twin ...)")
    ap.add_argument("--round", dest="round_csv", help="the round table (default <stem>_round.csv)")
    ap.add_argument("--summary", help="the round JSON (default <stem>_round.json)")
    ap.add_argument("--plan", help="the drill plan, CSV (default: the JSON's `plan`)")
    ap.add_argument("--spacing-m", type=float, default=0.005, help="most a body point moves between samples (m)")
    ap.add_argument("--collar-tol-mm", type=float, default=0.1)
    ap.add_argument("--angle-tol-deg", type=float, default=None, help="default: collar tolerance / preview depth")
    ap.add_argument("--levels", type=int, default=4, help="refinements (x8 each) of an interval not yet certified")
    ap.add_argument("--trajectory-only", action="store_true",
                    help="the motion alone (no round table, JSON or plan): no hole and no makespan check")
    ap.add_argument("--actions", help="the actions file (default <stem>_actions.csv, checked when there)")
    ap.add_argument("--interlocks", help="the interlocks file (default <stem>_interlocks.csv)")
    ap.add_argument("--zones", help="the zones file (zone, boom, first_action, last_action; default "
                                    "<stem>_zones.csv when there, else no zone)")
    ap.add_argument("--execute", type=int, default=None, metavar="N",
                    help="N random draws (0.7-1.5x drilling), each hole alone at 3x, each boom slow")
    ap.add_argument("--seed", type=int, default=0, help="seed of the random draws")
    ap.add_argument("--draws", dest="draws_file", metavar="F",
                    help="a draws file (draw, label, hole_id, factor): execute exactly its draws (planned sets)")
    ap.add_argument("--realised", action="store_true",
                    help="a realised set (<stem>_executed_trajectory.csv ...): drills at their own factor, the "
                         "actions' realised times against the rows and the interlocks")
    ap.add_argument("--other-tunnel", action="store_true",
                    help="check in the composed tunnel though the round was planned in another (a what-if, e.g. the "
                         "drift as surveyed); without it a round planned in another tunnel is refused (exit 2)")
    args = ap.parse_intermixed_args(argv)
    bad = [o for o in args.overrides if "=" not in o]
    if bad:
        print(f"check_round: {bad}: not Hydra overrides (key=value)\nusage: {USAGE}", file=sys.stderr)
        return EXIT_INPUT
    try:
        out = check(args.trajectory, args.overrides, args.round_csv, args.summary, args.plan, args.spacing_m,
                    args.collar_tol_mm, args.angle_tol_deg, args.levels, args.trajectory_only, args.actions,
                    args.interlocks, args.execute, args.seed, args.realised, args.draws_file, args.zones,
                    args.other_tunnel)
    except InputError as e:
        print(f"check_round: {e}", file=sys.stderr)
        return EXIT_INPUT
    except Exception:  # noqa: BLE001 - a fault of the checker's own: neither clean (0) nor violations (1)
        traceback.print_exc()
        print("check_round: internal error (the traceback above): the round was not judged; exit 3 is neither "
              "clean (0) nor violations (1)", file=sys.stderr)
        return EXIT_INTERNAL
    print(json.dumps(out, indent=1))
    return EXIT_VIOLATIONS if out["violations"] or out["not_certified"] else EXIT_CLEAN
