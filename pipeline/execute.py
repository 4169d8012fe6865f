"""Stage: a planned round executed by events (spec section 8), ``python -m pipeline.execute plan=P rig=twin``.

It reads the set ``schedule`` wrote for the plan (``<stem>_trajectory.csv``, ``_actions.csv``,
``_interlocks.csv``, ``_round.csv``, ``_round.json``; ``execute.round`` points elsewhere), and

1. executes it under the drilling-time model of the ``execution`` group (seeded uniform factors, stalls
   with a probability, fixed factors of named holes) by the execution rule: every draw at once, the
   makespans and the standing at interlocks summarised, the factors written to ``<stem>_draws.csv``;
2. realises one round (``execute.draw``: ``nominal`` or the k-th random draw) and, with
   ``execute.interrupt.hole`` / ``at_s``, interrupts that hole: the round is then handed on
   (:mod:`pipeline.execution.interrupt`), re-planned from where every boom stands (``replan: true``, the
   instance rebuilt from the plan and the rig as ``schedule`` builds it) or going on with its own actions;
3. writes the executed set (``<stem>_executed_trajectory.csv`` in the spec-7 format,
   ``_executed_actions.csv`` with the executed times, ``_executed_interlocks.csv``, ``_executed_round.csv``,
   ``_executed.json``, ``_executed_makespans.png``, ``_executed_replay.html``), published whole and never
   over the planned files;
4. checks with the independent checker (``scripts/check_round.py``, a separate process that imports
   nothing of ``pipeline``): the planned set on exactly the draws (``--draws``), and the realised set
   (``--realised``); their verdicts go into the JSON. Under ``execute.strict`` a failed check, a deadlock
   or a hand-on round that cannot be made robust exits 1 (after writing the set).

Re-planning seconds and the checks' seconds are MLflow metrics (``timing.*``), not in the JSON.
"""

from __future__ import annotations

import json
import logging
import subprocess
import sys
import time
from dataclasses import dataclass, field

import hydra
import numpy as np
import pandas as pd
from omegaconf import DictConfig

from pipeline.assembly.rig import composed_rig, model_files
from pipeline.calibration.model_file import model_setting
from pipeline.core.config import as_dict, project_path
from pipeline.core.errors import ConfigError, InputError
from pipeline.core.io import file_md5, require_writable, save_figure, write_csv, write_text
from pipeline.core.settings import coerce, parse, rule
from pipeline.core.stage import run_stage
from pipeline.execution.actions import (
    actions_from_table,
    actions_table,
    interlocks_table,
    read_actions,
    read_interlocks,
)
from pipeline.execution.executed import draws_table, executed_round_table, long_holes
from pipeline.execution.executor import execute
from pipeline.execution.interrupt import interrupted_round, standing
from pipeline.execution.montecarlo import draws, fixed_factors, parse_execution, run, summary
from pipeline.execution.trajectory import action_rows, retimed
from pipeline.plans.model import COLLAR
from pipeline.plans.navigation import NavigationSettings, same_navigation
from pipeline.plans.read import read_plan_in_rig_frame
from pipeline.plans.solutions import spreadsheet_safe
from pipeline.round.output import EXECUTED, round_paths, write_round_set
from pipeline.tracking.runs import TrackingSettings, stage_run

log = logging.getLogger(__name__)
CHECKER = "scripts/check_round.py"


@dataclass(frozen=True)
class InterruptSettings:
    hole: str | None = None
    at_s: float | None = field(default=None, metadata=rule(gt=0))


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
    replay_frames: int = field(default=400, metadata=rule(ge=2))
    progress: bool = True


def parse_execute(cfg: DictConfig) -> tuple[ExecuteSettings, InterruptSettings]:
    node = dict(as_dict(cfg.execute))
    inter = parse(InterruptSettings, node.pop("interrupt", None) or {}, "execute.interrupt")
    node.pop("replan_round", None)  # round overrides, parsed with the round group (parse_replan_round)
    node["draw"] = str(node.get("draw", "0"))
    s = parse(ExecuteSettings, node, "execute")
    if s.draw != "nominal" and not s.draw.isdigit():
        raise ConfigError(f"execute.draw = {s.draw!r}: expected nominal or a whole number (the k-th random draw)")
    if (inter.hole is None) != (inter.at_s is None):
        raise ConfigError("execute.interrupt: set both hole and at_s (or neither)")
    return s, inter


def _planned_set(cfg, plan_path, settings: ExecuteSettings):
    """The planned set's paths, every file checked to exist (a clear error: run schedule first)."""
    planned = round_paths(plan_path, project_path(settings.round) if settings.round else None)
    for kind in ("trajectory", "actions", "interlocks", "round", "json"):
        if not planned[kind].is_file():
            raise InputError(f"{planned[kind]}: not found; the executor runs a round that schedule planned "
                             f"(python -m pipeline.schedule plan={plan_path} rig=...), or point execute.round at it")
    return planned


def _check(args: list[str], what: str) -> dict:
    """Run the independent checker; its JSON verdict (stdout's last line) and exit code."""
    started = time.perf_counter()
    proc = subprocess.run([sys.executable, str(project_path(CHECKER)), *args], capture_output=True, text=True,
                          cwd=str(project_path(".")))
    out = {"exit": proc.returncode, "seconds": time.perf_counter() - started}
    try:  # the checker prints one JSON document
        doc = json.loads(proc.stdout) if proc.stdout.strip() else None
    except json.JSONDecodeError:
        doc = None
    out["verdict"] = _verdict(doc)
    if proc.returncode not in (0, 1):
        log.error("checker (%s) exit %d: %s", what, proc.returncode, proc.stderr.strip()[-2000:])
    return out


def _verdict(doc: dict | None) -> dict | None:
    """What the executed set keeps of a checker's report: its counts, not its messages."""
    if doc is None:
        return None
    keep = {"violations": len(doc.get("violations") or [])}
    ex = doc.get("execution")
    if isinstance(ex, dict):
        keep["execution"] = {k: ex[k] for k in ("draws", "violating_draws", "deadlocks", "violations",
                                                "min_executed_candidate_distance_m", "interlocks_broken") if k in ex}
    r = doc.get("realised")
    if isinstance(r, dict):
        keep["realised"] = {k: r[k] for k in ("factor", "interrupted") if k in r}
    return keep


def _instance(cfg, rig, plan, round_settings, planned_table):
    """The round's instance and oracle, built from the plan and the rig as ``schedule`` builds them, each
    planned hole at the joints of the planned round table (the postures the round chose)."""
    from pipeline.data.holes import joint_box
    from pipeline.motion.timing import rig_motions
    from pipeline.plans.reach import reach_table, rig_solvers
    from pipeline.round.from_plan import planned_joints, round_instance
    from pipeline.solvers.hybrid import HybridSettings
    from pipeline.solvers.network_start import first_starts, network_source

    network = cfg.schedule.get("network")
    model_uri = cfg.schedule.get("model_uri")
    source = network_source(project_path(cfg.paths.data), network, model_uri)
    first = first_starts(source, network, TrackingSettings.from_config(cfg.tracking).uri, "schedule.model_uri")
    box = cfg.holes.sup.get("box")
    solvers = rig_solvers(rig, first, parse(HybridSettings, cfg.solver, "solver"),
                          joint_box(rig.booms[0].boom, None if box is None else as_dict(box)))
    reach = reach_table(plan, rig, solvers, "hybrid")
    motions = rig_motions(as_dict(cfg.motion), rig.booms)
    joints = planned_joints(rig, plan, reach, planned_table, list(rig.booms[0].boom.joint_names))
    inst, oracle, _ = round_instance(rig, plan, reach, motions, round_settings, joints)
    return inst, oracle


def run_execute(cfg: DictConfig, overrides: list[str] | None = None) -> dict:
    """The stage (module docstring); ``overrides``: the Hydra overrides ``cfg`` was composed with, passed
    to the checker so that it composes the same settings (default: this run's own, under Hydra)."""
    settings, inter = parse_execute(cfg)
    execution = parse_execution(as_dict(cfg.execution), "execution")
    tracking = TrackingSettings.from_config(cfg.tracking)
    plan_path = project_path(coerce(cfg.plan, "str", "plan"))
    planned = _planned_set(cfg, plan_path, settings)
    folder = project_path(settings.out) if settings.out else planned.folder
    # named after the planned set, beside it or in execute.out; never one of the files it reads
    files = round_paths(folder / f"{planned.stem}.csv", folder,
                        [plan_path, *planned.all().values(), *map(project_path, model_files(cfg))], EXECUTED)
    require_writable(files.folder, "execute.out (its folder)")
    rig = composed_rig(cfg, model_setting)
    doc = json.loads(planned["json"].read_text())
    if doc.get("rig") != rig.name:
        raise ConfigError(f"rig = {rig.name}: the planned round {planned['json']} is of rig {doc.get('rig')!r}")
    plan = read_plan_in_rig_frame(plan_path, parse(NavigationSettings, cfg.navigation, "navigation"),
                                  as_dict(cfg.solve.iredes))
    same_navigation(plan.navigation, doc.get("navigation"), planned["json"])
    ids = plan.holes["hole_id"].astype(str).tolist()
    table = read_actions(planned["actions"])
    acts = actions_from_table(table, rig.names, ids, str(planned["actions"]))
    edges = read_interlocks(planned["interlocks"], table.iloc[np.lexsort((table["action"].to_numpy(int),
                            [rig.names.index(b) for b in table["boom"]]))].reset_index(drop=True),
                            str(planned["actions"]))
    names = list(rig.booms[0].boom.joint_names)
    traj = pd.read_csv(planned["trajectory"], keep_default_na=False, dtype={"boom": str, "event": str, "hole_id": str})
    rows = action_rows(traj, acts, names, str(planned["trajectory"]))
    planned_table = pd.read_csv(planned["round"], keep_default_na=False, float_precision="round_trip",
                                dtype={"hole_id": str, "boom": str})
    planned_table = planned_table.replace({"": np.nan}).assign(
        hole_id=planned_table["hole_id"], boom=planned_table["boom"], status=planned_table["status"],
        reason=planned_table["reason"])
    H = len(ids)
    planned_s = np.ones(H)
    planned_s[acts.hole[acts.is_drill]] = acts.duration[acts.is_drill]
    nominal = float(acts.t_end.max()) if len(acts) else 0.0

    with stage_run(tracking, f"execute-{plan_path.stem}-{rig.name}",
                   {"stage": "execute", "plan": str(plan_path), "rig": rig.name}) as mlrun:
        mlrun.log_params({"plan": str(plan_path), "rig": rig.name, "execute": as_dict(cfg.execute),
                          "execution": as_dict(cfg.execution)})
        timings: dict[str, float] = {}
        out: dict = {"plan": str(plan_path), "rig": rig.name, "realised": True, "d_boom_m": rig.d_boom,
                     "planned": {p.name: file_md5(p) for p in planned.all().values() if p.is_file()},
                     "nominal_makespan_s": nominal}
        writers = {}
        d = draws(acts, execution)
        mc = None
        if settings.monte_carlo:
            t0 = time.perf_counter()
            ex_all = run(acts, edges, planned_s, d)
            timings["monte_carlo_s"] = time.perf_counter() - t0
            mc = summary(ex_all, nominal, d)
            out["monte_carlo"] = mc
            dt = draws_table(acts, d)
            writers["draws"] = lambda p: write_csv(dt, p)
            if settings.figures:
                from pipeline.execution.robust import makespans_figure

                fig_span, fig_labels = ex_all.makespan, d.labels
        # the realised round
        fixed = fixed_factors(acts, execution.factors)
        if settings.draw == "nominal":
            factor, label = fixed, "nominal"
        else:
            k = int(settings.draw)
            if k >= execution.draws:
                raise ConfigError(f"execute.draw = {k}: there are execution.draws = {execution.draws} random draws")
            factor, label = d.factors[k], f"random draw {k}"
        drill_s = factor * planned_s
        interrupted: set[int] = set()
        r_acts, r_edges, r_rows = acts, edges, rows
        if inter.hole is None:
            ex = execute(acts, edges, drill_s)
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
                from pipeline.round.settings import parse_round

                # the round group's settings, then execute.replan_round's (routing off by default: on the clock)
                round_settings = parse_round({**as_dict(cfg.round), **(as_dict(cfg.execute.get("replan_round"))
                                                                         or {})}, "round + execute.replan_round")
                t0 = time.perf_counter()
                inst, oracle = _instance(cfg, rig, plan, round_settings, planned_table)
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
            raise ConfigError("the round deadlocks: " + " -> ".join(r_acts.name(k) for k in ex.deadlock))
        start, end = ex.start[0], ex.end[0]
        realised_traj = retimed(r_acts, r_rows, start, end, names)
        r_table = executed_round_table(r_acts, start, end, r_rows, planned_table, names, interrupted)
        skip = interrupted
        out.update({"draw": label, "makespan_s": float(ex.makespan[0]),
                    "makespan_over_nominal": float(ex.makespan[0] / nominal) if nominal > 0 else None,
                    "standing_s": {name: float(ex.standing[0, b]) for b, name in enumerate(r_acts.booms)},
                    "holes_drilled": int(sum(1 for k in np.flatnonzero(r_acts.is_drill) if int(k) not in skip)),
                    "holes_left": [ids[r_acts.hole[k]] for k in sorted(interrupted)],
                    "ran_long": long_holes(r_acts, planned_s, start, end, skip),
                    "status": "interrupted" if interrupted else "complete"})
        executed_acts = actions_table(type(r_acts)(r_acts.booms, r_acts.hole_ids, r_acts.boom, r_acts.index,
                                                   r_acts.kind, r_acts.hole, r_acts.src, r_acts.dst, start, end))
        writers.update({"trajectory": lambda p: write_csv(realised_traj, p),
                        "round": lambda p: write_csv(spreadsheet_safe(r_table), p),
                        "actions": lambda p: write_csv(spreadsheet_safe(executed_acts), p),
                        "interlocks": lambda p: write_csv(interlocks_table(r_acts, r_edges), p)})
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
        checks = {}

        def log_staged(staged):
            for kind in ("json", "replay"):
                if kind in staged:
                    mlrun.log_artifact(staged[kind])

        out = write_round_set(files, out, writers, log_staged)
        if settings.check:
            overrides = _overrides() if overrides is None else list(overrides)
            if mc is not None:
                checks["planned_draws"] = _check([str(planned["trajectory"]), *overrides, "--draws",
                                                  str(files["draws"])], "the planned set on the draws")
            checks["realised"] = _check([str(files["trajectory"]), *overrides, "--realised", "--round",
                                         str(files["round"]), "--summary", str(files["json"]), "--actions",
                                         str(files["actions"]), "--interlocks", str(files["interlocks"]),
                                         "--plan", str(plan_path)], "the realised set")
            for k, c in checks.items():
                timings[f"check_{k}_s"] = c.pop("seconds")
            out["checks"] = {k: {"exit": c["exit"], "verdict": c["verdict"]} for k, c in checks.items()}
            _add_to_summary(files, out)
        mlrun.log_metrics({**_metrics(out), **{f"timing.{k}": v for k, v in timings.items()}})
    _report(out, timings, files, settings)
    return out


def _add_to_summary(files, out: dict) -> None:
    """The published summary again, with the checks' verdicts: its siblings (and so its manifest) unchanged,
    replaced by one rename under the set's lock."""
    from filelock import FileLock

    from pipeline.core.io import write_json

    with FileLock(str(files.lock), timeout=600):
        write_json(out, files["json"])


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
        raise SystemExit(f"execute.strict: {'; '.join(problems)} (see {files['json']})")


@hydra.main(version_base="1.3", config_path="../conf", config_name="config")
def main(cfg: DictConfig) -> None:
    run_stage(cfg, lambda c: run_execute(c, _overrides()), threads="threads")


if __name__ == "__main__":
    main()
