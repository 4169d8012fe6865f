"""Trainings that resume: a training stopped by SIGTERM, SIGINT or a crash continues from its resume state
to the very weights an uninterrupted training gives (torch.equal, not a tolerance), in the same MLflow
run; the network it logs is registered and its alias resolves to those weights."""

import os
import signal

import pytest
import torch
from mlflow.tracking import MlflowClient

from pipeline import generate, train
from pipeline.learning.models import build_model, load_checkpoint
from pipeline.learning.network_source import load_network
from pipeline.learning.training import (
    Checkpoints,
    Objective,
    fit,
    fresh_hole_batches,
    load_training_state,
    save_training_state,
    training_digest,
)

# tiny: 150 steps, held-out evaluations at 0, 50, 100, 149; one seed (the seeds' own resume: the last test)
STEPS = ("runtime.checkpoint_every=40", "train.seeds=1")


def _weights(path):
    return load_checkpoint(path)[0].state_dict()


def _same(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def _stop_at(monkeypatch, step: int, how):
    """Make the stage's per-evaluation logging stop the training at held-out evaluation ``step``."""
    original = train.log_training_progress

    def hook(run, s, *args, **kwargs):
        original(run, s, *args, **kwargs)
        if s == step:
            how()

    monkeypatch.setattr(train, "log_training_progress", hook)


@pytest.fixture(scope="module")
def study(tmp_path_factory, make_cfg):
    tmp = tmp_path_factory.mktemp("resume")
    generate.run(make_cfg(tmp))
    done = train.run(make_cfg(tmp, *STEPS))  # the uninterrupted training
    return tmp, _weights(done["checkpoint"]), done


def _runs(tmp):
    client = MlflowClient(f"sqlite:///{tmp}/mlflow.db")
    exp = client.get_experiment_by_name("boom-ik-tiny")  # the experiment of conf/experiment/tiny.yaml
    return client, client.search_runs([exp.experiment_id], "tags.stage = 'train'", order_by=["start_time ASC"])


@pytest.mark.slow
def test_sigterm_then_resume_gives_the_uninterrupted_weights(study, make_cfg, monkeypatch):
    tmp, reference, _ = study
    _stop_at(monkeypatch, 50, lambda: os.kill(os.getpid(), signal.SIGTERM))
    with pytest.raises(SystemExit) as stopped:
        train.run(make_cfg(tmp, *STEPS))
    assert stopped.value.code == 128 + signal.SIGTERM
    states = list((tmp / "data" / "models").glob(".cuikm_seed0.run-*/resume.pt"))
    assert len(states) == 1
    state = torch.load(states[0], weights_only=True)  # plain data: loads without running code
    assert state["step"] == 51 and [r["step"] for r in state["history"]] == [0, 50]
    client, runs = _runs(tmp)
    killed = runs[-1]
    assert killed.info.status == "KILLED"
    assert "checkpoints/resume.pt" in {a.path for a in client.list_artifacts(killed.info.run_id, "checkpoints")}

    monkeypatch.undo()
    train.run(make_cfg(tmp, *STEPS, "runtime.progress=true"))  # how it runs may change (outside the digest)
    assert _same(_weights(tmp / "data" / "models" / "cuikm.pt"), reference)
    assert not list((tmp / "data" / "models").glob(".cuikm_seed0.run-*"))  # the private folder goes once published
    client, runs = _runs(tmp)
    resumed = client.get_run(killed.info.run_id)  # the same run, continued
    assert len(runs) == 2 and resumed.info.status == "FINISHED"
    assert resumed.data.tags["resumed_at_step"] == "51" and "run.end_reason" not in resumed.data.tags
    assert resumed.data.params["runtime.progress"] == "False"  # a param keeps its first value
    steps = [m.step for m in client.get_metric_history(resumed.info.run_id, "val_hole_mm")]
    assert steps == [0, 50, 100, 149]


@pytest.mark.slow
def test_a_crash_resumes_from_the_last_periodic_state(study, make_cfg, monkeypatch):
    tmp, reference, _ = study

    def crash():
        raise RuntimeError("simulated crash")

    _stop_at(monkeypatch, 100, crash)
    with pytest.raises(RuntimeError, match="simulated crash"):
        train.run(make_cfg(tmp, *STEPS))
    (state_file,) = (tmp / "data" / "models").glob(".cuikm_seed0.run-*/resume.pt")
    assert torch.load(state_file, weights_only=True)["step"] == 80  # every 40 steps: 40, 80
    monkeypatch.undo()
    train.run(make_cfg(tmp, *STEPS))
    assert _same(_weights(tmp / "data" / "models" / "cuikm.pt"), reference)


@pytest.mark.slow
def test_another_config_does_not_resume_and_resume_false_starts_over(study, make_cfg, monkeypatch):
    tmp, reference, _ = study
    _stop_at(monkeypatch, 50, lambda: os.kill(os.getpid(), signal.SIGTERM))
    with pytest.raises(SystemExit):
        train.run(make_cfg(tmp, *STEPS, "train.lr=2e-3"))
    monkeypatch.undo()
    (other,) = (tmp / "data" / "models").glob(".cuikm_seed0.run-*")
    train.run(make_cfg(tmp, *STEPS))  # the reference settings: the lr=2e-3 state is not theirs
    assert _same(_weights(tmp / "data" / "models" / "cuikm.pt"), reference)
    assert other.is_dir()
    client, before = _runs(tmp)
    train.run(make_cfg(tmp, *STEPS, "train.lr=2e-3", "runtime.resume=false"))  # from step 0, a new run
    client, after = _runs(tmp)
    assert len(after) == len(before) + 1 and "resumed_at_step" not in after[-1].data.tags
    assert client.get_run(before[-2].info.run_id).info.status == "KILLED"  # the interrupted one stays as it was
    assert not other.exists()  # replaced by the new training's folder, removed once it published


@pytest.mark.slow
def test_the_logged_network_is_registered_at_its_kept_step(study, make_cfg):
    tmp, _, done = study
    client = MlflowClient(f"sqlite:///{tmp}/mlflow.db")
    newest = client.get_model_version_by_alias("boom-ik-tiny-cuikm", "newest")
    assert int(newest.version) == max(int(v.version) for v in client.search_model_versions(
        "name = 'boom-ik-tiny-cuikm'"))
    net, meta = load_network("models:/boom-ik-tiny-cuikm@newest", None, f"sqlite:///{tmp}/mlflow.db")
    assert meta["mlflow_run_id"] == newest.run_id
    published, published_meta = load_checkpoint(tmp / "data" / "models" / "cuikm.pt")  # the last training's
    assert published_meta["mlflow_run_id"] == newest.run_id and _same(net.state_dict(), published.state_dict())
    (output,) = client.get_run(newest.run_id).outputs.model_outputs
    model = client.get_logged_model(output.model_id)
    assert newest.source == f"models:/{output.model_id}"
    assert model.name == "cuikm"
    kept = next(r for r in meta["history"] if r.get("kept"))
    linked = {m.key: m for m in model.metrics}
    assert linked["val_hole_mm"].step == kept["step"] and linked["val_hole_mm"].value == kept["val_hole_mm"]
    assert {m.dataset_name for m in model.metrics if m.dataset_name} == {
        "train.parquet", "held-out holes (val_seed=999)"}


def test_fit_resumes_after_sigint_to_the_same_weights(safety, tmp_path):
    """The loop alone (no stage, no MLflow): Ctrl-C during step 7 saves the state at the next step
    boundary, and fitting on from it (through a file) equals fitting straight through, fresh holes included."""
    from pipeline.assembly.build import hole_sampling
    from pipeline.core.config import load_group_file

    sampling = hole_sampling(load_group_file("holes", "default"))
    pose = next(fresh_hole_batches(safety, sampling, 64, 1, "cpu"))[0]
    objective = Objective(False, 1.0, 1.0, "norm")

    def run(saved: list, interrupt_at=None, resume=None):
        torch.manual_seed(0)
        model = build_model(safety.boom, pose.mean(0), pose.std(0), 16, 1, "gelu")

        def on_eval(step, _rec, _elapsed):
            if step == interrupt_at:
                os.kill(os.getpid(), signal.SIGINT)

        fit(model, safety.boom, safety, objective, fresh_hole_batches(safety, sampling, 32, 3, "cpu"), 12, 1e-2,
            pose, eval_every=1, on_eval=on_eval, progress=False, keep_best=True,
            checkpoints=Checkpoints(saved.append, 5, resume))
        return model

    periodic, stopped = [], []
    straight = run(periodic)
    assert [s["step"] for s in periodic] == [5, 10]
    with pytest.raises(KeyboardInterrupt):
        run(stopped, interrupt_at=7)
    assert [s["step"] for s in stopped] == [5, 8]
    path = tmp_path / "resume.pt"
    save_training_state(path, stopped[-1], "d")
    assert load_training_state(path, "another digest") is None
    resumed = run([], resume=load_training_state(path, "d"))
    assert _same(resumed.state_dict(), straight.state_dict())
    assert _same(run([], resume=periodic[0]).state_dict(), straight.state_dict())
    # the comparison can fail: the same state with the hole sampler's generator back at its seed differs
    rewound = {**periodic[0], "batches": fresh_hole_batches(safety, sampling, 32, 3, "cpu").state()}
    assert not _same(run([], resume=rewound).state_dict(), straight.state_dict())


def test_the_digest_follows_config_and_data(tmp_path):
    f = tmp_path / "train.parquet"
    f.write_bytes(b"a")
    base = training_digest({"train": {"lr": 1e-3}}, [f])
    assert training_digest({"train": {"lr": 1e-3}}, [f]) == base
    assert training_digest({"train": {"lr": 2e-3}}, [f]) != base
    f.write_bytes(b"b")
    assert training_digest({"train": {"lr": 1e-3}}, [f]) != base


@pytest.mark.slow
def test_a_finished_seed_waits_for_the_others_and_is_not_trained_again(study, make_cfg, monkeypatch):
    """Two seeds, SIGTERM in the second: the first, finished, waits in its private folder (nothing published
    yet); the rerun trains only the second, from its state, and publishes both with the uninterrupted weights."""
    tmp, _, _ = study
    two = ("runtime.checkpoint_every=40", "train.seeds=2", "train.seed=40")
    train.run(make_cfg(tmp, *two))
    models = tmp / "data" / "models"
    reference = {s: _weights(models / "cuikm_seeds" / f"cuikm_seed{s}.pt") for s in (40, 41)}
    original, seen = train.log_training_progress, []

    def hook(run, s, *args, **kwargs):
        original(run, s, *args, **kwargs)
        seen.append(s)
        if s == 50 and seen.count(50) == 2:  # the second seed's evaluation at step 50
            os.kill(os.getpid(), signal.SIGTERM)

    monkeypatch.setattr(train, "log_training_progress", hook)
    (models / "cuikm_seeds").rename(models / "earlier_seeds")  # so that publishing is seen
    with pytest.raises(SystemExit):
        train.run(make_cfg(tmp, *two))
    assert not (models / "cuikm_seeds").exists()
    assert len(list(models.glob(".cuikm_seed40.run-*/done/cuikm_seed40.pt"))) == 1
    assert len(list(models.glob(".cuikm_seed41.run-*/resume.pt"))) == 1
    monkeypatch.undo()
    client, before = _runs(tmp)
    train.run(make_cfg(tmp, *two))
    client, after = _runs(tmp)
    assert len(after) == len(before)  # seed 40 not trained again, seed 41 continued in its own run
    for s in (40, 41):
        assert _same(_weights(models / "cuikm_seeds" / f"cuikm_seed{s}.pt"), reference[s])
    assert not list(models.glob(".cuikm_seed4*"))
