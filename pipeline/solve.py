"""Stage ``solve``: a drill plan in, exact and collision-free joints out, an honest status per hole.

    python -m pipeline.solve plan=data/plans/demo_face.csv
    python -m pipeline.solve plan=round_42.xml out=round_42_joints.csv strict=true
    python -m pipeline.solve plan=round_42.csv solve.model_uri=models:/boom-ik-cuikm@champion
    python -m pipeline.solve rig=twin plan=data/plans/demo_face.csv     # a reach table: every hole by every boom

Reads a CSV or IREDES plan (bad rows are reported with their row and id, the good ones solved),
solves every hole with the hybrid solver (:mod:`pipeline.solvers.hybrid`), and writes
``<plan stem>_solution.csv`` beside the plan (or ``out``): per hole the joints (rad, m), start,
preview and hole-seeking error (mm), the four clearances (m), ``status`` (ok, inexact, unsafe,
unreachable; invalid for unreadable rows) and ``method``; plus ``<stem>_solution.png`` (the face by
status and the boom where it matters) and ``<stem>_solution.json`` (counts, timing, the IREDES
checksum state with the convention and line ends that matched, the file's TMatrix as applied, the
set's MD5s: :meth:`~pipeline.plans.model.DrillPlan.provenance`). Rows stay in the plan's order,
invalid ones in place. ``out`` is checked before any work and the three files are published as one
set (:mod:`pipeline.plans.output`); the plan is solved in chunks (:mod:`pipeline.plans.chunks`). Logs
an MLflow run. With ``strict=true`` it exits with status 1 unless every hole is ok. The hybrid's
settings are the ``solver`` group (conf/solver/hybrid.yaml).

A rig of more than one boom (``rig=twin``, ``rig=trio``) writes a reach table instead
(:mod:`pipeline.plans.reach`, docs/rig.md): one row per hole and boom, a ``boom`` column, the other
booms at park; ``strict=true`` then asks every hole to be ok by at least one boom. ``rig=single``
(the default) is today's path, unchanged.
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass, field

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf

from pipeline.assembly.build import build_safety, load_boom
from pipeline.assembly.rig import build_rig, composed_rig, rig_spec
from pipeline.calibration.model_file import model_setting
from pipeline.core.config import as_dict, project_path
from pipeline.core.errors import ConfigError, StrictCheckFailed
from pipeline.core.io import require_writable
from pipeline.core.settings import coerce, parse, rule
from pipeline.core.stage import run_stage, stage_main
from pipeline.data.holes import joint_box
from pipeline.evaluation.plots import solution_figure
from pipeline.learning.network_source import load_network
from pipeline.plans.chunks import solve_in_chunks
from pipeline.plans.iredes import MAX_TEXT
from pipeline.plans.iredes_frames import TMATRIX_TOL
from pipeline.plans.model import COLLAR
from pipeline.plans.navigation import NavigationSettings, navigation_metrics, navigation_params
from pipeline.plans.output import solution_paths, write_solution_set
from pipeline.plans.reach import reach_figure, solved_reach
from pipeline.plans.read import MAX_PLAN_MB, read_plan_in_rig_frame
from pipeline.plans.solutions import CLEARANCE_COLUMNS, solution_frame, solved_holes, status_counts
from pipeline.solvers.base import NetworkSolver
from pipeline.solvers.hybrid import HybridSettings, HybridSolver
from pipeline.solvers.network_start import first_starts, network_source
from pipeline.tracking.runs import TrackingSettings, stage_run

log = logging.getLogger(__name__)

LOGGED_TABLE_ROWS = 20_000
# Bounds (conf/solve/default.yaml): a chunk's holes not ok after their first start are refined with all their extra
# starts in one batch, about 16 KB a start (jumbo8 with its safety terms, measured), so the chunk times the most
# starts of one kind is bounded too; plans and text nodes beyond these sizes are no drill plan
MAX_CHUNK = 65_536
MAX_BATCH_STARTS = 2**20  # chunk x starts: about 16 GB where every hole of a chunk needs the deep starts
MAX_BOOM_VIEWS = 100
LARGEST_PLAN_MB = 4096.0
LARGEST_TEXT = 2**28


@dataclass(frozen=True)
class IredesSettings:
    """``solve.iredes``: how IREDES coordinates map onto the boom base frame (pipeline/plans/iredes.py)."""

    axes: str = "xyz"
    unit: str = "m"
    origin: tuple[float, ...] = (0.0, 0.0, 0.0)
    checksum: str = field(default="refuse", metadata=rule(choices=("refuse", "warn", "ignore")))
    max_text: int = field(default=MAX_TEXT, metadata=rule(ge=1, le=LARGEST_TEXT))
    tmatrix_tol: float = field(default=TMATRIX_TOL, metadata=rule(gt=0))


@dataclass(frozen=True)
class SolveSettings:
    """The ``solve`` node (the hybrid solver's settings are the ``solver`` group)."""

    network: str = "cuikm"
    model_uri: str | None = None
    figure: bool = True
    max_boom_views: int = field(default=6, metadata=rule(ge=0, le=MAX_BOOM_VIEWS))
    chunk: int = field(default=2048, metadata=rule(ge=1, le=MAX_CHUNK))  # holes at a time: bounds memory, not the plan
    progress: bool = True
    max_plan_mb: float = field(default=MAX_PLAN_MB, metadata=rule(gt=0, le=LARGEST_PLAN_MB))
    iredes: IredesSettings = field(default_factory=IredesSettings)


def check_batch(settings: SolveSettings, hybrid: HybridSettings) -> None:
    """ConfigError when a chunk's extra starts, refined in one batch, would not fit in memory (MAX_BATCH_STARTS)."""
    name, starts = max((("solver.perturbed_starts", hybrid.perturbed_starts), ("solver.random_starts",
                         hybrid.random_starts), ("solver.deep_starts", hybrid.deep_starts)), key=lambda kv: kv[1])
    if settings.chunk * starts > MAX_BATCH_STARTS:
        raise ConfigError(f"solve.chunk = {settings.chunk}: with {name} = {starts} a chunk refines up to "
                          f"{settings.chunk * starts} starts in one batch (about 16 KB each), at most "
                          f"{MAX_BATCH_STARTS}: lower solve.chunk")


def run(cfg: DictConfig) -> dict:
    settings = parse(SolveSettings, cfg.solve, "solve")
    hybrid = parse(HybridSettings, cfg.solver, "solver")
    check_batch(settings, hybrid)
    tracking = TrackingSettings.from_config(cfg.tracking)
    plan_path = project_path(coerce(cfg.plan, "str", "plan"))
    # Before any work: never the plan itself, never colliding names, never a folder (pipeline/plans/output.py).
    paths = solution_paths(plan_path, project_path(cfg.out) if cfg.get("out") else None)
    out = paths.csv
    strict = coerce(cfg.get("strict", False), "bool", "strict")
    require_writable(out.parent, "out (its folder)")
    navigation = parse(NavigationSettings, cfg.navigation, "navigation")
    spec = rig_spec(cfg.rig)
    if len(spec.mounts) > 1:  # a reach table; one boom keeps today's path and file format
        rig = composed_rig(cfg, model_setting)  # boom_model: every boom of its kind; boom_models: per boom
        return solve_rig(cfg, rig, settings, hybrid, tracking, plan_path, paths, strict, navigation)
    build_rig(spec, cfg.tunnel, cfg.safety, boom_cfg=cfg.boom)  # the one-boom rig checked; solved with `boom`
    if cfg.get("boom_models"):
        raise ConfigError(f"boom_models = {as_dict(cfg.boom_models)!r}: one model per boom of a rig; this is a "
                          "one-boom solve: use boom_model=<file>")
    boom = load_solve_boom(cfg.boom, cfg.get("boom_model"))
    safety = build_safety(boom, cfg.tunnel, cfg.safety)
    # a bad plan or navigation fails before the network loads
    plan = read_plan_in_rig_frame(plan_path, navigation, asdict(settings.iredes), settings.max_plan_mb)
    source = network_source(project_path(cfg.paths.data), settings.network, settings.model_uri)
    network, _ = load_network(source, boom, tracking.uri, "solve.model_uri")
    for line in plan.report():
        log.warning("skipped: %s", line)
    method = f"hybrid ({settings.model_uri or settings.network})"
    with stage_run(tracking, f"solve-{plan_path.stem}", {"stage": "solve", "plan": str(plan_path),
                                                         "plan_checksum": plan.checksum}) as mlrun:
        mlrun.log_params({"plan": str(plan_path), "solve": OmegaConf.to_container(cfg.solve, resolve=True),
                          "solver": as_dict(cfg.solver), "boom_model": str(cfg.get("boom_model")),
                          "plan_checksum": plan.checksum, **navigation_params(plan)})
        mlrun.log_dataset(plan.holes, plan_path, "drill plan")
        box = cfg.holes.sup.get("box")  # random starts within the working box
        solver = HybridSolver(boom, safety, NetworkSolver(boom, network, settings.network), hybrid, "hybrid",
                              joint_box(boom, None if box is None else as_dict(box)))
        result = solve_in_chunks(solver, plan.poses(boom.preview_depth), boom.preview_depth, settings.chunk,
                                 settings.progress)
        table = solution_frame(plan, result, boom.joint_names, method, solved_holes(plan, *boom.tool_pose(result.q)))
        summary = {"holes": len(plan), "invalid_rows": invalid_rows(plan), **status_counts(table),
                   "hole_mm_max": float(np.nanmax(table["hole_mm"].to_numpy(dtype=float))), "solve_s": result.wall_s,
                   "ms_per_hole": 1000 * result.wall_s / len(plan)}
        mlrun.log_metrics({**summary, **navigation_metrics(plan)})
        if len(table) <= LOGGED_TABLE_ROWS:  # MLflow's table view holds the whole table in memory as JSON
            mlrun.log_table(table, "solution.json")
        fig = (solution_figure(table, plan.holes[COLLAR].to_numpy(), safety.tunnel,
                               boom_views(table, result.q, safety, settings.max_boom_views), safety.distances.wall)
               if settings.figure else None)
        if fig is not None:
            mlrun.log_figure(fig, "solution.png")
        record = {"plan": str(plan_path), "method": method, **plan.provenance(), **summary,
                  "navigation": plan.navigation.record()}
        write_solution_set(paths, table, record, fig, lambda staged: mlrun.log_artifact(staged["csv"]))
    log.info("solved %d holes in %.2f s (%.3f ms/hole): %s -> %s", len(plan), result.wall_s, summary["ms_per_hole"],
             status_counts(table), out)
    if strict and summary["ok"] != len(table):
        raise StrictCheckFailed(f"strict: {len(table) - summary['ok']} of {len(table)} holes are not ok (see {out})")
    return {**summary, "checksum": plan.checksum}


def solve_rig(cfg: DictConfig, rig, settings: SolveSettings, hybrid: HybridSettings, tracking, plan_path, paths,
              strict: bool, navigation: NavigationSettings) -> dict:
    """Every hole by every boom of ``rig``, the others at park: the reach table, its JSON and figure,
    published as one set like a single boom's solution."""
    source = network_source(project_path(cfg.paths.data), settings.network, settings.model_uri)
    plan = read_plan_in_rig_frame(plan_path, navigation, asdict(settings.iredes), settings.max_plan_mb)
    out = paths.csv
    for line in plan.report():
        log.warning("skipped: %s", line)
    method = f"hybrid ({settings.model_uri or settings.network})"
    box = cfg.holes.sup.get("box")
    with stage_run(tracking, f"solve-{plan_path.stem}-{rig.name}", {"stage": "solve", "plan": str(plan_path),
                                                                    "rig": rig.name,
                                                                    "plan_checksum": plan.checksum}) as mlrun:
        mlrun.log_params({"plan": str(plan_path), "rig": rig.name, "solve": as_dict(cfg.solve),
                          "solver": as_dict(cfg.solver), "boom_model": str(cfg.get("boom_model")),
                          "boom_models": str(cfg.get("boom_models")), "plan_checksum": plan.checksum,
                          **navigation_params(plan)})
        network = first_starts(source, settings.network, tracking.uri, "solve.model_uri")  # per boom, checked
        _, reach = solved_reach(plan, rig, network, hybrid, None if box is None else as_dict(box), method)
        summary = {"rig": rig.name, "booms": rig.names, "invalid_rows": invalid_rows(plan), **reach.summary()}
        mlrun.log_metrics({**{k: v for k, v in summary.items() if isinstance(v, (int, float))},
                           **navigation_metrics(plan)})
        if len(reach.table) <= LOGGED_TABLE_ROWS:
            mlrun.log_table(reach.table, "reach.json")
        fig = reach_figure(reach, plan, rig) if settings.figure else None
        if fig is not None:
            mlrun.log_figure(fig, "reach.png")
        record = {"plan": str(plan_path), "method": method, **plan.provenance(), **summary,
                  "navigation": plan.navigation.record()}
        write_solution_set(paths, reach.table, record, fig, lambda staged: mlrun.log_artifact(staged["csv"]))
    log.info("rig %s: %d holes, %d ok by at least one boom (%s) -> %s", rig.name, summary["holes"],
             summary["ok_by_any"], ", ".join(f"{b}: {summary[b + '.ok']} ok" for b in rig.names), out)
    if strict and summary["ok_by_none"]:
        raise StrictCheckFailed(f"strict: {summary['ok_by_none']} hole(s) no boom can drill: "
                                f"{summary['holes_ok_by_none']} (see {out})")
    return summary


def load_solve_boom(boom_cfg, boom_model):
    """The composed boom ``boom``, or a calibrated one (``boom_model=<file>``) on the composed boom when it is
    of that kind (else on its kind's config); a missing or bad file is a ConfigError naming ``boom_model``."""
    boom = load_boom(boom_cfg)
    if not boom_model:
        return boom
    return model_setting("boom_model", boom_model, {boom.name: boom})


def invalid_rows(plan) -> int:
    """Rows of the plan that were skipped: a row with several bad cells is one row."""
    return len({p.row for p in plan.problems})


def boom_views(table, q: torch.Tensor, safety, limit: int) -> list[dict]:
    """Where to draw the boom: the ok hole with the smallest clearance, then every hole that is
    not ok (up to ``limit`` drawings in all)."""
    solved = table[table["status"] != "invalid"].reset_index(drop=True)
    worst = solved[CLEARANCE_COLUMNS].min(axis=1).to_numpy()
    ok = (solved["status"] == "ok").to_numpy()
    picks = [int(np.flatnonzero(ok)[np.argmin(worst[ok])])] if ok.any() else []
    picks += [int(i) for i in np.flatnonzero(~ok)]
    views = []
    boom = safety.boom
    frames = boom.frames(q[picks[:limit]]) if picks else None
    for k, i in enumerate(picks[:limit]):
        capsules = [(name, *(p.numpy() for p in boom.capsule_ends(frames[k], name)), body.radius)
                    for name, body in boom.bodies.items()]
        row = solved.iloc[i]
        title = f"{row['hole_id']} ({row['status']}, min clearance {worst[i]:.3f} m)"
        views.append({"hole_id": row["hole_id"], "status": row["status"], "title": title, "capsules": capsules})
    return views


@stage_main
def main(cfg: DictConfig) -> None:
    run_stage(cfg, run, threads="threads")


if __name__ == "__main__":
    main()
