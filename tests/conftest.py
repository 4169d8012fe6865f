"""Shared fixtures: the reference boom and safety model, config composition (as the stages see it), and
the tiny study (generate + CUIKM trained once per session) that tests get a private copy of."""

import os
import shutil
import sqlite3
from pathlib import Path

import pytest

from pipeline.assembly.build import build_safety, load_boom
from pipeline.core.config import compose, load_group_file

# pytest-xdist workers beside each other (addopts: -n 2): each keeps to one torch and one numba thread in
# process, so two workers on two cores do not oversubscribe them (a first two-worker CI run, without this,
# the file order below or the DVC test's overrides, took 32 min against 24 in one process). Stage
# subprocesses keep their own settings (runtime.threads); the DVC test sets one thread for its stages.
_WORKERS = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))

# Files whose tests take longest start first, so the other worker runs the rest beside them
# (addopts: --no-loadscope-reorder keeps this order); measured with --durations in a one-process run.
_LONGEST_FIRST = ("test_sweeps_dvc.py", "test_schedule.py", "test_reliability.py", "test_compiled.py",
                  "test_check_execution.py")


def pytest_configure(config):
    """Two workers on two cores: the processes they start (stages, scripts, sweep jobs) and the workers'
    own BLAS and OpenMP pools get one thread each, as the workers' torch and numba do (below). Set in
    the controller before it starts the workers, so they and their children inherit it; a stage that
    sets its own threads (``runtime.threads``) still does, so the tests that start one pass
    ``runtime.threads=1`` too. Five or six threads on two cores only wait on each other (measured: a few
    percent of those tests' CPU, docs/benchmarks.md, "The test suite")."""
    workers = getattr(config.option, "numprocesses", None)
    if _WORKERS > 1 or workers not in (None, 0, 1):
        for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ.setdefault(var, "1")


def pytest_collection_modifyitems(config, items):
    rank = {name: i for i, name in enumerate(_LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable: the rest keep their order


@pytest.fixture(autouse=True)
def _one_thread_per_worker():
    if _WORKERS > 1:
        import numba
        import torch

        torch.set_num_threads(1)  # a stage's main() run in-process may have set more
        numba.set_num_threads(1)
    yield


@pytest.fixture(scope="session")
def jumbo8():
    return load_boom("jumbo8")


@pytest.fixture(scope="session")
def safety(jumbo8):
    return build_safety(jumbo8, load_group_file("tunnel", "horseshoe"), load_group_file("safety", "paper"))


@pytest.fixture(scope="module")
def one_torch_thread():
    """One torch thread for a module, as calibrate runs (runtime.calibrate_threads): its tiny batched ops
    run far faster on one thread than on two contending ones."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="session")
def make_cfg():
    """``make_cfg(tmp, *overrides)``: the tiny experiment (conf/experiment/tiny.yaml) writing data, MLflow store
    and artifacts under ``tmp``, so a test never touches the checkout's own ``data/`` or ``mlflow.db``."""

    def make(tmp: Path, *overrides: str):
        return compose(["experiment=tiny", f"paths.data={tmp}/data", f"tracking.uri=sqlite:///{tmp}/mlflow.db",
                        f"tracking.artifact_root={tmp}/artifacts", *overrides])

    return make


@pytest.fixture(scope="session")
def _tiny_study(tmp_path_factory, make_cfg) -> Path:
    """Built once a session: the tiny experiment's holes, the demo face and its CUIKM network, with their MLflow
    runs. Under pytest-xdist the workers share one build (the first to need it builds it, under a lock, in the
    session's own temporary folder), as no test writes to it: they use copies (``copy_study``)."""
    from filelock import FileLock

    from pipeline import demo_face, generate, train

    if os.environ.get("PYTEST_XDIST_WORKER") is None:
        root = tmp_path_factory.getbasetemp()
    else:  # .../pytest-<n>/popen-gw<k>: the parent is this session's, shared by its workers alone
        root = tmp_path_factory.getbasetemp().parent
    tmp, done = root / "tiny_study_shared", root / "tiny_study_shared.done"
    with FileLock(str(root / "tiny_study_shared.lock")):
        if not done.is_file():
            shutil.rmtree(tmp, ignore_errors=True)  # a build a failed worker left half done
            tmp.mkdir()
            generate.run(make_cfg(tmp))
            demo_face.run(make_cfg(tmp))  # the drill plans, as DVC's demo_face stage writes them
            train.run(make_cfg(tmp, "method=cuikm"))
            done.touch()
    return tmp


def copy_study(src: Path, dst: Path) -> Path:
    """``src``'s data/, MLflow store and artifacts under ``dst``. The store names its artifact folders by
    absolute path, so those are rewritten: a run logged in the copy must land in the copy."""
    shutil.copytree(src / "data", dst / "data")
    shutil.copytree(src / "artifacts", dst / "artifacts")
    shutil.copy2(src / "mlflow.db", dst / "mlflow.db")
    old, new = f"{src}/", f"{dst}/"
    with sqlite3.connect(dst / "mlflow.db") as db:
        tables = [t for (t,) in db.execute("select name from sqlite_master where type = 'table'")]
        for table in tables:
            for _, column, kind, *_ in db.execute(f"pragma table_info('{table}')").fetchall():
                if "CHAR" in kind.upper() or "TEXT" in kind.upper():
                    db.execute(f'update "{table}" set "{column}" = replace("{column}", ?, ?) '
                               f'where instr("{column}", ?) > 0', (old, new, old))
    return dst


@pytest.fixture(scope="session")
def copy_tiny_study(_tiny_study):
    """``copy_tiny_study(dst)``: a private copy of the tiny study under ``dst`` (for module fixtures)."""
    return lambda dst: copy_study(_tiny_study, Path(dst))


@pytest.fixture
def tiny_study(_tiny_study, tmp_path) -> Path:
    """A private copy of the tiny study in ``tmp_path``: what a test writes there no other test sees."""
    return copy_study(_tiny_study, tmp_path)


# The clock-timed round (no interlocks from the stage): the checker's tests write their own actions and
# interlocks files for it, by hand, and plant faults in them; the stage's own are tested in test_schedule.
CHECK_STAGE = ["rig=twin", "schedule.network=null", "round.solution_limit=20", "round.reopt_rounds=2",
               "schedule.figures=false", "schedule.replay=false", "schedule.baselines=false", "runtime.progress=false",
               "schedule.interlocks=false", "round.clear_ends=false",
               "round.sweep_more_bands_m=[]", "round.postures=1"]  # the planner of the round whose R waits at
# park for L (its chosen postures need no wait: tests/test_execute.py plans with them)


@pytest.fixture(scope="session")
def small_twin_round(tmp_path_factory, make_cfg):
    """One small twin round (6 holes of the demo face), planned once for the checker's tests: its folder
    and the stage's settings as composed (``small_trajectory.csv``, ``small_round.csv``, ``small_round.json``)."""
    import pandas as pd

    from pipeline import demo_face, schedule

    tmp = tmp_path_factory.mktemp("check_round")
    demo_face.run(make_cfg(tmp))
    holes = pd.read_csv(tmp / "data" / "plans" / "demo_face.csv")
    plan = tmp / "small.csv"
    holes.iloc[::11].reset_index(drop=True).to_csv(plan, index=False)
    stage = [*CHECK_STAGE, f"plan={plan}"]
    schedule.run(make_cfg(tmp, *stage))
    return tmp, ["experiment=tiny", f"paths.data={tmp}/data", *stage]
