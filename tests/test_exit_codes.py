"""Exit codes, one meaning each (pipeline/core/exit_codes.py, docs/usage.md "Exit codes"): the table, the
checker's numbers held to it, every stage's main going through the one wrapper, and each code from a real
stage run as a user runs it (``python -m pipeline.<stage>``), with the outputs it must (not) leave.

SIGTERM during a training (143, the run KILLED, no partial files) is tests/test_reliability.py's; here the
signals reach a stage waiting on a locked MLflow store, the cheapest place a stage is sure to be inside
its run."""

import importlib.util
import os
import re
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
from hydra.errors import ConfigCompositionException, MissingConfigException, OverrideParseException

from pipeline.core.config import PROJECT_ROOT
from pipeline.core.errors import ConfigError, Deadlock, Diverged, InputError, JobFailed, NoRoutes, StrictCheckFailed
from pipeline.core.exit_codes import ExitCode, exit_code, for_signal
from pipeline.core.signals import Terminated
from pipeline.core.stage import run_stage


def _env(**extra: str) -> dict:
    env = dict(os.environ)
    env.pop("MLFLOW_TRACKING_URI", None)
    env.pop("HYDRA_FULL_ERROR", None)
    env["PYTHONUNBUFFERED"] = "1"
    return {**env, **extra}


def _stage(tmp: Path, stage: str, *overrides: str) -> list[str]:
    """The command line of a tiny-experiment stage whose every file lands under ``tmp``."""
    return [sys.executable, "-m", f"pipeline.{stage}", "experiment=tiny", f"paths.data={tmp}/data",
            f"tracking.uri=sqlite:///{tmp}/mlflow.db", f"tracking.artifact_root={tmp}/art",
            f"hydra.run.dir={tmp}/hydra", "runtime.threads=1", *overrides]


def _run(cmd: list[str], **env: str) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, cwd=PROJECT_ROOT, env=_env(**env), capture_output=True, text=True, timeout=300)


def _files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.rglob("*") if p.is_file()) if folder.exists() else []


# ---------------------------------------------------------------------------------------------- the table
def test_the_table_has_one_code_per_meaning():
    assert {c.name: int(c) for c in ExitCode} == {"DONE": 0, "CHECK_FAILED": 1, "BAD_INPUT": 2, "JOB_FAILED": 3,
                                                 "INTERRUPTED": 130, "TERMINATED": 143}
    assert for_signal(signal.SIGINT) == ExitCode.INTERRUPTED and for_signal(signal.SIGTERM) == ExitCode.TERMINATED


def test_each_error_maps_to_its_code():
    from pipeline.execute import CheckerFailed
    from pipeline.round.routing import RoutingFailed
    from pipeline.tracking.runs import StoreBusy

    expected = {
        ExitCode.CHECK_FAILED: [StrictCheckFailed("strict: 1 of 3 holes are not ok")],
        ExitCode.BAD_INPUT: [ConfigError("strict = 'maybe'"), InputError("plan.csv: row 3"),
                             ConfigCompositionException("Could not override 'strictt'"),
                             MissingConfigException("no boom jumbo9", "boom/jumbo9"),
                             OverrideParseException("solve=[", "no viable alternative at input '['")],
        ExitCode.JOB_FAILED: [JobFailed("x"), NoRoutes("x"), RoutingFailed("x"), Deadlock("x"), Diverged("x"),
                              StoreBusy("x"), CheckerFailed("x"), RuntimeError("a fault of the stage")],
        ExitCode.INTERRUPTED: [Terminated(signal.SIGINT), KeyboardInterrupt()],
        ExitCode.TERMINATED: [Terminated(signal.SIGTERM)],
    }
    got = {code: [exit_code(e) for e in errors] for code, errors in expected.items()}
    assert got == {code: [code] * len(errors) for code, errors in expected.items()}
    # a job that failed is not a bad setting: code that catches ConfigError / ValueError does not swallow it
    assert not any(issubclass(c, ValueError) for c in (JobFailed, RoutingFailed, StoreBusy, CheckerFailed))


def test_the_checker_keeps_the_same_numbers():
    """The independent checker imports nothing of pipeline: its own constants, held to the table here."""
    spec = importlib.util.spec_from_file_location("check_round_exit_codes", PROJECT_ROOT / "scripts/check_round.py")
    spec.loader.exec_module(importlib.util.module_from_spec(spec))
    cli = sys.modules["round_check.cli"]
    assert (cli.EXIT_CLEAN, cli.EXIT_VIOLATIONS, cli.EXIT_INPUT, cli.EXIT_INTERNAL) == (
        ExitCode.DONE, ExitCode.CHECK_FAILED, ExitCode.BAD_INPUT, ExitCode.JOB_FAILED)
    source = (PROJECT_ROOT / "scripts/round_check/cli.py").read_text()
    assert not re.findall(r"(?:return|SystemExit\()\s*\d", source)  # no bare number left


def test_every_stage_runs_through_stage_main_and_run_stage():
    """One place maps Hydra's own errors and the stages' errors to codes: no stage calls hydra.main itself,
    and none exits with a number of its own."""
    stages = [p for p in sorted((PROJECT_ROOT / "pipeline").glob("*.py")) if "run_stage(" in p.read_text()]
    assert len(stages) >= 19
    for path in stages:
        text = path.read_text()
        assert "@stage_main\ndef main(" in text and "hydra.main" not in text, path.name
        assert not re.findall(r"SystemExit\(|sys\.exit\(", text), path.name


@pytest.mark.parametrize("error, code, said", [
    (StrictCheckFailed("strict: 1 of 3 holes are not ok (see out.csv)"), 1, "strict: 1 of 3 holes are not ok"),
    (ConfigError("strict = 'maybe': expected true or false"), 2, "error: strict = 'maybe'"),
    (Diverged("training diverged: loss = nan at step 1"), 3, "error: training diverged: loss = nan at step 1"),
])
def test_run_stage_ends_a_single_run_with_the_code_and_one_line(make_cfg, tmp_path, capsys, error, code, said):
    def run(cfg):
        raise error

    with pytest.raises(SystemExit) as ended:
        run_stage(make_cfg(tmp_path), run, threads=None)
    err = capsys.readouterr().err
    assert ended.value.code == code and said in err and "Traceback" not in err, err


# ------------------------------------------------------------------- real stages, as a user runs them
@pytest.mark.slow
@pytest.mark.parametrize("override, said, env", [
    ("strictt=true", "Could not override 'strictt'", {}),  # a mistyped setting name: Hydra's own error
    ("strictt=true", "Could not override 'strictt'", {"HYDRA_FULL_ERROR": "1"}),  # Hydra raises instead
    ("boom=jumbo9", ("Could not find 'boom/jumbo9'", "jumbo8"), {}),  # an unknown option of a group, the known named
    ("strict=maybe", "error: strict = 'maybe': expected true or false", {}),  # a bad value: the stage's check
])
def test_bad_settings_exit_2_naming_them_and_write_nothing(tmp_path, override, said, env):
    done = _run(_stage(tmp_path, "solve", "tracking.enabled=false", override), **env)
    assert done.returncode == ExitCode.BAD_INPUT, done.stderr[-3000:]
    for part in (said,) if isinstance(said, str) else said:
        assert part in done.stderr, done.stderr[-3000:]
    assert _files(tmp_path / "data") == [] and not (tmp_path / "mlflow.db").exists()


PLAN = pd.DataFrame({"hole_id": ["001", "002", "010", "9"],
                     "collar_x": [6.5, 6.5, 6.5, 6.5], "collar_y": [0.0, 1.0, -1.0, 0.5],
                     "collar_z": [1.5, 2.0, 2.5, 3.0], "toe_x": [10.0, 10.0, 10.0, 10.0],
                     "toe_y": [0.0, 1.0, -1.0, 0.5], "toe_z": [1.5, 2.0, 2.5, 3.0]})


@pytest.mark.slow
def test_a_strict_check_that_fails_exits_1_after_writing_the_result(tmp_path):
    """quality strict=true on a log with one hole 0.15 m off: exit 1, the message, the set written."""
    from pipeline.plans.drpqual import LOG_COLUMNS, write_quality_log
    from pipeline.plans.model import COORDS

    plan, log_path = tmp_path / "round.csv", tmp_path / "round_qual.xml"
    PLAN.to_csv(plan, index=False)
    drilled = PLAN[["hole_id"]].assign(hole_name=PLAN["hole_id"], boom="L", status="Drilled",
                                       start_time="2026-01-01T07:00:00", end_time="2026-01-01T07:02:00")
    shift = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.15], [0.0, 0.0, 0.0]])
    drilled[COORDS] = PLAN[COORDS].to_numpy() + np.concatenate([shift, shift], axis=1)
    write_quality_log(drilled[LOG_COLUMNS], log_path, plan_id="round", plan_name="round",
                      created="2026-01-01T07:00:00")
    cmd = _stage(tmp_path, "quality", f"plan={plan}", f"log={log_path}", "tracking.enabled=false",
                 "quality.figure=false")
    done = _run(cmd)
    assert done.returncode == 0, done.stderr[-3000:]  # the same run without strict: done
    done = _run([*cmd, "strict=true"])
    assert done.returncode == ExitCode.CHECK_FAILED, done.stderr[-3000:]
    assert "strict: 1 of 4 holes not drilled within tolerance" in done.stderr and "Traceback" not in done.stderr
    table = pd.read_csv(tmp_path / "round_quality.csv", dtype={"hole_id": str})
    assert table["within"].tolist() == [True, True, False, True]


def _hold_the_store(tmp: Path) -> sqlite3.Connection:
    """The store's write lock, held as another process's long write holds it."""
    holder = sqlite3.connect(tmp / "mlflow.db", timeout=0, isolation_level=None, check_same_thread=False)
    holder.execute("BEGIN IMMEDIATE")
    return holder


@pytest.mark.slow
def test_a_store_locked_past_its_timeout_exits_3_and_writes_nothing(tmp_path):
    holder = _hold_the_store(tmp_path)
    try:
        done = _run(_stage(tmp_path, "generate", "tracking.busy_timeout_s=1"))
    finally:
        holder.execute("ROLLBACK")
        holder.close()
    assert done.returncode == ExitCode.JOB_FAILED, done.stderr[-3000:]
    assert re.search(r"error: tracking.uri = sqlite:///.*mlflow.db: the MLflow store stayed locked by another "
                     r"process .* \(tracking.busy_timeout_s = 1\)", done.stderr), done.stderr[-3000:]
    assert "Traceback" not in done.stderr and _files(tmp_path / "data") == []


@pytest.fixture(scope="module")
def holes(tmp_path_factory, make_cfg):
    """The tiny experiment's hole sets (no MLflow), for trainings of a few steps."""
    from pipeline import generate

    tmp = tmp_path_factory.mktemp("exit_holes")
    generate.run(make_cfg(tmp, "tracking.enabled=false"))
    return tmp


@pytest.mark.slow
def test_a_training_that_diverges_exits_3_and_publishes_no_model(holes, tmp_path):
    shutil.copytree(holes / "data" / "holes", tmp_path / "data" / "holes")
    cmd = _stage(tmp_path, "train", "tracking.enabled=false", "train.steps=20", "train.eval_every=10",
                 "train.batch_size=64", "runtime.log_model=false", "runtime.progress=false")
    done = _run([*cmd, "train.lr=1e30"])  # the first step's update makes the loss NaN
    assert done.returncode == ExitCode.JOB_FAILED, done.stderr[-3000:]
    assert re.search(r"error: training diverged: loss = nan at step \d+ .*train.lr = 1e\+30", done.stderr), \
        done.stderr[-3000:]
    assert "Traceback" not in done.stderr and _files(tmp_path / "data" / "models") == []


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_exits_128_plus_its_number_and_writes_nothing(tmp_path, signum):
    """SIGTERM (143) or SIGINT (130) while the stage waits on a locked store, inside its run."""
    holder = _hold_the_store(tmp_path)
    proc = subprocess.Popen(_stage(tmp_path, "generate", "tracking.busy_timeout_s=120"), cwd=PROJECT_ROOT,
                            env=_env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        said, deadline = [], time.monotonic() + 240
        while time.monotonic() < deadline:
            line = proc.stdout.readline()
            said.append(line)
            if not line or "is locked by another process; waiting" in line:
                break
        assert proc.poll() is None, "".join(said)
        proc.send_signal(signum)
        out, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
        holder.execute("ROLLBACK")
        holder.close()
    assert proc.returncode == for_signal(signum), "".join(said) + out
    assert proc.returncode == {signal.SIGTERM: 143, signal.SIGINT: 130}[signum]
    assert "Traceback" not in out and _files(tmp_path / "data") == []
