"""Runs that never lie: one test per defect of the reliability issue, each reproducing it first.

Concurrent trainings log their own models; SIGTERM ends a run KILLED; SIGKILL's leftovers are
marked KILLED by the next run; a failing sweep job gives a FAILED parent with a summary of the
others; NaN joints and bad settings are refused before any run exists; parallel first runs share
a fresh store; an interrupted or mixed hole set is detected; corrupt checkpoints are named.
"""

import json
import os
import shutil
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from mlflow.tracking import MlflowClient

from pipeline import generate, paper_baselines, train
from pipeline.core.config import PROJECT_ROOT
from pipeline.core.errors import ConfigError, Diverged, InputError
from pipeline.core.exit_codes import ExitCode
from pipeline.core.io import file_md5, write_json
from pipeline.data.hole_sets import read_hole_table
from pipeline.learning.models import load_checkpoint
from pipeline.tracking.runs import TrackingSettings, round_metric, stage_run

# the runs' bookkeeping is under test here, not what they learn: a few small steps, no MLflow model
SHORT = ["train.steps=20", "train.eval_every=10", "train.batch_size=64", "train.seeds=1", "runtime.log_model=false"]


def _env():
    env = dict(os.environ)
    env.pop("MLFLOW_TRACKING_URI", None)
    env["PYTHONUNBUFFERED"] = "1"
    return env


def _cli(tmp: Path, *args: str) -> list[str]:
    return [sys.executable, "-m", "pipeline.train", "experiment=tiny", *SHORT, f"paths.data={tmp}/data",
            f"tracking.uri=sqlite:///{tmp}/mlflow.db", f"tracking.artifact_root={tmp}/art",
            f"hydra.run.dir={tmp}/h/{time.monotonic_ns()}", *args]


def _client(tmp: Path):
    client = MlflowClient(f"sqlite:///{tmp}/mlflow.db")
    exp = client.get_experiment_by_name("boom-ik-tiny")
    return client, (client.search_runs([exp.experiment_id]) if exp else [])


def _wait_for_running_run(tmp: Path, proc, timeout=120) -> str:
    """The id of the process's RUNNING run, read with plain SQLite: an MlflowClient here would race
    the process on creating the fresh store, which is not what is under test."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()
        try:
            with sqlite3.connect(f"file:{tmp}/mlflow.db?mode=ro", uri=True) as db:
                rows = db.execute("select run_uuid from runs where status = 'RUNNING'").fetchall()
            if rows:
                return rows[0][0]
        except sqlite3.OperationalError:  # no file or no tables yet
            pass
        time.sleep(0.5)
    raise AssertionError("no RUNNING run appeared")


@pytest.fixture(scope="module")
def holes(tmp_path_factory, copy_tiny_study):
    """This module's copy of the tiny study (its holes, its CUIKM checkpoint), only read from."""
    return copy_tiny_study(tmp_path_factory.mktemp("rel"))


def _fresh(tmp_path, holes) -> Path:
    """A study folder with a copy of the hole set and its own (empty) MLflow store."""
    shutil.copytree(holes / "data" / "holes", tmp_path / "data" / "holes")
    return tmp_path


# ---------------------------------------------------------------------------------------- defect 1
@pytest.mark.slow
def test_concurrent_trainings_each_log_their_own_model(tmp_path, holes):
    tmp = _fresh(tmp_path, holes)
    # two seeds each (11, 12 and 21, 22): the seeds folder and the chosen set are published together
    procs = [subprocess.Popen(_cli(tmp, f"train.seed={seed}", "train.seeds=2", "train.steps=60"), env=_env(),
                              cwd=PROJECT_ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
             for seed in (11, 21)]
    for p in procs:
        out, _ = p.communicate(timeout=600)
        assert p.returncode == 0, out
    client, runs = _client(tmp)
    assert len(runs) == 4
    for run in runs:
        seed = run.data.tags["seed"]
        local = client.download_artifacts(run.info.run_id, f"cuikm_seed{seed}.pt", str(tmp / run.info.run_id))
        _, meta = load_checkpoint(local)
        assert meta["mlflow_run_id"] == run.info.run_id and str(meta["seed"]) == seed
        assert str(meta["config"]["train"]["seed"]) == run.data.params["train.seed"] == seed
        assert round_metric(meta["final"]["val_hole_mm"]) == run.data.metrics["summary/val_hole_mm"]
    # the published set belongs to one training: its chosen network, its summary and its seeds folder
    models = tmp / "data" / "models"
    _, meta = load_checkpoint(models / "cuikm.pt")
    final = json.loads((models / "cuikm_final.json").read_text())
    assert final["val_hole_mm"] == meta["final"]["val_hole_mm"] and final["seed"] == meta["seed"]
    in_folder = sorted(int(p.stem.removeprefix("cuikm_seed")) for p in (models / "cuikm_seeds").glob("*.pt"))
    assert in_folder == final["seeds"] and in_folder in ([11, 12], [21, 22]) and meta["seed"] in in_folder
    assert final["val_hole_mm"] == min(final["val_hole_mm_by_seed"])
    assert not list(models.glob(".cuikm*"))  # private folders and staging removed


# ---------------------------------------------------------------------------------------- defect 2
@pytest.mark.slow
def test_sigterm_ends_the_run_killed_and_leaves_no_partial_files(tmp_path, holes):
    tmp = _fresh(tmp_path, holes)
    proc = subprocess.Popen(_cli(tmp, "train.steps=1000000"), env=_env(), cwd=PROJECT_ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    run_id = _wait_for_running_run(tmp, proc)
    proc.send_signal(signal.SIGTERM)
    out, _ = proc.communicate(timeout=120)
    assert proc.returncode == ExitCode.TERMINATED == 143, out  # the table's code (tests/test_exit_codes.py)
    client, _ = _client(tmp)
    ended = client.get_run(run_id)
    assert ended.info.status == "KILLED"
    assert ended.data.tags["run.end_reason"] == "received SIGTERM"
    models = tmp / "data" / "models"
    assert not (models / "cuikm.pt").exists() and not list(models.glob(".*"))


@pytest.mark.slow
def test_a_sigkilled_run_is_marked_killed_by_the_next_run(tmp_path, holes):
    tmp = _fresh(tmp_path, holes)
    proc = subprocess.Popen(_cli(tmp, "train.steps=1000000"), env=_env(), cwd=PROJECT_ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    run_id = _wait_for_running_run(tmp, proc)
    proc.kill()
    proc.wait(timeout=60)
    client, _ = _client(tmp)
    assert client.get_run(run_id).info.status == "RUNNING"  # what SIGKILL leaves behind
    settings = TrackingSettings.from_config({"enabled": True, "uri": f"sqlite:///{tmp}/mlflow.db",
                                             "experiment": "boom-ik-tiny", "artifact_root": str(tmp / "art")})
    with stage_run(settings, "next", {"stage": "test"}):
        pass
    stale = client.get_run(run_id)
    assert stale.info.status == "KILLED"
    assert "ended without closing the run" in stale.data.tags["run.end_reason"]


@pytest.mark.slow
def test_a_failing_sweep_job_fails_the_parent_and_the_others_are_summarised(tmp_path, holes):
    tmp = _fresh(tmp_path, holes)
    sweep = tmp / "sweep"
    cmd = _cli(tmp, "method=cuikm", "method.mu=1,-1", "hydra/launcher=joblib", "hydra.launcher.n_jobs=2",
               f"hydra.sweep.dir={sweep}")
    cmd.insert(3, "-m")  # python -m pipeline.train -m ...
    done = subprocess.run(cmd, env=_env(), cwd=PROJECT_ROOT, capture_output=True, text=True, timeout=600)
    assert done.returncode != 0
    client, runs = _client(tmp)
    assert runs, done.stdout[-3000:] + done.stderr[-3000:]
    (parent,) = [r for r in runs if r.data.tags.get("stage") == "sweep"]
    assert parent.info.status == "FAILED" and parent.data.tags["run.end_reason"] == "1 job(s) failed"
    children = {r.data.tags["sweep.overrides"].split()[-1]: r for r in runs
                if r.data.tags.get("mlflow.parentRunId") == parent.info.run_id}
    assert children["method.mu=1"].info.status == "FINISHED"
    assert children["method.mu=-1"].info.status == "FAILED"
    assert "method.mu = -1.0" in children["method.mu=-1"].data.tags["run.end_reason"]
    summary = pd.read_csv(sweep / "summary.csv").set_index("overrides")
    assert summary.loc["method.mu=1", "status"] == "FINISHED" and summary.loc["method.mu=1", "pareto"]
    assert summary.loc["method.mu=-1", "status"] == "FAILED"
    assert (sweep / "tradeoff.png").stat().st_size > 5000
    assert {"sweep/summary.json", "sweep/tradeoff.png"} <= {a.path for a in
                                                           client.list_artifacts(parent.info.run_id, "sweep")}


# ---------------------------------------------------------------------------------------- defect 3
def test_a_nan_joint_in_the_supervised_set_is_refused_before_any_run(tmp_path, holes, make_cfg):
    tmp = tmp_path
    (tmp / "data" / "holes").mkdir(parents=True)
    src = holes / "data" / "holes"
    for f in src.iterdir():
        (tmp / "data" / "holes" / f.name).write_bytes(f.read_bytes())
    sup = pd.read_parquet(src / "sup.parquet")
    sup.loc[7, "q4"] = np.nan
    sup.to_parquet(tmp / "data" / "holes" / "sup.parquet", index=False)
    meta = json.loads((src / "meta.json").read_text())
    meta["files"]["sup.parquet"] = file_md5(tmp / "data" / "holes" / "sup.parquet")  # as if generate wrote it
    write_json(meta, tmp / "data" / "holes" / "meta.json")
    with pytest.raises(InputError, match=r"sup.parquet: column 'q4' has 1 non-finite .* row 7"):
        train.run(make_cfg(tmp, "method=sikm"))
    assert not (tmp / "mlflow.db").exists() or not _client(tmp)[1]


def test_json_is_strict_and_names_the_key(tmp_path):
    with pytest.raises(InputError, match=r"value at 'sikm.hole_mm_mean' is not finite"):
        write_json({"sikm": {"hole_mm_mean": float("nan")}}, tmp_path / "m.json")
    assert not (tmp_path / "m.json").exists()


def test_a_non_finite_loss_stops_training_and_names_the_step(safety):
    from pipeline.learning.models import build_model
    from pipeline.learning.training import Objective, fit

    pose = torch.zeros(8, 6)
    model = build_model(safety.boom, pose.mean(0), torch.ones(6), 8, 1, "gelu")
    batches = iter([(torch.full((8, 6), float("nan")), None)] * 3)
    with pytest.raises(Diverged, match=r"loss = nan at step 0"):  # the job could not finish: exit 3
        fit(model, safety.boom, safety, Objective(False, 1.0, 0.0, "norm"), batches, 3, 1e-3, pose)


# ---------------------------------------------------------------------------------------- defect 4
PROBE = """
import sys
from pipeline.tracking.runs import TrackingSettings, stage_run
s = TrackingSettings.from_config({"enabled": True, "uri": sys.argv[1], "experiment": "race",
                                  "artifact_root": sys.argv[2]})
with stage_run(s, "probe", {"stage": "probe"}) as run:
    run.log_metrics({"x": 1.0})
"""


def test_parallel_first_runs_on_a_fresh_store_do_not_race(tmp_path):
    uri = f"sqlite:///{tmp_path}/fresh.db"
    procs = [subprocess.Popen([sys.executable, "-c", PROBE, uri, str(tmp_path / "art")], env=_env(),
                              cwd=PROJECT_ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
             for _ in range(4)]
    outs = [p.communicate(timeout=300)[0] for p in procs]
    assert [p.returncode for p in procs] == [0] * 4, outs
    client = MlflowClient(uri)
    runs = client.search_runs([client.get_experiment_by_name("race").experiment_id])
    assert len(runs) == 4 and {r.info.status for r in runs} == {"FINISHED"}


# ---------------------------------------------------------------------------------------- defect 5
@pytest.mark.parametrize("override", ["train.steps=0", "train.steps=-5", "train.steps=nan", "train.eval_every=0",
                                      "train.lr=0", "train.lr=abc", "train.batch_size=0", "model.width=0"])
def test_bad_train_settings_fail_before_any_run_or_file(tmp_path, holes, make_cfg, override):
    tmp = _fresh(tmp_path, holes)
    with pytest.raises(ConfigError, match=override.split("=")[0].replace(".", r"\.")):
        train.run(make_cfg(tmp, override))
    assert not (tmp / "mlflow.db").exists()
    assert not (tmp / "data" / "models").exists()


def test_an_unwritable_data_folder_fails_before_training(tmp_path, holes, make_cfg):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    with pytest.raises(InputError, match=r"paths.data = .*file/models: cannot create the folder"):
        train.run(make_cfg(tmp_path, f"paths.data={blocker}"))


def test_an_unwritable_tracking_store_fails_at_once_with_the_setting_named(tmp_path, holes, make_cfg):
    tmp = _fresh(tmp_path, holes)
    (tmp / "file").write_text("not a folder")
    with pytest.raises(ConfigError, match=r"tracking.uri \(its folder\) = .*file/sub: cannot create the folder"):
        train.run(make_cfg(tmp, f"tracking.uri=sqlite:///{tmp}/file/sub/mlflow.db"))


def test_paper_baselines_checks_its_holes_before_the_swarms(tmp_path, make_cfg):
    with pytest.raises(InputError, match="test_group_1.parquet: no such hole table"):
        paper_baselines.run(make_cfg(tmp_path))
    assert not (tmp_path / "mlflow.db").exists()


# ---------------------------------------------------------------------------------------- defect 6
def test_corrupt_checkpoints_are_named_with_how_to_rebuild(tmp_path, holes):
    good = next((holes / "data").glob("models/*.pt"), None)
    truncated = tmp_path / "cuikm.pt"
    truncated.write_bytes(b"PK\x03\x04 not a whole file")
    rebuild = r"`python -m pipeline.train method=cuikm`"
    with pytest.raises(InputError, match=rf"cuikm.pt: not a readable checkpoint .*{rebuild}"):
        load_checkpoint(truncated)
    foreign = tmp_path / "uikm.pt"
    torch.save({"weights": torch.zeros(3)}, foreign)
    with pytest.raises(InputError, match=r"uikm.pt: not an IK network checkpoint \(missing \['state_dict'"):
        load_checkpoint(foreign)
    empty = tmp_path / "sikm.pt"
    empty.write_bytes(b"")
    with pytest.raises(InputError, match="sikm.pt: not a readable checkpoint"):
        load_checkpoint(empty)
    assert good is None or load_checkpoint(good)


@pytest.mark.slow
def test_a_hole_folder_mixing_two_generate_runs_is_detected(tmp_path, make_cfg):
    generate.run(make_cfg(tmp_path / "a"))
    generate.run(make_cfg(tmp_path / "b", "holes.unsup.seed=7"))
    a, b = tmp_path / "a" / "data" / "holes", tmp_path / "b" / "data" / "holes"
    read_hole_table(a, "train.parquet")
    (a / "train.parquet").write_bytes((b / "train.parquet").read_bytes())
    with pytest.raises(InputError, match=r"train.parquet: MD5 .* differs .*`python -m pipeline.generate`"):
        read_hole_table(a, "train.parquet")


@pytest.mark.slow
def test_an_interrupted_generate_leaves_the_old_set_whole(tmp_path, make_cfg, monkeypatch):
    generate.run(make_cfg(tmp_path))
    holes = tmp_path / "data" / "holes"
    before = {p.name: p.read_bytes() for p in holes.iterdir()}
    import pipeline.data.hole_sets as hole_sets

    calls = {"n": 0}
    real = hole_sets.write_parquet

    def dies_on_the_third_file(df, path):
        calls["n"] += 1
        if calls["n"] == 3:
            raise KeyboardInterrupt  # Ctrl-C mid-write
        real(df, path)

    monkeypatch.setattr(hole_sets, "write_parquet", dies_on_the_third_file)
    with pytest.raises(KeyboardInterrupt):
        generate.run(make_cfg(tmp_path, "holes.unsup.seed=9"))
    assert {p.name: p.read_bytes() for p in holes.iterdir()} == before
    assert not [p.name for p in (tmp_path / "data").iterdir() if p.name.startswith(".")]  # no staging folder left


def test_stale_runs_of_dead_processes_are_marked_killed_in_every_experiment(tmp_path):
    """A run left RUNNING by a killed process of another experiment (a quick study, a sweep) is ended too."""
    import socket

    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait(timeout=60)
    settings = TrackingSettings.from_config({"enabled": True, "uri": f"sqlite:///{tmp_path}/mlflow.db",
                                             "experiment": "boom-ik", "artifact_root": str(tmp_path / "art")})
    client = MlflowClient(settings.uri)
    other = client.create_experiment("boom-ik-quick", artifact_location=(tmp_path / "art").as_uri())
    left = client.create_run(other, tags={"host": socket.gethostname(), "pid": str(dead.pid), "pid_start": "1.0"})
    alive = client.create_run(other, tags={"host": socket.gethostname(), "pid": str(os.getpid())})
    with stage_run(settings, "next", {"stage": "test"}):
        pass
    assert client.get_run(left.info.run_id).info.status == "KILLED"
    assert "ended without closing the run" in client.get_run(left.info.run_id).data.tags["run.end_reason"]
    assert client.get_run(alive.info.run_id).info.status == "RUNNING"  # this process still lives


# --- the solution set and a busy store ---------------------------------------------

_HANGING_WRITER = """
import sys, time
from pathlib import Path
from pipeline.core.io import atomic_write, staged_folder
folder = Path(sys.argv[1])
with staged_folder(folder, "sol.csv") as stage:
    (stage / "sol.csv").write_text("half")
    def hang(tmp):
        Path(tmp).write_text("half")
        print("writing", flush=True)
        time.sleep(600)
    atomic_write(folder / "other.csv", hang)
"""


def test_temp_files_of_a_kill_9_are_removed_by_the_next_run_and_a_live_writers_are_kept(tmp_path):
    from pipeline.core.io import remove_stale_temps
    from pipeline.plans.output import SolutionPaths, read_solution_set, write_solution_set

    procs = [subprocess.Popen([sys.executable, "-c", _HANGING_WRITER, str(tmp_path)], cwd=PROJECT_ROOT,
                              stdout=subprocess.PIPE, text=True, env=_env()) for _ in range(2)]
    for p in procs:
        assert p.stdout.readline().strip() == "writing"
    procs[0].send_signal(signal.SIGKILL)
    procs[0].wait(timeout=60)
    left = sorted(p.name for p in tmp_path.iterdir())
    assert len(left) == 4 and all(n.endswith(".tmp") for n in left)  # a stage folder and a temp file each
    out = tmp_path / "sol.csv"
    paths = SolutionPaths(out, out.with_suffix(".json"), out.with_suffix(".png"))
    write_solution_set(paths, pd.DataFrame({"hole_id": ["A"], "status": ["ok"]}), {"ok": 1})
    kept = sorted(p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp"))
    assert kept == sorted(n for n in left if f".{procs[1].pid}-" in n)  # the dead writer's gone, the live one kept
    assert read_solution_set(out)[1]["ok"] == 1
    procs[1].kill()
    procs[1].wait(timeout=60)
    assert len(remove_stale_temps(tmp_path)) == 2 and not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


_SET_WRITER = """
import sys
import pandas as pd
from pathlib import Path
from pipeline.plans.output import SolutionPaths, write_solution_set
out, tag = Path(sys.argv[1]), sys.argv[2]
paths = SolutionPaths(out, out.with_suffix(".json"), out.with_suffix(".png"))
for i in range(15):
    table = pd.DataFrame({"hole_id": [f"{tag}{i}-{k}" for k in range(2000)], "status": "ok"})
    write_solution_set(paths, table, {"writer": tag, "round": i})
"""


def test_two_solves_into_one_out_never_leave_a_mixed_set(tmp_path):
    """Two writers publish sets into one out= while this process reads them under the lock: every
    read is one writer's table with that writer's summary."""
    from pipeline.plans.output import read_solution_set

    out = tmp_path / "sol.csv"
    writers = [subprocess.Popen([sys.executable, "-c", _SET_WRITER, str(out), tag], cwd=PROJECT_ROOT, env=_env())
               for tag in ("a", "b")]
    reads = 0
    while any(w.poll() is None for w in writers):
        if out.with_suffix(".json").exists():
            table, summary = read_solution_set(out)
            assert table["hole_id"][0] == f"{summary['writer']}{summary['round']}-0" and len(table) == 2000
            reads += 1
    assert all(w.returncode == 0 for w in writers) and reads > 0
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


def test_a_store_locked_by_another_process_gets_a_named_wait_then_a_clear_error(tmp_path):
    """A second run waiting on another process's SQLite write lock (a paused solve) waits
    tracking.busy_timeout_s, then fails naming tracking.uri (before: a raw OperationalError after ~25 s).
    The wait is the setting's, not MLflow's fixed 20 s: the project's own wait for the write lock fails it
    (the message says so), and a lock released during a longer wait lets the run start."""
    import threading

    from pipeline.tracking.runs import StoreBusy

    node = {"enabled": True, "uri": f"sqlite:///{tmp_path}/mlflow.db", "experiment": "boom-ik",
            "artifact_root": str(tmp_path / "art"), "busy_timeout_s": 1}
    settings = TrackingSettings.from_config(node)
    with stage_run(settings, "first", {"stage": "test"}):  # the store exists
        pass
    holder = sqlite3.connect(tmp_path / "mlflow.db", timeout=0, isolation_level=None, check_same_thread=False)
    holder.execute("BEGIN IMMEDIATE")  # the write lock, held as a paused writer holds it
    start = time.monotonic()
    try:
        with pytest.raises(StoreBusy, match=rf"tracking.uri = sqlite:///{tmp_path}/mlflow.db: the MLflow store "
                                            r"stayed locked by another process .* while waiting for its write "
                                            r"lock \(tracking.busy_timeout_s = 1\)"):
            with stage_run(settings, "second", {"stage": "test"}):
                pass
    finally:
        holder.execute("ROLLBACK")
    assert time.monotonic() - start < 90
    holder.execute("BEGIN IMMEDIATE")
    threading.Timer(1.0, holder.execute, ["ROLLBACK"]).start()  # the other writer finishes during the wait
    with stage_run(TrackingSettings.from_config({**node, "busy_timeout_s": 60}), "third", {"stage": "test"}):
        pass
    holder.close()
    runs = MlflowClient(settings.uri).search_runs(
        [MlflowClient(settings.uri).get_experiment_by_name("boom-ik").experiment_id])
    assert sorted(r.info.run_name for r in runs) == ["first", "third"]
    with pytest.raises(ConfigError,
                       match=r"tracking.busy_timeout_s = -1: expected a number of seconds in \[0, 86400\]"):
        TrackingSettings.from_config({**node, "busy_timeout_s": -1})


def test_a_signal_while_waiting_on_the_store_exits_with_its_status_and_starts_no_run(tmp_path):
    """SIGTERM while a stage waits for another process's write lock: exit status 128 + 15 (as during the
    run), not a ``Terminated`` traceback with status 1, and no run left behind."""
    import threading

    from pipeline.core import signals

    node = {"enabled": True, "uri": f"sqlite:///{tmp_path}/mlflow.db", "experiment": "boom-ik",
            "artifact_root": str(tmp_path / "art"), "busy_timeout_s": 60}
    settings = TrackingSettings.from_config(node)
    with stage_run(settings, "first", {"stage": "test"}):
        pass
    holder = sqlite3.connect(tmp_path / "mlflow.db", timeout=0, isolation_level=None, check_same_thread=False)
    holder.execute("BEGIN IMMEDIATE")

    def terminate_once_handled():  # only once stage_run handles SIGTERM: the default would end pytest
        deadline = time.monotonic() + 30
        while signal.getsignal(signal.SIGTERM) is not signals._handler and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.5)  # into the wait
        os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=terminate_once_handled, daemon=True).start()
    start = time.monotonic()
    try:
        with pytest.raises(SystemExit) as ended:
            with stage_run(settings, "second", {"stage": "test"}):
                pass
    finally:
        holder.execute("ROLLBACK")
        holder.close()
    assert ended.value.code == 128 + signal.SIGTERM and time.monotonic() - start < 30
    runs = MlflowClient(settings.uri).search_runs(
        [MlflowClient(settings.uri).get_experiment_by_name("boom-ik").experiment_id])
    assert [r.info.run_name for r in runs] == ["first"]


def test_a_swallowed_signal_stops_a_set_before_it_is_published(tmp_path):
    """A SIGTERM whose exception a library swallowed (OR-Tools runs Python callbacks inside its solve) is
    still pending when the set is published: nothing is renamed, the previous output stays."""
    from pipeline.core import signals
    from pipeline.core.io import publish

    new, out = tmp_path / "new.csv", tmp_path / "out.csv"
    new.write_text("new set\n")
    out.write_text("the previous set\n")
    signals._pending = signal.SIGTERM
    try:
        with pytest.raises(signals.Terminated):
            publish({new: out}, tmp_path / "out.lock")
    finally:
        signals._pending = None
    assert out.read_text() == "the previous set\n" and new.read_text() == "new set\n"
    publish({new: out}, tmp_path / "out.lock")  # no signal pending: published
    assert out.read_text() == "new set\n"


def test_one_destination_has_one_publish_lock_however_it_is_spelled(tmp_path, monkeypatch):
    """train and distill publish into a models folder under :func:`publish_lock`: the same folder, named
    relative, absolute or through a link, gets the same lock; another folder or name another; never a file
    among the outputs."""
    from pipeline.core.io import publish_lock

    models, other = tmp_path / "models", tmp_path / "other"
    models.mkdir()
    other.mkdir()
    (tmp_path / "link").symlink_to(models)
    monkeypatch.chdir(tmp_path)
    spellings = {publish_lock(p, "cuikm") for p in (models, Path("models"), Path("link"), Path("./models/../models"))}
    assert len(spellings) == 1
    (lock,) = spellings
    assert lock != publish_lock(other, "cuikm") and lock != publish_lock(models, "uikm")
    assert not lock.resolve().is_relative_to(models.resolve())


@pytest.mark.parametrize("enabled", [True, False], ids=["tracking", "no-tracking"])
def test_a_signal_that_comes_back_wrapped_still_ends_the_run_killed(tmp_path, enabled):
    """A signal that lands inside a native library's callback comes back wrapped: numba, loading a kernel
    from its cache, re-raises the handler's exception as ``SystemError``. The stage still exits 128 +
    signum and its run ends KILLED, not FAILED (once seen in CI: SIGINT during a schedule stage's first
    compiled call)."""
    node = {"enabled": enabled, "uri": f"sqlite:///{tmp_path}/mlflow.db", "experiment": "boom-ik",
            "artifact_root": str(tmp_path / "art")}
    settings = TrackingSettings.from_config(node)
    with pytest.raises(SystemExit) as ended:
        with stage_run(settings, "wrapped", {"stage": "test"}):
            try:
                os.kill(os.getpid(), signal.SIGINT)  # the handler raises Terminated here
                time.sleep(1.0)
            except KeyboardInterrupt as exc:
                raise SystemError("returned a result with an exception set") from exc  # as numba does
    assert ended.value.code == 128 + signal.SIGINT
    if enabled:
        (run,) = MlflowClient(settings.uri).search_runs(
            [MlflowClient(settings.uri).get_experiment_by_name("boom-ik").experiment_id])
        assert run.info.status == "KILLED" and run.data.tags["run.end_reason"].startswith("received SIGINT")
