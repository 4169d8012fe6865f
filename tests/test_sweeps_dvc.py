"""Hydra multirun sweeps into MLflow, and DVC reproducible reruns."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import yaml
from mlflow.tracking import MlflowClient

from pipeline.core.config import PROJECT_ROOT, load_group_file
from pipeline.evaluation.pareto import pareto_front, summary_table
from pipeline.params import composed_yaml

# the sweeps' bookkeeping is under test, not what the jobs learn: a few steps, no MLflow model
SHORT = ["experiment=tiny", "train.steps=20", "train.eval_every=10", "train.seeds=1", "runtime.log_model=false"]


def _env():
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env.pop("MLFLOW_TRACKING_URI", None)
    env["DVC_NO_ANALYTICS"] = "1"  # each dvc command would otherwise start a detached process that posts its usage
    return env


def _run(args, cwd=PROJECT_ROOT, timeout=600):
    done = subprocess.run(args, cwd=cwd, capture_output=True, text=True, timeout=timeout, env=_env())
    assert done.returncode == 0, f"{args}\n{done.stdout[-3000:]}\n{done.stderr[-5000:]}"
    return done


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory, copy_tiny_study):
    """This module's copy of the tiny study; each sweep writes its own folder and store in it."""
    return copy_tiny_study(tmp_path_factory.mktemp("sweep"))


def _sweep(tmp, name, *extra):
    args = [sys.executable, "-m", "pipeline.train", "-m", *SHORT, f"paths.data={tmp}/data",
            f"tracking.uri=sqlite:///{tmp}/{name}.db", f"tracking.artifact_root={tmp}/{name}-art",
            f"hydra.sweep.dir={tmp}/{name}", "method=cuikm", "method.mu=1,10", *extra]
    done = _run(args)
    client = MlflowClient(f"sqlite:///{tmp}/{name}.db")
    exp = client.get_experiment_by_name("boom-ik-tiny")
    runs = client.search_runs([exp.experiment_id])
    return done, client, runs


def _check_parent_and_children(client, runs, tmp, name):
    parents = [r for r in runs if r.data.tags.get("stage") == "sweep"]
    assert len(parents) == 1
    parent = parents[0]
    children = [r for r in runs if r.data.tags.get("mlflow.parentRunId") == parent.info.run_id]
    assert len(children) == 2 and all(c.info.status == "FINISHED" for c in children)
    assert sorted(c.data.tags["sweep.overrides"].split()[-1] for c in children) == ["method.mu=1", "method.mu=10"]
    assert parent.data.metrics["jobs_finished"] == 2
    arts = {a.path for a in client.list_artifacts(parent.info.run_id, "sweep")}
    assert {"sweep/summary.json", "sweep/tradeoff.png"} <= arts
    summary = pd.read_csv(tmp / name / "summary.csv")
    assert sorted(summary["overrides"]) == ["method.mu=1", "method.mu=10"]
    assert summary["pareto"].any()
    # each job kept its own model
    assert (tmp / name / "0" / "cuikm.pt").is_file() and (tmp / name / "1" / "cuikm.pt").is_file()


@pytest.mark.slow
def test_two_job_multirun_makes_one_parent_with_two_children(tiny_data):
    _, client, runs = _sweep(tiny_data, "basic")
    _check_parent_and_children(client, runs, tiny_data, "basic")


@pytest.mark.slow
def test_joblib_launcher_runs_jobs_in_parallel_without_losing_runs(tiny_data):
    done, client, runs = _sweep(tiny_data, "joblib", "hydra/launcher=joblib", "hydra.launcher.n_jobs=2")
    _check_parent_and_children(client, runs, tiny_data, "joblib")
    a, b = [r for r in runs if r.data.tags.get("stage") == "train"]
    assert a.data.tags["pid"] != b.data.tags["pid"]  # two worker processes
    assert a.info.start_time < b.info.end_time and b.info.start_time < a.info.end_time  # that overlapped in time


@pytest.mark.slow
def test_sweep_without_mlflow_still_summarises(tiny_data):
    args = [sys.executable, "-m", "pipeline.train", "-m", *SHORT, f"paths.data={tiny_data}/data",
            "tracking.enabled=false", f"hydra.sweep.dir={tiny_data}/plain", "method=cuikm", "method.mu=1,10"]
    _run(args)
    assert len(pd.read_csv(tiny_data / "plain" / "summary.csv")) == 2


def test_pareto_front_and_labels():
    runs = pd.DataFrame({
        "run_id": list("abcd"), "status": ["FINISHED"] * 4,
        "tags.sweep.overrides": [f"experiment=quick method.mu={m}" for m in (0.1, 1, 10, 100)],
        "metrics.summary/val_hole_mm": [3.0, 3.5, 4.0, 6.0],
        "metrics.summary/val_collision_rate": [0.2, 0.01, 0.01, 0.0],
    })
    table = summary_table(runs)
    assert list(table["overrides"]) == ["method.mu=0.1", "method.mu=1", "method.mu=10", "method.mu=100"]
    assert list(table["pareto"]) == [True, True, False, True]  # mu=10 is beaten by mu=1
    assert list(pareto_front(pd.Series([1.0, 1.0]).to_numpy(), pd.Series([0.0, 0.0]).to_numpy())) == [True, True]


def test_committed_params_yaml_is_the_composition_of_conf():
    committed = (PROJECT_ROOT / "params.yaml").read_text()
    assert committed == composed_yaml(), "params.yaml is stale: run python -m pipeline.params"


def _copy_checkout(dst: Path) -> None:
    files = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard"], cwd=PROJECT_ROOT,
                           capture_output=True, text=True, check=True).stdout.split()
    for rel in files:
        if (PROJECT_ROOT / rel).is_file():
            (dst / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(PROJECT_ROOT / rel, dst / rel)
    # numba's compiled kernels (scripts/warm_kernels.py) and Python's bytecode, beside their sources: numba keys its
    # cache on each source's modification time and size, which copy2 keeps, so the copy's stages load the kernels
    # instead of compiling about 30 of them again (10-20 s of this test's stages). A stale entry is compiled anew.
    for cached in (PROJECT_ROOT / "pipeline").rglob("__pycache__/*"):
        to = dst / cached.relative_to(PROJECT_ROOT)
        if cached.suffix in (".nbi", ".nbc", ".pyc") and to.parent.parent.is_dir():  # its package was copied
            to.parent.mkdir(exist_ok=True)
            shutil.copy2(cached, to)
    subprocess.run(["git", "init", "-q"], cwd=dst, check=True)


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("git") is None, reason="DVC needs git")
def test_dvc_repro_of_the_quick_experiment_then_up_to_date_and_a_param_change_reruns_the_right_stages(tmp_path):
    """The tiny experiment (its own paths.data=data/tiny), every stage, MLflow on, in a copy of the checkout."""
    _copy_checkout(tmp_path)
    # DVC's bookkeeping is under test here, not the round's quality: the schedule stage keeps the best of
    # its seeds (no OR-Tools solve) and times no baselines. That cuts the stage from about 125 s to 33 s;
    # the routing and the baselines run in tests/test_round.py and tests/test_schedule.py. One torch thread
    # per stage (train too), as the other test worker runs beside it (2 cores): with two, the schedule
    # stage's seed sweep took 38 s in CI against 8 s alone; with one, this test took 350 s against 401 s.
    # Also fewer execution draws, no torch.compile row and no per-runtime processes in the export benchmark
    # (each is tested in its own stage's tests): the first repro took 537 s without these (16 stages, about
    # 10 s of each only starting Python, torch and MLflow), 594 s for the test in CI. Likewise the round's
    # extra seed bands and its posture plannings, and the benchmark's population methods (tested in
    # tests/test_schedule.py, tests/test_postures.py and tests/test_solvers.py): the first repro of 17
    # stages, alone on 2 cores, took 188 s with them (schedule 31 s, benchmark 23 s). And a tenth of OMPL's
    # iterations per detour search: the round planned on the tiny loop's calibrated model has moves nothing
    # makes clear, and each of their searches ran all 5 000 (loop_after's planning: 74 s, 12 s with 500, the
    # same round; detours are tested in tests/test_detours.py).
    sweeps = load_group_file("sweeps", "default")
    assert "mu-1" in sweeps["jobs"] and "mu" in sweeps["tables"]
    compose = [sys.executable, "-m", "pipeline.params", *SHORT, "round.routing=false", "schedule.baselines=false",
               "round.detour_iterations=500",
               "runtime.threads=1", "runtime.train_threads=1", "draws.count=20", "export.benchmark.compile=false",
               "export.benchmark.isolate=false", "round.sweep_more_bands_m=[]", "round.postures=1",
               "solver_benchmark.methods=[cuikm,uikm,sikm,sikm_best,cuikm_start,hybrid,nm]",
               "train.seeds=2",  # the study's seeded path: <method>_seeds, each seed evaluated, the report's spread
               # the sweeps' pipeline (sweeps/dvc.yaml) at its smallest: one job, mu = 1, and the mu table (every
               # other job and table of conf/sweeps/default.yaml removed, those added later too)
               *[f"~sweeps.jobs.{job}" for job in sweeps["jobs"] if job != "mu-1"],
               *[f"~sweeps.tables.{table}" for table in sweeps["tables"] if table != "mu"]]
    _run(compose, cwd=tmp_path)
    dvc = [sys.executable, "-m", "dvc"]
    _run([*dvc, "repro"], cwd=tmp_path, timeout=1500)  # a guard against a hang, not a speed test
    d = "data/tiny"
    for out in ["holes/train.parquet", "models/sikm.pt", "models/cuikm.pt", "eval/metrics.json",
                "eval/collisions.csv", "report/README.md"]:
        assert (tmp_path / d / out).is_file(), out
    metrics = json.loads((tmp_path / d / "eval/metrics.json").read_text())
    assert set(metrics) == {"sikm", "sikm_best", "uikm", "cuikm"}
    seeds = pd.read_csv(tmp_path / d / "report/seeds.csv")
    assert list(seeds.columns) == ["method", "seed", "kept", "mean_mm", "collision_rate_pct"]
    assert sorted(zip(seeds["method"], seeds["seed"], strict=True)) == sorted((m, k) for m in metrics for k in (0, 1))
    assert all(metrics[m]["seeds"] == 2 for m in metrics) and seeds["kept"].sum() == 4
    for m in metrics:
        assert (tmp_path / d / "eval/predictions" / f"{m}_seed1_group5.parquet").is_file()
    outs = {p: (tmp_path / d / p).stat().st_mtime_ns for p in ["holes/meta.json", "models/sikm.pt", "models/uikm.pt",
                                                             "models/cuikm.pt", "eval/metrics.json",
                                                             "report/README.md"]}
    # the sweeps: the job trains into its own folder, the table scores it beside the study's CUIKM (the reference);
    # DVC walks their upstream, generate and train@cuikm, and rebuilds nothing of the study
    _run([*dvc, "repro", "sweeps/dvc.yaml"], cwd=tmp_path)
    assert {p: (tmp_path / d / p).stat().st_mtime_ns for p in outs} == outs
    jobs = pd.read_csv(tmp_path / d / "sweeps/mu/jobs.csv")
    assert sorted(zip(jobs["job"], jobs["seed"], jobs["method.mu"], strict=True)) == [
        ("mu-1", 0, 1), ("mu-1", 1, 1), ("reference", 0, 10), ("reference", 1, 10)]
    assert (tmp_path / d / "sweeps/mu/jobs/mu-1/cuikm_seeds/cuikm_seed1.pt").is_file()
    status = _run([*dvc, "status", "--json"], cwd=tmp_path)  # both pipelines up to date: a repro would run nothing
    assert json.loads(status.stdout) == {}
    _check_dataset_digests_are_dvc_hashes(tmp_path, d)

    params = yaml.safe_load((tmp_path / "params.yaml").read_text())
    params["baselines"]["uikm"]["lam"] = 2.0
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    status = json.loads(_run([*dvc, "status", "--json"], cwd=tmp_path).stdout)
    assert set(status) == {"train@uikm"}
    _run([*dvc, "repro"], cwd=tmp_path)
    changed = {p for p in outs if (tmp_path / d / p).stat().st_mtime_ns != outs[p]}
    assert changed == {"models/uikm.pt", "eval/metrics.json", "report/README.md"}

    # a conf file edited by hand, then params.yaml composed again (README): the stages that time motion, and
    # no other, are named, each for that one setting
    motion = tmp_path / "conf" / "motion" / "jumbo8.yaml"
    text = motion.read_text()
    assert "  q1: 15\n" in text
    motion.write_text(text.replace("  q1: 15\n", "  q1: 7.5\n"))
    _run([*compose, "baselines.uikm.lam=2.0"], cwd=tmp_path)  # the uikm change above, as a setting this time
    status = json.loads(_run([*dvc, "status", "--json"], cwd=tmp_path).stdout)
    stages = yaml.safe_load((tmp_path / "dvc.yaml").read_text())["stages"]
    timing = {name for name, st in stages.items() if "motion" in (st.get("params") or [])}
    assert "schedule" in timing and set(status) == timing, status
    for name in timing:  # each for its motion params alone
        assert status[name] == [{"changed deps": {"params.yaml": {"motion": "modified"}}}], status[name]


def _check_dataset_digests_are_dvc_hashes(repo: Path, d: str) -> None:
    """DVC's manifest of the hole folder, meta.json and the MLflow runs name the same file versions."""
    lock = yaml.safe_load((repo / "dvc.lock").read_text())
    (out,) = [o for o in lock["stages"]["generate"]["outs"] if o["path"] == f"{d}/holes"]
    manifest_hash = out["md5"].removesuffix(".dir")
    manifest = json.loads((repo / ".dvc/cache/files/md5" / manifest_hash[:2] / f"{manifest_hash[2:]}.dir").read_text())
    dvc_md5 = {e["relpath"]: e["md5"] for e in manifest}
    meta = json.loads((repo / d / "holes/meta.json").read_text())
    assert meta["files"] == {k: v for k, v in dvc_md5.items() if k != "meta.json"}
    client = MlflowClient(f"sqlite:///{repo}/mlflow.db")
    exp = client.get_experiment_by_name("boom-ik-tiny")
    assert exp.tags["mlflow.experimentKind"] == "custom_model_development"
    uikm = client.search_runs([exp.experiment_id], "tags.method = 'uikm'")
    assert sorted(r.data.tags["seed"] for r in uikm) == ["0", "1"]
    for run in uikm:
        logged = {i.dataset.name: i.dataset.digest for i in run.inputs.dataset_inputs}
        assert logged["train.parquet"] == dvc_md5["train.parquet"]  # the training table: the version DVC records
        assert set(logged) == {"train.parquet", "held-out holes (val_seed=999)"}  # and the held-out holes it scored


@pytest.mark.slow
@pytest.mark.skipif(os.environ.get("BOOM_IK_RAY_TESTS") != "1", reason="opt-in: BOOM_IK_RAY_TESTS=1, [ray] extra")
def test_ray_launcher_against_a_local_head(tiny_data):
    """The same two-job sweep on a Ray cluster: a local head started (and stopped) by the test."""
    import socket

    ray = shutil.which("ray", path=str(Path(sys.executable).parent))
    assert ray, "the ray command is missing: pip install -e '.[ray]'"
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    _run([ray, "start", "--head", f"--port={port}", "--num-cpus=2", "--include-dashboard=false",
          "--disable-usage-stats"], timeout=180)
    try:
        _, client, runs = _sweep(tiny_data, "ray", "hydra/launcher=ray_cluster",
                                 f"hydra.launcher.ray.init.address=127.0.0.1:{port}")
        _check_parent_and_children(client, runs, tiny_data, "ray")
    finally:
        subprocess.run([ray, "stop", "--force"], capture_output=True, timeout=120, env=_env())
