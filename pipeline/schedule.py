"""Stage ``schedule``: the round of a rig, every boom at once, no two booms closer than d_boom.

    python -m pipeline.schedule plan=data/plans/demo_face.csv rig=twin
    python -m pipeline.schedule plan=round_42.xml rig=trio out=rounds/
    python -m pipeline.schedule plan=... rig=twin round.solution_limit=2000 'round.precedence=[[R1,C1]]'
    python -m pipeline.schedule plan=... rig=twin schedule.strict=true   # exit 1 on an unsafe round

Reads the plan (CSV or IREDES), solves every hole by every boom (the reach table, the hybrid with the
other booms at park: :mod:`pipeline.plans.reach`), plans the round (:mod:`pipeline.round.from_plan`:
OR-Tools routing, the timeline with boom-boom conflicts and waits, the conflict loop; docs/round.md)
and its baselines, and writes beside the plan (or into ``out``, a folder or a ``<stem>_round.csv``):

- ``<stem>_round.csv``: hole_id, boom, order, t_start, t_end, q1 .. q8, status, reason (every plan
  hole once, unreadable rows as ``invalid``);
- ``<stem>_trajectory.csv``: the reference's trajectory file, every boom park to park;
- ``<stem>_round.json``: makespan, lower bound, baselines, clearance, per boom times, moves by kind; the
  plan's MD5 (``plan_md5``) and what the round was planned with (``planned_with``: the rig, its booms and
  the tunnel, a profile by its file's MD5), which ``execute`` and the independent checker hold theirs to;
- ``<stem>_round_face.png``, ``<stem>_round_gantt.png``, ``<stem>_round_replay.html``;
- for every rig (``schedule.interlocks``; one boom has no interlock, the file holds its header), the round
  executed by events (docs/reference.md section 8,
  :mod:`pipeline.events.robust_round`): ``<stem>_actions.csv``, ``<stem>_interlocks.csv``,
  ``<stem>_zones.csv`` (section 9; the planner chooses no zone yet, so it holds its header alone),
  ``<stem>_round_executed.png`` and ``<stem>_round_executed_replay.html``; the trajectory is then the
  round re-timed by its interlocks, and the JSON's ``execution`` holds the drawn rounds' summary.

``out`` is checked before any work (:mod:`pipeline.round.output`); the set is written into a private
folder and published under one lock, its JSON last with the MD5 of each sibling (:func:`pipeline.core.io.publish`),
so an interrupt (Ctrl-C, SIGTERM) leaves the previous set or none, never half of one; the MLflow run
ends KILLED (:func:`pipeline.tracking.runs.stage_run`).

The set reproduces: planning is limited by counts (conf/round), and wall-clock seconds (planning,
reach table) are MLflow metrics (``timing.*``), not in the JSON. A round that is not safe to run as it
is (conflicts left, a move not certified clear, the one-boom fallback) is written and warned about;
with ``schedule.strict=true`` the stage then exits 1, as ``solve strict=true`` does.
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass, field

import numpy as np
import pandas as pd
from omegaconf import DictConfig

from pipeline.assembly.build import build_safety, load_boom
from pipeline.assembly.rig import build_rig, composed_rig, model_files, rig_booms, rig_record, rig_spec, rig_tunnel
from pipeline.calibration.model_file import model_setting
from pipeline.core.config import as_dict, project_path
from pipeline.core.errors import ConfigError, StrictCheckFailed
from pipeline.core.io import file_md5, require_writable, save_figure, write_csv, write_text
from pipeline.core.settings import SEED_MAX, RuntimeSettings, coerce, parse, rule
from pipeline.core.stage import run_stage, stage_main
from pipeline.events.draws import parse_draws
from pipeline.events.robust_round import robust_hooks
from pipeline.events.zone_choice import ZoneSettings
from pipeline.motion.timing import rig_motions
from pipeline.plans.model import COLLAR
from pipeline.plans.navigation import NavigationSettings, navigation_metrics, navigation_params
from pipeline.plans.reach import solved_reach
from pipeline.plans.read import read_plan_in_rig_frame
from pipeline.plans.solutions import spreadsheet_safe
from pipeline.round.from_plan import round_problem, schedule_round
from pipeline.round.output import round_paths, write_round_set
from pipeline.round.postures import round_postures
from pipeline.round.problem import precedence_indices
from pipeline.round.problem_file import save_problem
from pipeline.round.settings import parse_round
from pipeline.solvers.hybrid import HybridSettings
from pipeline.solvers.network_start import first_starts, network_source
from pipeline.tracking.runs import TrackingSettings, stage_run

log = logging.getLogger(__name__)

# a generated benchmark face's holes (conf/schedule/default.yaml): the benchmark's faces have 50 to 150; 1000 is far
# beyond any tunnel face (and generated_face needs 20: cut, perimeter, stoping)
FACE_HOLES = (20, 1000)


@dataclass(frozen=True)
class ScheduleSettings:
    """The ``schedule`` node (conf/schedule/default.yaml); the planner's settings are ``round``."""

    network: str | None = "cuikm"
    model_uri: str | None = None
    baselines: bool = True
    figures: bool = True
    replay: bool = True
    replay_frames: int = field(default=120, metadata=rule(ge=2, le=10_000))
    check_moves: bool = True
    benchmark: bool = False  # true: the round benchmark (faces x rigs) instead of one plan
    bench_faces: list = field(default_factory=lambda: ["demo", 50, 100, 150], metadata=rule(min_items=1, max_items=20))
    bench_rigs: list = field(default_factory=lambda: ["single", "twin", "trio"], metadata=rule(min_items=1,
                                                                                               max_items=20))
    bench_seed: int = field(default=0, metadata=rule(ge=0, le=SEED_MAX))
    strict: bool = False  # true: exit 1 (after writing the set) on conflicts left, failed moves, the fallback,
    # or a round the interlocks cannot make robust
    interlocks: bool = True  # the round executed by events: actions, interlocks, draws (pipeline.events)

    def __post_init__(self):
        for k, face in enumerate(self.bench_faces):
            if face == "demo":
                continue
            whole = isinstance(face, int) or (isinstance(face, float) and face.is_integer())
            if isinstance(face, bool) or not whole or not FACE_HOLES[0] <= face <= FACE_HOLES[1]:
                raise ConfigError(f"schedule.bench_faces[{k}] = {face!r}: expected demo or a face of "
                                  f"{FACE_HOLES[0]}..{FACE_HOLES[1]} holes")


def _progress(enabled: bool):
    """A tqdm bar over the planner's steps (routing solves, baselines, tables)."""
    if not enabled:
        return (lambda msg: log.info("%s", msg)), (lambda: None)
    from tqdm import tqdm

    bar = tqdm(total=None, desc="round", unit="step", leave=False)

    def say(msg):
        bar.update(1)
        bar.set_postfix_str(msg[:70])
        log.info("%s", msg)

    return say, bar.close


def run(cfg: DictConfig) -> dict:
    settings = parse(ScheduleSettings, cfg.schedule, "schedule")
    if settings.benchmark:
        return run_benchmark(cfg, settings)
    round_settings = parse_round(as_dict(cfg.round), "round")
    draw_settings = parse_draws(as_dict(cfg.draws), "draws")
    zone_settings = parse(ZoneSettings, cfg.zones, "zones")
    hybrid = parse(HybridSettings, cfg.solver, "solver")
    tracking = TrackingSettings.from_config(cfg.tracking)
    runtime = RuntimeSettings.from_config(cfg)
    plan_path = project_path(coerce(cfg.plan, "str", "plan"))
    # Before any work: never an input, never a folder in the way, never a name that makes a folder.
    files = round_paths(plan_path, project_path(cfg.out) if cfg.get("out") else None,
                        [project_path(f) for f in model_files(cfg)])
    require_writable(files.folder, "out (its folder)")
    rig = composed_rig(cfg, model_setting)  # its booms from boom, boom_model, boom_models: before any work
    motions = rig_motions(as_dict(cfg.motion), rig.booms)
    # what the round is planned with, for execute and the checker to hold their own settings and files to
    planned_with = rig_record(cfg)
    plan_md5 = file_md5(plan_path) if plan_path.is_file() else None
    plan = read_plan_in_rig_frame(plan_path, parse(NavigationSettings, cfg.navigation, "navigation"),
                                  as_dict(cfg.solve.iredes))
    if len(plan) == 0:
        raise ConfigError(f"plan = {plan_path}: no readable hole")
    precedence_indices(round_settings.precedence, plan.holes["hole_id"].astype(str).tolist())  # before solving
    for line in plan.report():
        log.warning("skipped: %s", line)
    source = network_source(project_path(cfg.paths.data), settings.network, settings.model_uri)
    box = cfg.holes.sup.get("box")
    with stage_run(tracking, f"schedule-{plan_path.stem}-{rig.name}",
                   {"stage": "schedule", "plan": str(plan_path), "rig": rig.name}) as mlrun:
        mlrun.log_params({"plan": str(plan_path), "rig": rig.name, "schedule": asdict(settings),
                          "round": as_dict(cfg.round), "draws": as_dict(cfg.draws), "zones": as_dict(cfg.zones),
                          "motion": as_dict(cfg.motion), "solver": as_dict(cfg.solver), **navigation_params(plan)})
        mlrun.log_dataset(plan.holes, plan_path, "drill plan")

        first_start = first_starts(source, settings.network, tracking.uri, "schedule.model_uri")
        say, close = _progress(runtime.progress)
        try:
            solvers, reach = solved_reach(plan, rig, first_start, hybrid, None if box is None else as_dict(box),
                                          "hybrid")
            say(f"reach table: {len(plan)} holes x {len(rig)} booms")
            postures = round_postures(plan, rig, solvers, reach, motions, round_settings)
            rs = round_settings
            finish, choose = (robust_hooks(draw_settings, zone_settings, rs.robust_candidates, rs.robust_slack,
                                           rs.robust_min_gain, say) if settings.interlocks else (None, None))
            res = schedule_round(rig, plan, reach, motions, round_settings, settings.baselines,
                                 settings.check_moves, say, finish, postures, choose)
        finally:
            close()
        table = with_invalid_rows(res.round, plan)
        summary = {"plan": str(plan_path), "plan_md5": plan_md5, **res.summary,
                   "invalid_rows": len({p.row for p in plan.problems}), "navigation": plan.navigation.record(),
                   "planned_with": planned_with}
        # wall-clock seconds go to MLflow only: the round JSON is DVC-tracked and must reproduce
        timings = {**res.timings, "reach_solve_s": reach.summary()["solve_s"]}
        executed = res.finished
        if executed is not None:
            summary["execution"] = executed.summary
            timings.update({f"interlocks.{k}": v for k, v in executed.extra["timings"].items()})
        collars = plan.holes[COLLAR].to_numpy(float)
        problem = round_problem(rig, plan, reach, table, list(rig.booms[0].boom.joint_names))
        writers = {"round": lambda p: write_csv(spreadsheet_safe(table), p),
                   "trajectory": lambda p: write_csv(res.trajectory, p),
                   "problem": lambda p: save_problem(problem, p)}  # what execute re-plans a handed-on round on
        if settings.figures:
            from pipeline.round.figures import face_figure, gantt_figure

            ratio = summary["makespan_over_bound"]
            title = (f"rig {rig.name}: makespan {summary['makespan_s']:.0f} s "
                     f"(bound {summary['lower_bound_s']:.0f} s)" if ratio is not None else
                     f"rig {rig.name}: no hole drillable")
            face = face_figure(res.round, collars, rig, title)
            gantt = gantt_figure(res.trajectory, rig.names, title)
            writers["face"] = lambda p: save_figure(face, p)
            writers["gantt"] = lambda p: save_figure(gantt, p)
            mlrun.log_figure(face, "round_face.png")
            mlrun.log_figure(gantt, "round_gantt.png")
        if res.plan.book is not None:  # for a round handed on after an interruption (pipeline.execute)
            from pipeline.round.move_file import save_book

            writers["moves"] = lambda p: save_book(res.plan.book, p)
        if executed is not None:
            writers["actions"] = lambda p: write_csv(spreadsheet_safe(executed.actions), p)
            writers["interlocks"] = lambda p: write_csv(executed.interlocks, p)
            writers["zones"] = lambda p: write_csv(spreadsheet_safe(executed.zones), p)
            if settings.figures:
                from pipeline.events.robust_round import realised_makespans_figure

                realised_fig = realised_makespans_figure(executed, f"rig {rig.name}: the round executed by events")
                writers["executed"] = lambda p: save_figure(realised_fig, p)
                mlrun.log_figure(realised_fig, "round_executed.png")
        if settings.replay:
            from pipeline.round.figures import replay_html

            writers["replay"] = lambda p: write_text(replay_html(res.trajectory, rig, collars,
                                                                 settings.replay_frames), p)
            if executed is not None and executed.realised is not None:
                from pipeline.round.tables import trajectory_table

                r_inst, r_tl = executed.realised
                r_traj = trajectory_table(r_inst, r_tl, res.oracle, rig.booms[0].boom.joint_names)
                label = f"realised: {executed.realised_label} (waits at interlocks shown)"
                writers["executed_replay"] = lambda p: write_text(
                    replay_html(r_traj, rig, collars, settings.replay_frames, label), p)
        mlrun.log_metrics({**metrics(summary), **{f"timing.{k}": v for k, v in timings.items()},
                           **navigation_metrics(plan)})
        mlrun.log_table(table, "round.json")
        mlrun.log_table(res.trajectory, "trajectory.json")

        def log_staged(staged):
            for kind in ("json", "replay"):
                if kind in staged:
                    mlrun.log_artifact(staged[kind])

        summary = write_round_set(files, summary, writers, log_staged)
    log.info("round of rig %s: %d holes, makespan %.1f s (lower bound %.1f s, naive %s, nearest %s), planned in "
             "%.1f s -> %s", rig.name, summary["holes_drilled"], summary["makespan_s"], summary["lower_bound_s"],
             summary["naive_makespan_s"], summary["nearest_makespan_s"], timings["planning_s"], files["round"])
    if summary["status"] != "complete":
        log.warning("round of rig %s: %s (%d of %d holes drilled; the round table says why)", rig.name,
                    summary["status"], summary["holes_drilled"], len(plan))
    unsafe = round_problems(summary)
    if executed is not None:
        ex = summary["execution"]
        log.info("executed by events: %d interlocks; %d draws, %d deadlocks; makespan p95 %.3f x nominal; standing "
                 "at interlocks p95 %.2f %% of the makespan", ex["interlocks"]["interlocks"], ex["draws"],
                 ex["deadlocks"], (ex["random"] or {}).get("makespan_ratio_p95", float("nan")),
                 100 * (ex["random"] or {}).get("standing_share_p95", float("nan")))
    for m in summary.get("moves_not_clear", []):
        log.warning("move not certified clear (event move_unclear in %s): boom %s %s -> %s: %s",
                    files["trajectory"].name, m["boom"], m["from"], m["to"], m["reason"])
    if unsafe and settings.strict:
        raise StrictCheckFailed(f"schedule.strict: {'; '.join(unsafe)} (see {files['json']})")
    for line in unsafe:
        log.warning("round: %s", line)
    return summary


def round_problems(summary: dict) -> list[str]:
    """What makes a written round unsafe to run as it is: what ``schedule.strict`` exits 1 for."""
    out = []
    if summary.get("conflicts_left"):
        out.append(f"{summary['conflicts_left']} boom-boom conflict(s) left")
    if summary.get("moves_failed"):
        out.append(f"{summary['moves_failed']} move(s) not certified clear (move_unclear)")
    if summary.get("sequential_fallback"):
        out.append("the one-boom-at-a-time fallback was used")
    ex = summary.get("execution")
    if ex is not None and not ex["robust"]:
        out.append(f"the interlocks cannot make the round robust: {ex['problem']}")
    if ex is not None and ex["deadlocks"]:
        out.append(f"the interlocks deadlock in {ex['deadlocks']} draw(s)")
    return out


def run_benchmark(cfg: DictConfig, settings: ScheduleSettings) -> dict:
    """``schedule.benchmark=true``: :func:`pipeline.rig_benchmarks.round_faces.round_benchmark` into
    ``paths.data/benchmark/round_benchmark.{csv,md}`` and one MLflow run."""
    from pipeline.rig_benchmarks.round_faces import markdown, round_benchmark

    rigs = benchmark_rigs(cfg, settings.bench_rigs)  # every rig, boom model and motion checked before any work
    round_settings = parse_round(as_dict(cfg.round), "round")
    draw_settings = parse_draws(as_dict(cfg.draws), "draws") if settings.interlocks else None
    zone_settings = parse(ZoneSettings, cfg.zones, "zones")
    hybrid = parse(HybridSettings, cfg.solver, "solver")
    tracking = TrackingSettings.from_config(cfg.tracking)
    folder = require_writable(project_path(cfg.paths.data) / "benchmark", "paths.data/benchmark")
    box = cfg.holes.sup.get("box")  # the stage's working box: the benchmark's reach tables use it too
    (folder / "rounds").mkdir(exist_ok=True)
    source = network_source(project_path(cfg.paths.data), settings.network, settings.model_uri)

    first_start = first_starts(source, settings.network, tracking.uri, "schedule.model_uri")

    with stage_run(tracking, "schedule-benchmark", {"stage": "schedule", "mode": "benchmark"}) as mlrun:
        mlrun.log_params({"schedule": asdict(settings), "round": as_dict(cfg.round), "solver": as_dict(cfg.solver),
                          "draws": as_dict(cfg.draws), "zones": as_dict(cfg.zones)})
        table = round_benchmark(settings.bench_faces, rigs, hybrid, round_settings, first_start, settings.bench_seed,
                                lambda m: log.info("%s", m), folder / "rounds", None if box is None else as_dict(box),
                                draw_settings, zone_settings)
        write_csv(table, folder / "round_benchmark.csv")
        write_text(markdown(table), folder / "round_benchmark.md")
        mlrun.log_table(table, "round_benchmark.json")
        for _, r in table.iterrows():
            key = f"{r['rig']}.{r['face'].split(' (')[0].replace(' ', '')}"
            logged = ("makespan_s", "lower_bound_s", "ratio", "naive_s", "nearest_s", "planning_s", "plan_makespan_s",
                      "robust_price_pct", "exec_p95", "standing_p95_pct", "order_p95_pct", "zone_p95_pct",
                      "idle_after_p95_pct")
            mlrun.log_metrics({f"{key}.{k}": float(r[k]) for k in logged if pd.notna(r[k])})
    log.info("round benchmark:\n%s", markdown(table))
    return {"rows": len(table)}


def benchmark_rigs(cfg: DictConfig, names) -> list:
    """The benchmark's rigs by name, each in the drift its file selects, its booms from the composed ``boom``
    and ``boom_model`` (as :func:`pipeline.assembly.rig.composed_rig`), its motion from ``motion``, and the
    composed boom's safety model in that drift for designing the faces."""
    from pipeline.rig_benchmarks.round_faces import BenchRig

    if cfg.get("boom_models"):
        raise ConfigError(f"boom_models = {as_dict(cfg.boom_models)!r}: names the booms of one rig; the round "
                          f"benchmark plans rigs {list(names)}: use boom_model (every boom of its kind)")
    out = []
    for name in names:
        tunnel = rig_tunnel(coerce(name, "str", "schedule.bench_rigs"), cfg.tunnel)
        spec = rig_spec(name)
        booms = rig_booms(spec, cfg.boom, cfg.get("boom_model"), None, model_setting)
        rig = build_rig(spec, tunnel, cfg.safety, booms)
        out.append(BenchRig(rig, build_safety(load_boom(cfg.boom), tunnel, cfg.safety),
                            rig_motions(as_dict(cfg.motion), rig.booms)))
    return out


def metrics(summary: dict) -> dict:
    """The summary's numbers, flat (booms.L.moving_s, naive.waiting_s, ...)."""
    out = {}
    for k, v in summary.items():
        if isinstance(v, bool):
            out[k] = int(v)
        elif isinstance(v, (int, float)) and v is not None:
            out[k] = v
        elif isinstance(v, dict):
            for k2, v2 in metrics(v).items():
                out[f"{k}.{k2}"] = v2
    return out


def with_invalid_rows(table: pd.DataFrame, plan) -> pd.DataFrame:
    """The round table plus one ``invalid`` row per unreadable plan row (its problems as the reason),
    every row where it stood in the plan (by line in the file), as ``solve`` keeps them."""
    if not plan.problems:
        return table
    by_row: dict[int, list] = {}
    for p in plan.problems:
        by_row.setdefault(p.row, []).append(p)
    rows = [{"hole_id": ps[0].hole_id or f"row {r}", "boom": "", "status": "invalid",
             "reason": f"row {r}: " + "; ".join(f"{p.column}: {p.message}" for p in ps)}
            for r, ps in sorted(by_row.items())]
    lines = np.arange(len(table)) if plan.lines is None else np.asarray(plan.lines)
    order = np.argsort(np.concatenate([lines, np.array(sorted(by_row), dtype=lines.dtype)]), kind="stable")
    out = pd.concat([table, pd.DataFrame(rows)], ignore_index=True).iloc[order].reset_index(drop=True)
    out["order"] = out["order"].astype("Int64")
    return out


@stage_main
def main(cfg: DictConfig) -> None:
    run_stage(cfg, run, threads="threads")


if __name__ == "__main__":
    main()
