"""Stage: a planned round executed by events (docs/reference.md, section 8).

It reads the set ``schedule`` wrote for the plan (``<stem>_trajectory.csv``, ``_actions.csv``,
``_interlocks.csv``, ``_round.csv``, ``_round.json``; ``execute.round`` points elsewhere), first holding
every file it reads to the MD5 the round JSON records for it, the plan to ``plan_md5`` and the composed
rig and tunnel to ``planned_with`` (:func:`verify_planned`: a changed file is refused, exit 2, naming it),
and

1. executes it under the drilling-time model of the ``draws`` group (seeded uniform factors, stalls
   with a probability, fixed factors of named holes) by the execution rule: every draw at once, the
   makespans and the standing at interlocks summarised, the factors written to ``<stem>_draws.csv``;
2. realises one round (``execute.draw``: ``nominal`` or the k-th random draw) and, with
   ``execute.interrupt.hole`` / ``at_s``, interrupts that hole: the round is then handed on
   (:mod:`pipeline.events.interrupt`), re-planned from where every boom stands (``replan: true``, the
   instance rebuilt from the plan and the rig as ``schedule`` builds it) or going on with its own actions;
3. writes the executed set (``<stem>_executed_trajectory.csv`` in the section-7 format,
   ``_executed_actions.csv`` with the executed times, ``_executed_interlocks.csv``, ``_executed_round.csv``,
   ``_executed.json``, ``_executed_makespans.png``, ``_executed_replay.html``, and the as-drilled log
   ``_executed_quality.xml``: IREDES DRPQual, each hole where the rig's real boom drilled it, in the plan frame,
   :mod:`pipeline.events.as_drilled_log`), published whole and never over the planned files;
4. checks with the independent checker (``scripts/check_round.py``, or ``python -m round_check`` installed
   from the wheel: a separate process that imports nothing of ``pipeline``), on the staged set before it is
   published: the planned set on exactly the draws (``--draws``), and the realised set (``--realised``);
   their verdicts go into the JSON. For an
   IREDES plan both get the holes as read, as CSV (``<stem>_executed_plan.csv``, in the set). A check
   that cannot judge the set stops the stage (exit 2 for the checker's 2, else 3) and nothing is
   published; so does a signal (exit 128 + signum, the previous set intact), and so does a realised round
   that deadlocks (exit 3). Under ``execute.strict`` a failed check, draws that deadlock or a hand-on round
   that cannot be made robust exit 1 (after writing the set). The codes: :mod:`pipeline.core.exit_codes`.

Re-planning seconds and the checks' seconds are MLflow metrics (``timing.*``), not in the JSON.
"""

from __future__ import annotations

import json
import logging
import subprocess
import sys
import time
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

import numpy as np
import pandas as pd
from omegaconf import DictConfig

from pipeline.assembly.rig import composed_rig, model_files, rig_record, true_rig_booms
from pipeline.calibration.model_file import model_setting
from pipeline.core.config import IN_CHECKOUT, PROJECT_ROOT, as_dict, base_dir, project_path
from pipeline.core.csv_input import read_text_csv
from pipeline.core.errors import ConfigError, Deadlock, InputError, JobFailed, StrictCheckFailed
from pipeline.core.exit_codes import ExitCode
from pipeline.core.io import file_md5, require_writable, save_figure, write_csv, write_text
from pipeline.core.settings import coerce, parse, rule
from pipeline.core.stage import run_stage, stage_main
from pipeline.events.actions import (
    actions_from_table,
    actions_table,
    interlocks_table,
    read_actions,
    read_interlocks,
)
from pipeline.events.as_drilled_log import drilled_holes
from pipeline.events.draws import draws, fixed_factors, parse_draws, run, summary
from pipeline.events.executed_files import draws_table, executed_round_table, long_holes
from pipeline.events.interrupt import interrupted_round, standing
from pipeline.events.rule import execute
from pipeline.events.trajectory import action_rows, retimed
from pipeline.events.zones import NO_ZONES, entry_orders, read_zones, zones_table
from pipeline.plans.drpqual import write_quality_log
from pipeline.plans.model import COLLAR
from pipeline.plans.navigation import NavigationSettings, same_navigation
from pipeline.plans.read import read_plan_in_rig_frame
from pipeline.plans.solutions import spreadsheet_safe
from pipeline.round.output import EXECUTED, round_paths, write_round_set
from pipeline.tracking.runs import TrackingSettings, stage_run

log = logging.getLogger(__name__)
CHECKER = "scripts/check_round.py"


def checker_command() -> list[str]:
    """The independent checker's command: the checkout's script, else the installed ``round_check`` package
    (the wheel ships it; ``boom-ik-check-round`` is the same command)."""
    script = PROJECT_ROOT / CHECKER
    if IN_CHECKOUT and script.is_file():
        return [sys.executable, str(script)]
    return [sys.executable, "-m", "round_check"]


@dataclass(frozen=True)
class InterruptSettings:
    hole: str | None = None
    at_s: float | None = field(default=None, metadata=rule(gt=0, le=86_400))


@dataclass(frozen=True)
class ExecuteSettings:
    """The ``execute`` node (conf/execute/default.yaml)."""

    round: str | None = None
    out: str | None = None
    draw: str = "0"
    replan: bool = True
    monte_carlo: bool = True
    check: bool = True
    strict: bool = False
    figures: bool = True
    replay: bool = True
    replay_frames: int = field(default=400, metadata=rule(ge=2, le=10_000))
    progress: bool = True
    start_time: str = "2026-01-01T07:00:00"  # the round's start on the clock: the as-drilled log's times
    # the boom the rig really has, for the as-drilled log (pipeline/events/as_drilled_log.py): a boom config
    # file, or a calibrated model file; null: the model the round was planned with
    true_boom: str | None = None
    true_boom_model: str | None = None


def parse_execute(cfg: DictConfig) -> tuple[ExecuteSettings, InterruptSettings]:
    node = dict(as_dict(cfg.execute))
    inter = parse(InterruptSettings, node.pop("interrupt", None) or {}, "execute.interrupt")
    replan_round(cfg, node.pop("replan_round", None))  # round overrides: checked now, used when a round is handed on
    node["draw"] = str(node.get("draw", "0"))
    s = parse(ExecuteSettings, node, "execute")
    if s.draw != "nominal" and not s.draw.isdigit():
        raise ConfigError(f"execute.draw = {s.draw!r}: expected nominal or a whole number (the k-th random draw)")
    if (inter.hole is None) != (inter.at_s is None):
        raise ConfigError("execute.interrupt: set both hole and at_s (or neither)")
    try:
        datetime.fromisoformat(s.start_time)
    except ValueError:
        raise ConfigError(f"execute.start_time = {s.start_time!r}: expected an ISO 8601 date and time, e.g. "
                          "2026-01-01T07:00:00") from None
    return s, inter


def replan_round(cfg, node=None):
    """The round settings of a re-plan: the round group's, then ``execute.replan_round``'s, each key of which
    must be a round setting (an unknown one is refused, not ignored) and every value in its range."""
    import dataclasses

    from pipeline.core.settings import unknown_keys
    from pipeline.round.settings import RoundSettings, parse_round

    node = as_dict(cfg.execute.get("replan_round")) if node is None else node
    node = node or {}
    if not isinstance(node, dict):
        raise ConfigError(f"execute.replan_round = {node!r}: expected a mapping of round settings")
    unknown_keys(node, {f.name for f in dataclasses.fields(RoundSettings)}, "execute.replan_round",
                 " (round settings of the re-plan after an interruption)")
    return parse_round({**as_dict(cfg.round), **node}, "round + execute.replan_round")


# what execute reads of the planned set: each must be the file schedule wrote (its MD5 in the JSON's manifest)
READS = ("trajectory", "actions", "interlocks", "zones", "round", "moves", "problem")
MAX_JSON_MB = 64.0  # the planned round's JSON, read whole (as the checker's bound)


def _planned_doc(path) -> dict:
    """The planned round's JSON, or an :class:`InputError` naming the file and the place."""
    if path.stat().st_size > MAX_JSON_MB * 1e6:
        raise InputError(f"{path}: {path.stat().st_size / 1e6:.1f} MB, over {MAX_JSON_MB:g} MB for a round's JSON "
                         "(a round's is tens of kB); not read")
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read the planned round's JSON ({e})") from None
    try:
        doc = json.loads(text)
    except (json.JSONDecodeError, RecursionError) as e:
        where = (f"line {e.lineno}, column {e.colno}: {e.msg}" if isinstance(e, json.JSONDecodeError)
                 else "nested too deep")
        raise InputError(f"{path}: not valid JSON ({where}); re-run schedule") from None
    if not isinstance(doc, dict):
        raise InputError(f"{path}: expected a JSON object (the planned round's summary), got {type(doc).__name__}")
    return doc


def verify_planned(planned, doc: dict, plan_path, recorded_with: dict) -> None:
    """The planned files execute reads are those schedule wrote, the plan is the one the round was planned
    from and the rig and tunnel are those it was planned with: an :class:`InputError` (a file: changed,
    not in the manifest) or :class:`ConfigError` (settings) naming what differs, before any work.

    The JSON's ``files`` holds the MD5 of each sibling (written last, :func:`write_round_set`), ``plan_md5``
    the plan's; the plan is compared by content, not path (a DVC temporary copy runs it under another path)."""
    from pipeline.assembly.rig import record_differences

    where = planned["json"]
    manifest = doc.get("files")
    if not isinstance(manifest, dict) or not all(isinstance(v, str) for v in manifest.values()):
        raise InputError(f"{where}: no `files` manifest (each planned file's MD5): not a set schedule wrote; "
                         "re-run schedule")
    for kind in READS:
        path = planned[kind]
        said = manifest.get(path.name)
        if said is None:
            if kind == "moves" and not path.exists():
                continue  # no move book: every move is certified again
            if kind == "zones" and not path.exists():
                continue  # planned before zones files were written: no zone (docs/reference.md, section 9)
            if kind == "problem" and not path.exists():
                raise InputError(f"{path}: not found, and {where} does not list it: a set planned before schedule "
                                 "wrote the round's problem; re-run schedule")
            raise InputError(f"{path}: not in the manifest of {where} (`files`): not a file of the planned set; "
                             "re-run schedule, or remove it")
        if not path.is_file():
            if kind == "moves":
                continue
            raise InputError(f"{path}: not found; {where} lists it")
        now = file_md5(path)
        if now != said:
            raise InputError(f"{path}: changed since schedule wrote it (MD5 {now}; {where.name} records {said}): "
                             "execute runs the planned files as planned; re-run schedule for a changed round")
    said = doc.get("plan_md5")
    if not isinstance(said, str):
        raise InputError(f"{where}: no plan_md5 (the plan's MD5): planned before plans were recorded; re-run schedule")
    now = file_md5(plan_path)
    if now != said:
        raise InputError(f"plan = {plan_path}: not the plan {where.name} was planned from (its MD5 {now}; the round "
                         f"records {said} for {doc.get('plan')}): a plan changed after planning is planned again "
                         "(python -m pipeline.schedule), never executed on the old round")
    planned_with = doc.get("planned_with")
    if not isinstance(planned_with, dict):
        raise InputError(f"{where}: no planned_with (the rig and tunnel it was planned with); re-run schedule")
    diff = record_differences(planned_with, recorded_with)
    if diff:
        raise ConfigError(f"{where} was planned with another rig or tunnel than this run's ({'; '.join(diff[:6])}): "
                          "give the settings it was planned with (rig=..., tunnel=..., tunnel.file=...)")


def _csv(path, columns, what: str, numeric=()) -> pd.DataFrame:
    """A planned CSV, every column there and every ``numeric`` cell a finite number; else an :class:`InputError`
    naming the file, the column and the row (file line)."""
    # the checker's bound on a planned file's size (round_check/files.py)
    df = read_text_csv(path, what, list(columns), max_mb=256.0)
    for c in numeric:
        v = pd.to_numeric(df[c], errors="coerce").to_numpy(float)
        bad = ~np.isfinite(v)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise InputError(f"{path}: row {i + 2}: {c} = {df[c].iloc[i]!r} is not a finite number ({what})")
    return df


def _read_trajectory(path, names: list[str]) -> pd.DataFrame:
    df = _csv(path, ["boom", "t", *names, "event", "hole_id"], "trajectory file", ["t", *names])
    return df.astype({c: float for c in ["t", *names]})


def _read_round_table(path, names: list[str]) -> pd.DataFrame:
    df = _csv(path, ["hole_id", "boom", "status", "reason", *names], "round table")
    ok = df["status"] == "ok"
    for c in names:
        v = pd.to_numeric(df[c], errors="coerce").to_numpy(float)
        bad = ok.to_numpy() & ~np.isfinite(v)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise InputError(f"{path}: row {i + 2}: {c} = {df[c].iloc[i]!r} is not a finite number (round table)")
    out = pd.read_csv(path, keep_default_na=False, dtype={"hole_id": str, "boom": str})
    return out.replace({"": np.nan}).assign(hole_id=out["hole_id"], boom=out["boom"], status=out["status"],
                                            reason=out["reason"])


def _plan_holes(plan) -> pd.DataFrame:
    """The plan's holes as the stage read them, in the plan's own frame (its navigation undone), as a CSV plan
    (``hole_id``, collar and toe x y z), each unreadable row an id without coordinates (the round table's
    ``invalid`` row): what the independent checker reads for an IREDES plan, which it does not parse."""
    from pipeline.plans.model import COORDS

    xyz = plan.holes[COORDS].to_numpy(float)
    if plan.navigation is not None:
        xyz = plan.navigation.to_plan(xyz)
    good = pd.DataFrame(xyz, columns=COORDS)
    good.insert(0, "hole_id", plan.holes["hole_id"].astype(str).to_numpy())
    lines = np.arange(len(good)) if plan.lines is None else np.asarray(plan.lines)
    by_row: dict[int, str] = {}
    for p in plan.problems:
        by_row.setdefault(p.row, p.hole_id or f"row {p.row}")
    bad = pd.DataFrame({"hole_id": list(by_row.values())})
    order = np.argsort(np.concatenate([lines, np.array(sorted(by_row), dtype=lines.dtype)]), kind="stable")
    return pd.concat([good, bad], ignore_index=True).iloc[order].reset_index(drop=True)


def _planned_set(cfg, plan_path, settings: ExecuteSettings):
    """The planned set's paths, every file checked to exist (a clear error: run schedule first)."""
    planned = round_paths(plan_path, project_path(settings.round) if settings.round else None)
    for kind in ("trajectory", "actions", "interlocks", "round", "json"):
        if not planned[kind].is_file():
            raise InputError(f"{planned[kind]}: not found; the execute stage runs a round that schedule planned "
                             f"(python -m pipeline.schedule plan={plan_path} rig=...), or point execute.round at it")
    return planned


def _check(args: list[str], what: str) -> dict:
    """Run the independent checker; its JSON verdict (stdout's last line) and exit code."""
    started = time.perf_counter()
    proc = subprocess.run([*checker_command(), *args], capture_output=True, text=True, cwd=str(base_dir()))
    out = {"exit": proc.returncode, "seconds": time.perf_counter() - started, "stderr": proc.stderr[-4000:]}
    try:  # the checker prints one JSON document
        doc = json.loads(proc.stdout) if proc.stdout.strip() else None
    except json.JSONDecodeError:
        doc = None
    out["verdict"] = _verdict(doc)
    if proc.returncode in (0, 1):
        out.pop("stderr")
    if proc.returncode not in (0, 1):
        log.error("checker (%s) exit %d: %s", what, proc.returncode, proc.stderr.strip()[-2000:])
    return out


def _verdict(doc: dict | None) -> dict | None:
    """What the executed set keeps of a checker's report: its counts, not its messages."""
    if doc is None:
        return None
    keep = {"violations": len(doc.get("violations") or [])}
    if isinstance(doc.get("holes"), dict):  # the plan's holes it judged: counts, and the plan file's name
        keep["holes"] = {k: v for k, v in doc["holes"].items() if k in ("plan", "drilled", "reported_not_drilled")}
        keep["plan"] = Path(str(doc.get("plan", ""))).name
    ex = doc.get("execution")
    if isinstance(ex, dict):
        keep["execution"] = {k: ex[k] for k in ("draws", "violating_draws", "deadlocks", "violations",
                                                "min_executed_candidate_distance_m", "interlocks_broken") if k in ex}
    r = doc.get("realised")
    if isinstance(r, dict):
        keep["realised"] = {k: r[k] for k in ("factor", "interrupted") if k in r}
    return keep


def _instance(cfg, rig, plan, round_settings, problem_path):
    """The round's instance and oracle, rebuilt from the problem schedule wrote (``<stem>_problem.npz``: each
    boom's joints per hole, the planned postures among them): no network and no IK solve."""
    from pipeline.motion.timing import rig_motions
    from pipeline.round.from_plan import problem_instance
    from pipeline.round.problem_file import load_problem

    ids = plan.holes["hole_id"].astype(str).tolist()
    problem = load_problem(problem_path, rig.names, ids, list(rig.booms[0].boom.joint_names))
    return problem_instance(rig, plan, problem, rig_motions(as_dict(cfg.motion), rig.booms), round_settings)


def run_execute(cfg: DictConfig, overrides: list[str] | None = None) -> dict:
    """The stage (module docstring); ``overrides``: the Hydra overrides ``cfg`` was composed with, passed
    to the checker so that it composes the same settings (default: this run's own, under Hydra)."""
    settings, inter = parse_execute(cfg)
    draw_settings = parse_draws(as_dict(cfg.draws), "draws")
    tracking = TrackingSettings.from_config(cfg.tracking)
    plan_path = project_path(coerce(cfg.plan, "str", "plan"))
    planned = _planned_set(cfg, plan_path, settings)
    folder = project_path(settings.out) if settings.out else planned.folder
    # named after the planned set, beside it or in execute.out; never one of the files it reads
    files = round_paths(folder / f"{planned.stem}.csv", folder,
                        [plan_path, *planned.all().values(), *map(project_path, model_files(cfg))], EXECUTED)
    require_writable(files.folder, "execute.out (its folder)")
    rig = composed_rig(cfg, model_setting)
    true_booms, true_source = true_rig_booms(rig, settings.true_boom, settings.true_boom_model, model_setting)
    doc = _planned_doc(planned["json"])
    if doc.get("rig") != rig.name:
        raise ConfigError(f"rig = {rig.name}: the planned round {planned['json']} is of rig {doc.get('rig')!r}")
    verify_planned(planned, doc, plan_path, rig_record(cfg))  # every file read is the one planned: before any work
    plan = read_plan_in_rig_frame(plan_path, parse(NavigationSettings, cfg.navigation, "navigation"),
                                  as_dict(cfg.solve.iredes))
    if not isinstance(doc.get("navigation", {}), dict):
        raise InputError(f"{planned['json']}: navigation = {doc['navigation']!r}: expected the navigation record")
    same_navigation(plan.navigation, doc.get("navigation"), planned["json"])
    ids = plan.holes["hole_id"].astype(str).tolist()
    table = read_actions(planned["actions"])
    acts = actions_from_table(table, rig.names, ids, str(planned["actions"]))
    boom_major = table.iloc[np.lexsort((table["action"].to_numpy(int), [rig.names.index(b) for b in table["boom"]]))
                            ].reset_index(drop=True)  # numbered as the actions are
    edges = read_interlocks(planned["interlocks"], boom_major, str(planned["actions"]))
    zones = (read_zones(planned["zones"], boom_major, acts, str(planned["actions"])) if planned["zones"].is_file()
             else NO_ZONES)
    zones_fixed = 0
    if len(zones) and inter.hole is not None:  # handed on with each zone's planned entry order as interlocks
        fixed = entry_orders(acts, zones)
        edges, zones, zones_fixed = np.unique(np.concatenate([edges, fixed]), axis=0), NO_ZONES, len(fixed)
        log.info("the round's zones are handed on as %d interlocks, each zone's entry order as planned", zones_fixed)
    names = list(rig.booms[0].boom.joint_names)
    traj = _read_trajectory(planned["trajectory"], names)
    rows = action_rows(traj, acts, names, str(planned["trajectory"]))
    planned_table = _read_round_table(planned["round"], names)
    H = len(ids)
    planned_s = np.ones(H)
    planned_s[acts.hole[acts.is_drill]] = acts.duration[acts.is_drill]
    nominal = float(acts.t_end.max()) if len(acts) else 0.0

    with stage_run(tracking, f"execute-{plan_path.stem}-{rig.name}",
                   {"stage": "execute", "plan": str(plan_path), "rig": rig.name}) as mlrun:
        mlrun.log_params({"plan": str(plan_path), "rig": rig.name, "execute": as_dict(cfg.execute),
                          "draws": as_dict(cfg.draws)})
        timings: dict[str, float] = {}
        writers = {}
        out: dict = {"plan": str(plan_path), "plan_md5": doc["plan_md5"], "planned_with": doc["planned_with"],
                     "rig": rig.name, "realised": True, "d_boom_m": rig.d_boom,
                     "planned": {p.name: file_md5(p) for p in planned.all().values() if p.is_file()},
                     "nominal_makespan_s": nominal, "zones_fixed_for_hand_on": zones_fixed}
        if plan_path.suffix.lower() == ".xml":  # the checker reads CSV plans: the holes as read, beside the set
            holes = _plan_holes(plan)
            writers["plan"] = lambda p: write_csv(holes, p)
            out["plan_holes"] = files["plan"].name
        d = draws(acts, draw_settings)
        mc = None
        if settings.monte_carlo:
            t0 = time.perf_counter()
            ex_all = run(acts, edges, planned_s, d, zones)
            timings["monte_carlo_s"] = time.perf_counter() - t0
            mc = summary(ex_all, nominal, d)
            out["monte_carlo"] = mc
            dt = draws_table(acts, d)
            writers["draws"] = lambda p: write_csv(dt, p)
            if settings.figures:
                from pipeline.events.robust_round import makespans_figure

                fig_span, fig_labels = ex_all.makespan, d.labels
        # the realised round
        fixed = fixed_factors(acts, draw_settings.factors)
        if settings.draw == "nominal":
            factor, label = fixed, "nominal"
        else:
            k = int(settings.draw)
            if k >= draw_settings.count:
                raise ConfigError(f"execute.draw = {k}: there are draws.count = {draw_settings.count} random draws")
            factor, label = d.factors[k], f"random draw {k}"
        drill_s = factor * planned_s
        interrupted: set[int] = set()
        r_acts, r_edges, r_rows = acts, edges, rows
        if inter.hole is None:
            ex = execute(acts, edges, drill_s, zones)
        else:
            if inter.hole not in ids:
                raise ConfigError(f"execute.interrupt.hole = {inter.hole!r}: no such hole in {plan_path}")
            x = ids.index(inter.hole)
            st = standing(acts, edges, drill_s, x, inter.at_s)
            out["interrupt"] = {"hole_id": inter.hole, "at_s": inter.at_s, "t_s": st.t_interrupt,
                                "handed_on_s": st.t_hand, "replan": settings.replan,
                                "booms_at": {rig.names[b]: ("park" if n == H else ids[n])
                                             for b, n in enumerate(st.node)},
                                "holes_left_to_drill": int(acts.is_drill.sum() - len(st.drilled) - 1)}
            if not settings.replan:
                cut = drill_s.copy()
                cut[x] = inter.at_s
                ex = execute(acts, edges, cut)
                interrupted = {st.interrupted}
            else:
                # the round group's settings, then execute.replan_round's (routing off by default: on the clock)
                round_settings = replan_round(cfg)
                t0 = time.perf_counter()
                inst, oracle = _instance(cfg, rig, plan, round_settings, planned["problem"])
                timings["instance_s"] = time.perf_counter() - t0
                _check_joints(oracle, st, rows, acts, ids)
                from pipeline.round.move_file import load_book

                book, said = load_book(planned["moves"], oracle, H, round_settings)
                log.info("move book: %s", said)
                out["interrupt"]["move_book"] = book is not None
                io = interrupted_round(acts, edges, rows, st, factor * planned_s, factor, inst, oracle, round_settings,
                                       names, lambda m: log.info("hand-on: %s", m), book)
                timings.update({f"replan.{k}": v for k, v in io.handed.timings.items()})
                timings["replan_s"] = io.handed.replan_s
                r_acts, r_edges, r_rows, ex = io.spliced.actions, io.spliced.interlocks, io.spliced.rows, io.execution
                interrupted = {io.cut}
                out["handed_on"] = {**io.report, "dropped_precedence": [[ids[i], ids[j]] for i, j in
                                                                        io.handed.dropped_precedence]}
        if ex.deadlock is not None:
            raise Deadlock(f"execute ({label}): the round deadlocks: "
                           + " -> ".join(r_acts.name(k) for k in ex.deadlock) + "; nothing written")
        start, end = ex.start[0], ex.end[0]
        realised_traj = retimed(r_acts, r_rows, start, end, names)
        r_table = executed_round_table(r_acts, start, end, r_rows, planned_table, names, interrupted)
        skip = interrupted
        out.update({"draw": label, "makespan_s": float(ex.makespan[0]),
                    "makespan_over_nominal": float(ex.makespan[0] / nominal) if nominal > 0 else None,
                    "standing_s": {name: float(ex.standing[0, b]) for b, name in enumerate(r_acts.booms)},
                    # of it, the time spent waiting for another boom to leave a zone; beside it, at park, done
                    "standing_for_zones_s": {n: float(ex.standing_zone[0, b]) for b, n in enumerate(r_acts.booms)},
                    "idle_after_s": {name: float(ex.idle_after[0, b]) for b, name in enumerate(r_acts.booms)},
                    "holes_drilled": int(sum(1 for k in np.flatnonzero(r_acts.is_drill) if int(k) not in skip)),
                    "holes_left": [ids[r_acts.hole[k]] for k in sorted(interrupted)],
                    "ran_long": long_holes(r_acts, planned_s, start, end, skip),
                    "status": "interrupted" if interrupted else "complete"})
        executed_acts = actions_table(type(r_acts)(r_acts.booms, r_acts.hole_ids, r_acts.boom, r_acts.index,
                                                   r_acts.kind, r_acts.hole, r_acts.src, r_acts.dst, start, end))
        drilling = as_dict(cfg.motion)["drilling"]
        drilled = drilled_holes(r_acts, r_rows, start, end, plan, np.array([m.base for m in rig.booms], float),
                                true_booms, interrupted, factor, float(drilling["collaring_s"]),
                                float(drilling["rate_m_per_min"]) / 60.0, datetime.fromisoformat(settings.start_time))
        out["as_drilled"] = {"boom": true_source, "holes": len(drilled),
                             "interrupted": int((drilled["status"] == "Interrupted").sum())}
        writers["quality"] = lambda p: write_quality_log(drilled, p, plan_id=plan.plan_id or plan_path.stem,
                                                         plan_name=plan.name or plan_path.stem,
                                                         created=datetime.fromisoformat(settings.start_time))
        writers.update({"trajectory": lambda p: write_csv(realised_traj, p),
                        "round": lambda p: write_csv(spreadsheet_safe(r_table), p),
                        "actions": lambda p: write_csv(spreadsheet_safe(executed_acts), p),
                        "interlocks": lambda p: write_csv(interlocks_table(r_acts, r_edges), p),
                        "zones": lambda p: write_csv(spreadsheet_safe(zones_table(r_acts, zones)), p)})
        collars = plan.holes[COLLAR].to_numpy(float)
        if settings.figures and mc is not None:
            fig = makespans_figure(fig_span, fig_labels, nominal, f"rig {rig.name}: the round executed by events",
                                   (out["makespan_s"], label + (" interrupted" if interrupted else "")))
            writers["makespans"] = lambda p: save_figure(fig, p)
            mlrun.log_figure(fig, "executed_makespans.png")
        if settings.replay:
            from pipeline.round.figures import replay_html

            title = f"executed: {label}" + (f", hole {inter.hole} interrupted, handed on" if interrupted else "")
            writers["replay"] = lambda p: write_text(replay_html(realised_traj, rig, collars,
                                                                 settings.replay_frames, title), p)

        def log_staged(staged):
            for kind in ("json", "replay"):
                if kind in staged:
                    mlrun.log_artifact(staged[kind])

        def check_staged(staged: dict) -> dict:
            """The independent checks of the staged set, before anything is published (their verdicts go into
            its JSON); one that cannot judge it stops the stage, and nothing is published."""
            ov = _overrides() if overrides is None else list(overrides)
            plan_arg = str(staged.get("plan", plan_path))  # an IREDES plan: the holes as read, as CSV
            checks = {}
            if mc is not None:
                checks["planned_draws"] = _check([str(planned["trajectory"]), *ov, "--draws", str(staged["draws"]),
                                                  "--plan", plan_arg], "the planned set on the draws")
            checks["realised"] = _check([str(staged["trajectory"]), *ov, "--realised", "--round",
                                         str(staged["round"]), "--summary", str(staged["json"]), "--actions",
                                         str(staged["actions"]), "--interlocks", str(staged["interlocks"]),
                                         "--zones", str(staged["zones"]), "--plan", plan_arg], "the realised set")
            for k, c in checks.items():
                timings[f"check_{k}_s"] = c.pop("seconds")
            _checks_ran(checks)
            return {"checks": {k: {"exit": c["exit"], "verdict": c["verdict"]} for k, c in checks.items()}}

        out = write_round_set(files, out, writers, log_staged, check_staged if settings.check else None)
        mlrun.log_metrics({**_metrics(out), **{f"timing.{k}": v for k, v in timings.items()}})
    _report(out, timings, files, settings)
    return out


class CheckerFailed(JobFailed):
    """The independent checker gave no verdict (its own failure, exit 3, or a signal): nothing published (exit 3)."""


def _checks_ran(checks: dict) -> None:
    """Every check judged the set (the checker's exit 0: clean, 1: violations); else the stage stops before
    publishing: the checker's exit 2 (an input it cannot judge) as an :class:`InputError` (exit 2), any other
    exit (its own failure, exit 3, or a signal) as :class:`CheckerFailed` (exit 3). A signal this process
    received meanwhile (Ctrl-C reaches the checker too) wins: exit 128 + signum."""
    from pipeline.core.signals import raise_if_terminated

    raise_if_terminated()
    for k, c in checks.items():
        if c["exit"] in (ExitCode.DONE, ExitCode.CHECK_FAILED):
            continue
        what = {"planned_draws": "planned set on the draws", "realised": "realised set"}.get(k, k)
        said = c.get("stderr", "").strip().splitlines()
        last = said[-1] if said else "(nothing on stderr)"
        if c["exit"] == ExitCode.BAD_INPUT:
            raise InputError(f"the independent check of the {what} could not judge it (checker exit 2: {last}); "
                             "nothing published")
        raise CheckerFailed(f"the independent check of the {what} failed (checker exit {c['exit']}: {last}); "
                            "nothing published")


def _check_joints(oracle, st, rows, acts, ids) -> None:
    """Where a boom stands must be today's joint solution of that hole (the re-plan starts from it)."""
    H = len(ids)
    for b, n in enumerate(st.node):
        mine = np.flatnonzero((acts.boom == b) & st.prefix)
        if n == H or not len(mine):
            continue
        q_file = rows[mine[-1]].q_end
        q_now = oracle.joints[b][n].numpy()
        wrap = np.asarray(oracle.limits[b].wrap, bool)
        diff = np.where(wrap, np.angle(np.exp(1j * (q_file - q_now))), q_file - q_now)
        if np.abs(diff).max() > 1e-6:
            raise InputError(f"boom {acts.booms[b]} stands at hole {ids[n]} at joints the planned trajectory gives, "
                             f"which differ from today's reach table by {np.abs(diff).max():.3g}; re-run schedule")


def _overrides() -> list[str]:
    from hydra.core.hydra_config import HydraConfig

    try:
        return [o for o in HydraConfig.get().overrides.task]
    except ValueError:  # not under Hydra (a test calling run_execute): the checker composes the defaults
        return []


def _metrics(out: dict) -> dict:
    m = {"makespan_s": out["makespan_s"], "nominal_makespan_s": out["nominal_makespan_s"]}
    mc = out.get("monte_carlo") or {}
    for k, v in (mc.get("random") or {}).items():
        m[f"monte_carlo.{k}"] = v
    if "handed_on" in out:
        m["handed_on.makespan_s"] = out["handed_on"]["makespan_s"]
    for k, c in (out.get("checks") or {}).items():
        m[f"check.{k}.exit"] = c["exit"]
    return m


def _report(out: dict, timings: dict, files, settings: ExecuteSettings) -> None:
    log.info("executed (%s): makespan %.1f s (nominal %.1f s) -> %s", out["draw"], out["makespan_s"],
             out["nominal_makespan_s"], files["trajectory"])
    if "interrupt" in out:
        i = out["interrupt"]
        log.info("hole %s interrupted at t = %.1f s; handed on at %.1f s with %d holes left to drill%s", i["hole_id"],
                 i["t_s"], i["handed_on_s"], i["holes_left_to_drill"],
                 f"; re-planned in {timings.get('replan_s', 0):.2f} s (planning "
                 f"{timings.get('replan.plan_s', 0):.2f} s, of which moves {timings.get('replan.moves_s', 0):.2f} s; "
                 "interlocks "
                 f"{timings.get('replan.interlocks_s', 0):.2f} s)" if i["replan"] else " (no re-plan)")
    problems = []
    ho = out.get("handed_on")
    if ho is not None and (not ho["robust"] or ho["conflicts_left"] or ho["moves_failed"]):
        problems.append(f"the handed-on round is not safe to run as it is ({ho['problem'] or ho})")
    mc = out.get("monte_carlo")
    if mc is not None and mc["deadlocks"]:
        problems.append(f"{mc['deadlocks']} draws deadlock")
    for k, c in (out.get("checks") or {}).items():
        if c["exit"] != 0:
            problems.append(f"the independent check of {k.replace('_', ' ')} exits {c['exit']}")
    for p in problems:
        log.warning("execute: %s", p)
    if problems and settings.strict:
        raise StrictCheckFailed(f"execute.strict: {'; '.join(problems)} (see {files['json']})")


@stage_main
def main(cfg: DictConfig) -> None:
    run_stage(cfg, lambda c: run_execute(c, _overrides()), threads="threads")


if __name__ == "__main__":
    main()
