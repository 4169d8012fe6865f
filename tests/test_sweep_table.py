"""The sweeps' table (pipeline.sweep_table): every seed of every point scored, the swept settings read from the
networks' own records, the front computed, and a point trained under other defaults refused before anything is
written."""

from pathlib import Path

import pandas as pd
import pytest
import torch
from omegaconf import open_dict

from pipeline import sweep_table, train
from pipeline.core.errors import ConfigError, InputError
from pipeline.data.hole_sets import read_test_groups
from pipeline.data.tables import POSE_COLUMNS
from pipeline.geometry.collision import SAFETY_KINDS
from pipeline.learning.models import load_checkpoint


def _cfg(make_cfg, tmp, jobs, *overrides):
    cfg = make_cfg(tmp, "sweeps.table=mu", *overrides)
    with open_dict(cfg):
        cfg.sweeps.jobs = jobs
    return cfg


@pytest.fixture(scope="module")
def swept(tmp_path_factory, copy_tiny_study, make_cfg):
    """The tiny study (its CUIKM, two seeds: the reference) and one job, mu = 1, one seed, then the mu table."""
    tmp = copy_tiny_study(tmp_path_factory.mktemp("sweep_table"))
    job = tmp / "data/sweeps/mu/jobs/mu-1"
    train.run(make_cfg(tmp, "method.mu=1", f"paths.models={job}", "train.seeds=1", "runtime.log_model=false"))
    jobs = {"mu-1": {"sweep": "mu", "set": "method.mu=1"}}
    summary = sweep_table.run(_cfg(make_cfg, tmp, jobs))
    return tmp, jobs, summary


@pytest.mark.slow
def test_every_seed_of_every_point_is_a_row_with_its_own_settings(swept):
    tmp, _, _ = swept
    rows = pd.read_csv(tmp / "data/sweeps/mu/jobs.csv")
    assert list(rows.columns) == ["job", "method.lam", "method.mu", "seed", "mean_mm", "p95_mm", "collision_rate_pct",
                                  "any_violation_pct", "collisions_self", "collisions_wall", "collisions_ground",
                                  "collisions_arch", "val_hole_mm", "train_seconds", "predictions"]
    assert sorted(zip(rows["job"], rows["seed"], strict=True)) == [("mu-1", 0), ("reference", 0), ("reference", 1)]
    assert set(rows.loc[rows["job"] == "reference", "method.mu"]) == {10.0}  # the defaults, from the records
    assert set(rows.loc[rows["job"] == "mu-1", "method.mu"]) == {1.0}
    assert (rows["mean_mm"] > 0).all() and (rows["p95_mm"] >= rows["mean_mm"]).all()


@pytest.mark.slow
def test_the_predictions_are_each_seed_s_own_network_on_the_test_groups(swept, safety):
    """The files a row names hold what that seed's network answers, not another seed's or job's, and the row's
    collisions per kind are those answers' violations of the reference distances, counted here from the joints."""
    tmp, _, _ = swept
    rows = pd.read_csv(tmp / "data/sweeps/mu/jobs.csv")
    groups = read_test_groups(tmp / "data/holes")
    holes = sum(len(df) for df, _ in groups.values())
    nets = {("reference", 0): tmp / "data/models/cuikm_seeds/cuikm_seed0.pt",
            ("reference", 1): tmp / "data/models/cuikm_seeds/cuikm_seed1.pt",
            ("mu-1", 0): tmp / "data/sweeps/mu/jobs/mu-1/cuikm_seeds/cuikm_seed0.pt"}
    answers = {}
    for (job, seed), path in nets.items():
        model, _ = load_checkpoint(path)
        (folder,) = rows.loc[(rows["job"] == job) & (rows["seed"] == seed), "predictions"]
        for k, (_, pose) in groups.items():
            pred = pd.read_parquet(tmp / "data/sweeps/mu" / folder / f"group{k}.parquet")
            joints = torch.tensor(pred.drop(columns=["hole_id", *POSE_COLUMNS]).to_numpy())
            with torch.no_grad():
                expected = model(pose.float()).double()
            torch.testing.assert_close(joints, expected, atol=1e-6, rtol=0)
            answers[(job, seed, k)] = joints
        counted = dict.fromkeys(SAFETY_KINDS, 0)
        for k in groups:  # the written joints against the reference safety model, kind by kind
            bad = safety.violations(safety.clearances(answers[(job, seed, k)]))
            counted = {kind: n + int(bad[kind].sum()) for kind, n in counted.items()}
        row = rows[(rows["job"] == job) & (rows["seed"] == seed)].iloc[0]
        assert {kind: row[f"collisions_{kind}"] for kind in counted} == counted
        assert 100 * sum(counted.values()) / holes == pytest.approx(row["collision_rate_pct"])
    assert not torch.equal(answers[("reference", 0, 1)], answers[("reference", 1, 1)])  # two seeds, two networks


@pytest.mark.slow
def test_the_summary_is_the_seeds_mean_and_std_and_the_front_is_the_undominated_jobs(swept):
    tmp, _, summary = swept
    rows = pd.read_csv(tmp / "data/sweeps/mu/jobs.csv")
    written = pd.read_csv(tmp / "data/sweeps/mu/summary.csv")
    assert list(written["job"]) == list(summary["job"]) == ["reference", "mu-1"]
    for _, job in written.iterrows():
        seeds = rows[rows["job"] == job["job"]]
        assert job["seeds"] == len(seeds)
        assert job["mean_mm"] == pytest.approx(seeds["mean_mm"].mean())
        assert job["mean_mm_std"] == pytest.approx(seeds["mean_mm"].std(ddof=1) if len(seeds) > 1 else 0.0)
    # brute force: a job is on the front unless another is no worse on both figures and better on one
    points = list(zip(written["mean_mm"], written["collision_rate_pct"], strict=True))
    for i, (e, c) in enumerate(points):
        dominated = any(e2 <= e and c2 <= c and (e2 < e or c2 < c) for j, (e2, c2) in enumerate(points) if j != i)
        assert written["pareto"][i] == (not dominated)
    assert (tmp / "data/sweeps/mu/tradeoff.png").stat().st_size > 10_000


@pytest.mark.slow
def test_a_point_trained_under_other_defaults_is_refused_and_nothing_is_overwritten(swept, make_cfg):
    tmp, jobs, _ = swept
    out = tmp / "data/sweeps/mu/jobs.csv"
    before = out.read_bytes()
    ckpt = tmp / "data/sweeps/mu/jobs/mu-1/cuikm_seeds/cuikm_seed0.pt"
    good = ckpt.read_bytes()
    payload = torch.load(ckpt, weights_only=True)
    payload["config"]["train"]["steps"] += 1  # planted: the job trained one step longer than the reference
    torch.save(payload, ckpt)
    try:
        with pytest.raises(InputError, match=r"'mu-1', seed 0: trained with train\.steps = '151'.*'150'"):
            sweep_table.run(_cfg(make_cfg, tmp, jobs))
    finally:
        ckpt.write_bytes(good)
    assert out.read_bytes() == before


def _sweep_files(out):
    """The table's own files (not the jobs' networks beside them), by path, with their bytes."""
    return {p.relative_to(out): p.read_bytes() for p in out.rglob("*")
            if p.is_file() and p.relative_to(out).parts[0] != "jobs"}


@pytest.mark.slow
def test_a_run_stopped_while_writing_leaves_the_earlier_set_whole(swept, make_cfg, monkeypatch):
    tmp, jobs, _ = swept
    out = tmp / "data/sweeps/mu"
    before = _sweep_files(out)
    assert any(p.parts[0] == "predictions" for p in before) and Path("jobs.csv") in before

    def stopped(*_):  # the last file of the set: everything else is written by then
        raise KeyboardInterrupt

    monkeypatch.setattr(sweep_table, "save_figure", stopped)
    with pytest.raises((KeyboardInterrupt, SystemExit)):  # a set unlike the first: the reference renamed
        sweep_table.run(_cfg(make_cfg, tmp, jobs, "sweeps.reference=defaults"))
    assert _sweep_files(out) == before  # nothing replaced, nothing left of the private folder


@pytest.mark.parametrize(("jobs", "overrides", "error", "match"), [
    ({"mu-3": {"sweep": "mu", "set": "method.mu=3"}}, [], InputError, r"'mu-3': no networks"),
    ({"mu-3": {"sweep": "speed", "set": "method.mu=3"}}, [], ConfigError, r"sweeps.jobs.mu-3.sweep = 'speed'"),
    ({"mu-3": {"sweep": "mu", "set": "method.mu"}}, [], ConfigError, r"expected one override"),
    ({}, ["sweeps.table=null"], ConfigError, r"sweeps.table is not set"),
    ({}, ["sweeps.table=speed"], ConfigError, r"sweeps.table = 'speed'"),
])
def test_bad_sweep_settings_are_named(tiny_study, make_cfg, jobs, overrides, error, match):
    cfg = _cfg(make_cfg, tiny_study, jobs, *overrides)
    with pytest.raises(error, match=match):
        sweep_table.run(cfg)
    assert not (tiny_study / "data/sweeps/mu/jobs.csv").exists()


def test_the_configured_sweeps_cover_the_issue_s_grid(make_cfg, tmp_path):
    """At least four values of mu and five settings of the training distances, the reference counted."""
    settings = sweep_table.SweepSettings.from_config(make_cfg(tmp_path).sweeps)
    per_sweep = {name: 1 + sum(job["sweep"] == name for job in settings.jobs.values()) for name in settings.tables}
    assert per_sweep["mu"] >= 4 and per_sweep["safety"] >= 5
    overrides = [job["set"].split("=")[0] for job in settings.jobs.values()]
    for name, keys in settings.tables.items():  # each job's override is a setting its table shows
        own = [job["set"].split("=")[0] for job in settings.jobs.values() if job["sweep"] == name]
        assert set(own) <= set(keys), name
    assert {"method.mu", *(f"method.train_safety.{k}" for k in SAFETY_KINDS)} <= set(overrides)  # mu, each distance
