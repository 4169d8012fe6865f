"""Every config composes, every settings node every stage reads parses (in every experiment and with every
option of every group), unknown keys are refused, and every settings class's defaults equal conf/."""

import dataclasses
import re

import pytest
from omegaconf import OmegaConf

from pipeline.assembly.build import build_safety, hole_sampling
from pipeline.calibration.study import CalibrationSettings
from pipeline.core.config import CONF_DIR, compose
from pipeline.core.errors import ConfigError
from pipeline.core.settings import RuntimeSettings, parse
from pipeline.data.hole_sets import SupervisedSet
from pipeline.deploy.package import ExportSettings
from pipeline.derive_box import DeriveBoxSettings
from pipeline.evaluate import EvalSettings
from pipeline.evaluation.solver_benchmark import SolverBenchmarkSettings
from pipeline.events.draws import parse_draws
from pipeline.execute import parse_execute
from pipeline.field_boom import FieldBoomSettings
from pipeline.generate import SetSize, TestGroups, supervised_sets
from pipeline.learning.distillation import DistillSettings
from pipeline.learning.models import ModelSettings
from pipeline.learning.training import MethodSettings, TrainSettings
from pipeline.plans.navigation import NavigationSettings
from pipeline.quality import QualitySettings
from pipeline.rig_benchmarks.moves import MoveBenchmarkSettings
from pipeline.round.settings import parse_round
from pipeline.schedule import ScheduleSettings
from pipeline.solve import SolveSettings, check_batch
from pipeline.solvers.hybrid import HybridSettings
from pipeline.sweep_table import SweepSettings
from pipeline.tracking.runs import TrackingSettings

EXPERIMENTS = sorted(p.stem for p in (CONF_DIR / "experiment").glob("*.yaml"))
METHOD_NODES = ("method", "baselines.sikm", "baselines.uikm", "baselines.sikm_best")

# settings class -> the node it parses (the stage that reads it)
NODES = {
    TrainSettings: "train",            # train
    ModelSettings: "model",            # train, export_benchmark
    EvalSettings: "eval",              # evaluate
    SolverBenchmarkSettings: "solver_benchmark",  # solver_benchmark
    SolveSettings: "solve",            # solve
    HybridSettings: "solver",          # solve, solver_benchmark (and the round planner)
    ExportSettings: "export",          # export, export_benchmark
    CalibrationSettings: "calibration",  # calibrate
    DeriveBoxSettings: "derive_box",   # derive_box
    DistillSettings: "distill",        # distill
    RuntimeSettings: "runtime",        # every stage's main
    SupervisedSet: "holes.sup",        # generate (less its box)
}
# the product stages' nodes (their code defaults need not be conf's: only conf's values are checked)
PRODUCT_NODES = {
    MoveBenchmarkSettings: "move_benchmark",  # move_benchmark
    ScheduleSettings: "schedule",             # schedule
    QualitySettings: "quality",               # quality
    NavigationSettings: "navigation",         # solve, schedule, execute, move_benchmark
    FieldBoomSettings: "field_boom",          # field_boom
}


def node(cfg, key: str):
    value = OmegaConf.to_container(OmegaConf.select(cfg, key), resolve=True)
    return {k: v for k, v in value.items() if k != "box"} if key == "holes.sup" else value


def check_all_groups(cfg) -> None:
    """What each stage parses first thing, before it reads data or opens a run."""
    for cls, key in {**NODES, **PRODUCT_NODES}.items():
        parse(cls, node(cfg, key), key)
    parse_round(node(cfg, "round"), "round")  # schedule, execute
    parse_draws(node(cfg, "draws"), "draws")
    parse_execute(cfg)
    check_batch(parse(SolveSettings, node(cfg, "solve"), "solve"), parse(HybridSettings, node(cfg, "solver"), "solver"))
    TrackingSettings.from_config(cfg.tracking)
    SweepSettings.from_config(cfg.sweeps)  # sweep_table
    for key in METHOD_NODES:
        MethodSettings.from_config(OmegaConf.select(cfg, key), key)
    parse(SetSize, cfg.holes.unsup, "holes.unsup")  # generate's sets
    parse(TestGroups, cfg.holes.test, "holes.test")
    supervised_sets(cfg.holes)
    build_safety(cfg.boom, cfg.tunnel, cfg.safety)
    hole_sampling(cfg.holes)


def group_options() -> list[str]:
    """``group=option`` for every option of every config group (nested calibration groups included)."""
    out = []
    for folder in sorted(p for p in CONF_DIR.rglob("*") if p.is_dir()):
        group = folder.relative_to(CONF_DIR).as_posix()
        if group.startswith(("hydra", "experiment")) or group in ("calibration/level",):
            continue
        out += [f"{group}={p.stem}" for p in sorted(folder.glob("*.yaml"))]
    return out


def test_there_are_experiments_and_groups():
    assert {"quick", "paper", "sweep_lambda_mu", "sweep_safety"} <= set(EXPERIMENTS)
    assert {"solver=hybrid", "runtime=default", "boom=huang9", "calibration/sensor=noise_free"} <= set(group_options())


@pytest.mark.parametrize("experiment", [None, *EXPERIMENTS])
def test_every_experiment_composes_and_validates(experiment):
    cfg = compose([] if experiment is None else [f"experiment={experiment}"])
    OmegaConf.resolve(cfg)
    check_all_groups(cfg)


@pytest.mark.parametrize("option", group_options())
def test_every_group_option_composes_and_validates(option):
    if option.startswith("boom=") and option != "boom=jumbo8":  # other booms: no tunnel / working box of theirs
        from pipeline.assembly.build import load_boom

        assert load_boom(option.split("=")[1]).n_joints >= 6
        return
    overrides = [option]
    if option == "tunnel=profile":  # a profile is a file: without one it is refused, naming the setting
        with pytest.raises(ConfigError, match=r"tunnel.file = None: tunnel=profile needs the profile CSV"):
            check_all_groups(compose(overrides))
        overrides.append("tunnel.file=conf/tunnel/profiles/d_5x5.csv")
    cfg = compose(overrides)
    OmegaConf.resolve(cfg)
    check_all_groups(cfg)


def test_every_calibration_level_parses():
    for level in sorted((CONF_DIR / "calibration" / "level").glob("*.yaml")):
        cfg = compose([f"calibration/level@calibration.levels.paper={level.stem}"])
        parse(CalibrationSettings, node(cfg, "calibration"), "calibration")


def field_default(f: dataclasses.Field):
    return f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default


@pytest.mark.parametrize("cls", list(NODES), ids=lambda c: c.__name__)
def test_every_settings_default_equals_its_conf_value(cls):
    """Code and conf/ agree, nested classes (calibration.network, swarm, ...) included: a default nobody can
    see in conf/ must not differ from the value every run uses."""
    key = NODES[cls]
    parsed, conf = parse(cls, node(compose([]), key), key), node(compose([]), key)
    for f in dataclasses.fields(cls):
        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            continue
        assert f.name in conf, f"{key}.{f.name}: a code default ({field_default(f)!r}) with no conf value"
        assert getattr(parsed, f.name) == field_default(f), (key, f.name, conf[f.name], field_default(f))


@pytest.mark.parametrize(("override", "pattern"), [
    ("train.steps=0", r"train.steps = 0: must be >= 1"),
    ("train.steps=-5", r"train.steps = -5: must be >= 1"),
    ("train.steps=nan", r"train.steps = nan: expected an integer"),
    ("train.eval_every=0", r"train.eval_every = 0: must be >= 1"),
    ("train.lr=0", r"train.lr = 0.0: must be > 0"),
    ("train.lr=abc", r"train.lr = 'abc': expected a number"),
    ("train.batch_size=0", r"train.batch_size = 0: must be >= 1"),
    ("model.activation=swish", r"model.activation = 'swish': expected one of"),
    ("tracking.enabled=maybe", r"tracking.enabled = 'maybe': expected true or false"),
    ("eval.timing_repeats=0", r"eval.timing_repeats = 0: must be >= 1"),
    ("solver_benchmark.holes=-1", r"solver_benchmark.holes = -1: must be >= 1"),
    ("solver.max_iters=0", r"solver.max_iters = 0: must be >= 1"),
    ("solver.prefer=fast", r"solver.prefer = 'fast': expected one of"),
    ("runtime.threads=0", r"runtime.threads = 0: must be >= 1"),
    ("solve.iredes.checksum=trust", r"solve.iredes.checksum = 'trust': expected one of"),
    ("calibration.methods=[bp,magic]", r"calibration.methods = 'magic': expected one of"),
    ("calibration.run_levels=[nosuch]", r"calibration.run_levels = \['nosuch'\]: \['nosuch'\] not among"),
    ("calibration.n_measurements=[1]", r"calibration.n_measurements = 1: must be >= 2"),
    ("calibration.ik.tol=0", r"calibration.ik.tol = 0.0: must be > 0"),
    ("calibration.network.trainer=adam", r"trainer in \('lm', 'gd'\) required"),
    ("derive_box.holes=10", r"derive_box.holes = 10: must be >= 100"),
    ("holes.unsup.size=0", r"holes.unsup.size = 0: must be >= 1"),
    # every size, count, duration and iteration budget has an upper bound, refused by name before any
    # work (a huge value ended in an allocation traceback after minutes); each bound is stated in its conf file
    ("train.batch_size=100000000", r"train.batch_size = 100000000: must be <= 65536"),
    ("train.steps=1e9", r"train.steps = 1000000000: must be <= 10000000"),
    ("train.val_size=100000000", r"train.val_size = 100000000: must be <= 1000000"),
    ("train.seed=1e20", r"train.seed = 100000000000000000000: must be <= 4294967295"),
    ("model.width=1000000", r"model.width = 1000000: must be <= 4096"),
    ("model.depth=1000", r"model.depth = 1000: must be <= 16"),
    ("baselines.sikm.max_steps=1e9", r"baselines.sikm.max_steps = 1000000000: must be <= 10000000"),
    ("holes.unsup.size=1e9", r"holes.unsup.size = 1000000000: must be <= 1000000"),
    ("holes.sup.size=1e8", r"holes.sup.size = 100000000: must be <= 1000000"),
    ("holes.sup_variants.coupled.size=1e8", r"holes.sup_variants.coupled.size = 100000000: must be <= 1000000"),
    ("holes.sup_variants.continuation.label_iters=1e6",
     r"holes.sup_variants.continuation.label_iters = 1000000: must be <= 10000"),
    ("holes.test.size=1e9", r"holes.test.size = 1000000000: must be <= 1000000"),
    ("holes.test.seeds=[1,1e12]", r"holes.test.seeds = 1000000000000: must be <= 4294967295"),
    (f"holes.test.seeds=[{','.join(map(str, range(101)))}]", r"holes.test.seeds: 101 items, at most 100 allowed"),
    ("solver.deep_starts=1e6", r"solver.deep_starts = 1000000: must be <= 1024"),
    ("solver.random_starts=100000", r"solver.random_starts = 100000: must be <= 1024"),
    ("solver.perturbed_starts=5000", r"solver.perturbed_starts = 5000: must be <= 1024"),
    ("solver.max_iters=1e9", r"solver.max_iters = 1000000000: must be <= 1000"),
    ("solver.deep_iters=1e6", r"solver.deep_iters = 1000000: must be <= 1000"),
    ("solver.seed=1e20", r"solver.seed = 100000000000000000000: must be <= 4294967295"),
    ("solve.chunk=1e9", r"solve.chunk = 1000000000: must be <= 65536"),
    ("solve.chunk=65536", r"solve.chunk = 65536: with solver.deep_starts = 128 a chunk refines up to 8388608 starts"),
    ("solve.max_boom_views=1e6", r"solve.max_boom_views = 1000000: must be <= 100"),
    ("solve.max_plan_mb=1e12", r"solve.max_plan_mb = 1000000000000.0: must be <= 4096"),
    ("solve.iredes.max_text=1e12", r"solve.iredes.max_text = 1000000000000: must be <= 268435456"),
    ("eval.timing_repeats=1e6", r"eval.timing_repeats = 1000000: must be <= 1000"),
    ("solver_benchmark.holes=1e9", r"solver_benchmark.holes = 1000000000: must be <= 1000000"),
    ("solver_benchmark.groups=[1,1000]", r"solver_benchmark.groups = 1000: must be <= 100"),
    ("solver_benchmark.single=1e9", r"solver_benchmark.single = 1000000000: must be <= 10000"),
    ("solver_benchmark.reference_ok_sample=1e9",
     r"solver_benchmark.reference_ok_sample = 1000000000: must be <= 100000"),
    ("solver_benchmark.solvers.rbf.samples=1e6", r"solver_benchmark.solvers.rbf.samples = 1000000: must be <= 20000"),
    ("solver_benchmark.solvers.pso.population=1e9",
     r"solver_benchmark.solvers.pso.population = 1000000000: must be <= 10000"),
    ("solver_benchmark.solvers.ceopso.iterations=1e9",
     r"solver_benchmark.solvers.ceopso.iterations = 1000000000: must be <= 10000"),
    ("+solver_benchmark.solvers.ga.grid=100", r"solver_benchmark.solvers.ga.grid = 100: must be <= 10"),
    ("solver_benchmark.solvers.ga.generations=1e7",
     r"solver_benchmark.solvers.ga.generations = 10000000: must be <= 10000"),
    ("solver_benchmark.solvers.nm.restarts=1e6", r"solver_benchmark.solvers.nm.restarts = 1000000: must be <= 1000"),
    ("solver_benchmark.solvers.hybrid.single=1e9",
     r"solver_benchmark.solvers.hybrid.single = 1000000000: must be <= 10000"),
    ("solver_benchmark.solvers.nm_coupled.max_holes=1e9",
     r"solvers.nm_coupled.max_holes = 1000000000: must be <= 1000000"),
    ("solver_benchmark.solvers.rbf.seed=abc", r"solver_benchmark.solvers.rbf.seed = 'abc': expected an integer"),
    ("solver_benchmark.papers.pso.runs=1e9", r"solver_benchmark.papers.pso.runs = 1000000000: must be <= 10000"),
    ("solver_benchmark.papers.pso.populations=[200,1e9]",
     r"solver_benchmark.papers.pso.populations = 1000000000: must be <= 10000"),
    ("solver_benchmark.papers.pso.checkpoints=[50,500]", r"solver_benchmark.papers.pso.checkpoints\[1\] = 500: beyond"),
    ("solver_benchmark.papers.ga.generations=1e9",
     r"solver_benchmark.papers.ga.generations = 1000000000: must be <= 10000"),
    ("solver_benchmark.papers.rbf.groups=[1,1000]", r"solver_benchmark.papers.rbf.groups = 1000: must be <= 100"),
    ("calibration.n_measurements=[10,1e7]", r"calibration.n_measurements = 10000000: must be <= 10000"),
    ("calibration.holdout=1e9", r"calibration.holdout = 1000000000: must be <= 100000"),
    ("calibration.ik.max_iters=1e9", r"calibration.ik.max_iters = 1000000000: must be <= 10000"),
    ("calibration.ik.restarts=1e6", r"calibration.ik.restarts = 1000000: must be <= 1000"),
    ("calibration.network.hidden=[8,100000]", r"calibration.network.hidden = 100000: must be <= 128"),
    ("calibration.network.hidden=[8,8,8,8,8]", r"calibration.network.hidden: 5 items, at most 4 allowed"),
    ("calibration.network.iterations=1e9", r"calibration.network.iterations = 1000000000: must be <= 100000"),
    ("calibration.swarm.pso.population=1e9", r"calibration.swarm.pso.population = 1000000000: must be <= 10000"),
    ("calibration.swarm.ssa.iterations=1e9", r"calibration.swarm.ssa.iterations = 1000000000: must be <= 10000"),
    ("calibration.identification.basis_poses=1e9",
     r"calibration.identification.basis_poses = 1000000000: must be <= 100000"),
    ("calibration.identification.max_iters=1e9", r"identification.max_iters = 1000000000: must be <= 10000"),
    ("calibration.gate.folds=1e6", r"calibration.gate.folds = 1000000: must be <= 100"),
    ("calibration.seeds.noise=1e20", r"calibration.seeds.noise = 100000000000000000000: must be <= 4294967295"),
    ("export.check.holes=1e9", r"export.check.holes = 1000000000: must be <= 1000000"),
    ("export.benchmark.batches=[1,1e8]", r"export.benchmark.batches = 100000000: must be <= 65536"),
    ("export.benchmark.ort_threads=[1,100000]", r"export.benchmark.ort_threads = 100000: must be <= 256"),
    ("export.benchmark.min_repeats=1e9", r"export.benchmark.min_repeats = 1000000000: must be <= 100000"),
    ("export.benchmark.min_time_s=1e9", r"export.benchmark.min_time_s = 1000000000.0: must be <= 3600"),
    ("derive_box.holes=1e9", r"derive_box.holes = 1000000000: must be <= 1000000"),
    ("runtime.threads=100000", r"runtime.threads = 100000: must be <= 256"),
    ("runtime.train_threads=1e6", r"runtime.train_threads = 1000000: must be <= 256"),
    ("runtime.checkpoint_every=1e12", r"runtime.checkpoint_every = 1000000000000: must be <= 10000000"),
    ("move_benchmark.pairs=1e9", r"move_benchmark.pairs = 1000000000: must be <= 100000"),
    ("move_benchmark.planner_iterations=1e12", r"planner_iterations = 1000000000000: must be <= 1000000"),
    ("move_benchmark.distance_batch=1e9", r"move_benchmark.distance_batch = 1000000000: must be <= 65536"),
    ("move_benchmark.planner_time_s=1e9", r"move_benchmark.planner_time_s = 1000000000.0: must be <= 3600"),
    ("move_benchmark.seed=4294967295", r"move_benchmark.seed = 4294967295: must be <= 2147483647"),
    ("schedule.replay_frames=1e9", r"schedule.replay_frames = 1000000000: must be <= 10000"),
    ("schedule.bench_faces=[demo,1e6]", r"schedule.bench_faces\[1\] = 1000000.0: expected demo or a face of 20..1000"),
    ("schedule.bench_faces=[demo,many]", r"schedule.bench_faces\[1\] = 'many': expected demo or a face of 20..1000"),
    ("schedule.bench_seed=-1", r"schedule.bench_seed = -1: must be >= 0"),
    ("quality.max_log_mb=1e9", r"quality.max_log_mb = 1000000000.0: must be <= 4096"),
    ("field_boom.poses=1e9", r"field_boom.poses = 1000000000: must be <= 100000"),
    ("round.postures=1e5", r"round.postures = 100000: must be <= 64"),
    ("safety.points_per_capsule=100000", r"safety.points_per_capsule = 100000: at most 256"),
    ("draws.count=1e9", r"draws.count = 1000000000: must be <= 10000"),
    ("execute.replay_frames=1e9", r"execute.replay_frames = 1000000000: must be <= 10000"),
    ("tracking.busy_timeout_s=1e12", r"tracking.busy_timeout_s = 1000000000000.0: expected a number of seconds in "
                                     r"\[0, 86400\]"),
])
def test_bad_settings_are_named(override, pattern):
    with pytest.raises(ConfigError, match=pattern):
        check_all_groups(compose([override]))


@pytest.mark.parametrize(("override", "pattern"), [
    ("+solver.deep_start=3", r"solver.deep_start: unknown setting; did you mean 'deep_starts'\?"),
    ("+solve.netwrok=uikm", r"solve.netwrok: unknown setting; did you mean 'network'\?"),
    ("+solve.iredes.unit_=mm", r"solve.iredes.unit_: unknown setting; did you mean 'unit'\?"),
    ("+train.stepz=3", r"train.stepz: unknown setting; did you mean 'steps'\?"),
    ("+export.check.seeds=3", r"export.check.seeds: unknown setting; did you mean 'seed'\?"),
    ("+calibration.swarm.pso.popluation=9", r"swarm.pso.popluation: unknown setting; did you mean 'population'\?"),
    ("+runtime.thread=1", r"runtime.thread: unknown setting; did you mean 'threads'\?"),
    ("+solver_benchmark.solvers.hybrid.tol_mm=1",
     r"solver_benchmark.solvers.hybrid.tol_mm: unknown setting.*solver group"),
])
def test_unknown_keys_are_refused_with_the_closest_known_one(override, pattern):
    cfg = compose([override])
    with pytest.raises(ConfigError, match=pattern):
        check_all_groups(cfg)
        from pipeline.solvers import build_solver

        spec = OmegaConf.to_container(cfg.solver_benchmark.solvers.hybrid)
        build_solver("hybrid", spec, None, "models", {}, safety=object())


def test_old_homes_of_moved_settings_are_refused():
    """Settings that moved to one source must not be accepted, and silently ignored, at their old place."""
    for old in ("+solve.solver.deep_starts=16", "+train.threads=1", "+train.log_model=false"):
        with pytest.raises(ConfigError, match="unknown setting"):
            check_all_groups(compose([old]))


def test_quick_overrides_the_one_hybrid_source():
    cfg = compose(["experiment=quick"])
    assert parse(HybridSettings, cfg.solver, "solver").deep_starts == 16
    # the benchmark's entry holds no solver settings: its kind, its first start and how many holes it times alone
    assert set(cfg.solver_benchmark.solvers.hybrid) == {"kind", "init", "single"}


def test_the_quick_tour_prints_the_figures_the_docs_report():
    """``tour`` holds what the full study measured, the mean over its seeds: the networks' table of
    docs/benchmarks.md ("Current results", which the README's results table quotes), one row a method."""
    tour = compose(["experiment=quick"]).tour
    docs = (CONF_DIR.parent / "docs" / "benchmarks.md").read_text()
    rows = {"cuikm": "CUIKM", "uikm": "UIKM", "sikm_best": "SIKM, best variant"}
    assert set(tour.hole_mm) <= set(rows) and set(tour.hole_mm) >= {"cuikm", "uikm"}
    for method, name in rows.items():
        if method not in tour.hole_mm:
            continue
        over_seeds = r"\**([\d.]+) ± [\d.]+"  # the "over 3 seeds" columns: mean ± std
        row = re.search(rf"^\| \**{re.escape(name)}\**[^|]*\|[^|]*\| {over_seeds}\** \|[^|]*\|[^|]*\|[^|]*\| "
                        rf"{over_seeds} %\** \|", docs, re.M)
        assert row, name
        assert (tour.hole_mm[method], tour.collision_pct[method]) == (float(row[1]), float(row[2])), method
    readme = (CONF_DIR.parent / "README.md").read_text()
    assert (f"mean hole-seeking error {tour.hole_mm.cuikm:g} ± " in readme
            and f"collision rate {tour.collision_pct.cuikm:g} ± " in readme)
