"""Train and evaluate: the quick experiment end to end, metrics on hand-built cases, learning."""

import json
import logging
import math

import numpy as np
import pandas as pd
import pytest
import torch
from mlflow.tracking import MlflowClient

from pipeline import evaluate, train
from pipeline.core.config import compose
from pipeline.core.errors import ConfigError, InputError
from pipeline.data.holes import HoleSampling, sample_holes, sample_joints
from pipeline.evaluation.metrics import solution_table, summarize
from pipeline.geometry.collision import SAFETY_KINDS
from pipeline.learning.losses import joint_loss
from pipeline.learning.models import build_model, load_checkpoint
from pipeline.learning.training import MethodSettings, Objective, dataset_batches, loss_terms

METHODS = ["sikm", "uikm", "cuikm"]


@pytest.fixture(scope="module")
def study(tmp_path_factory, copy_tiny_study, make_cfg):
    """The tiny study (its CUIKM already trained) with SIKM and UIKM trained beside it, all evaluated."""
    tmp = copy_tiny_study(tmp_path_factory.mktemp("study"))
    trained = {m: train.run(make_cfg(tmp, f"method={m}")) for m in METHODS if m != "cuikm"}
    metrics = evaluate.run(make_cfg(tmp, f"eval.methods=[{','.join(METHODS)}]"))
    return tmp, trained, metrics


@pytest.mark.slow
def test_quick_experiment_writes_everything(study, make_cfg):
    tmp, _, metrics = study
    data, per_group = tmp / "data", make_cfg(tmp).holes.test.size
    for m in METHODS:
        assert (data / "models" / f"{m}.pt").is_file()
        for k in range(1, 6):
            pred = pd.read_parquet(data / "eval" / "predictions" / f"{m}_group{k}.parquet")
            assert list(pred.columns) == ["hole_id", "collar_x", "collar_y", "collar_z", "preview_x", "preview_y",
                                          "preview_z", *(f"q{i}" for i in range(1, 9))]
            assert len(pred) == per_group
    on_disk = json.loads((data / "eval" / "metrics.json").read_text())
    assert set(on_disk) == set(METHODS)
    for m in METHODS:
        keys = ["start_mm_mean", "preview_mm_median", "hole_mm_p95", "hole_mm_max", "direction_deg_mean",
                "collision_rate_paper", "any_violation_share", "solve_ms_per_1000"]
        for key in [*keys, *(f"collisions_{k}" for k in SAFETY_KINDS)]:
            assert math.isfinite(on_disk[m][key]), (m, key)
        assert on_disk[m]["within_limits_share"] == 1.0  # the output squashing keeps every joint in range
    table = pd.read_csv(data / "eval" / "collisions.csv")
    assert list(table.columns) == ["group", "method", *SAFETY_KINDS] and len(table) == 15
    for m in METHODS:  # the table and the metrics agree
        assert table[table.method == m][list(SAFETY_KINDS)].to_numpy().sum() == pytest.approx(
            on_disk[m]["collision_rate_paper"] * 5 * per_group)
    for fig in ["training_curves.png", "face_projection.png", "method_comparison.png"]:
        assert (data / "eval" / "figures" / fig).stat().st_size > 10_000


@pytest.mark.slow
def test_mlflow_holds_the_runs(study, make_cfg):
    tmp, _, _ = study
    cfg = make_cfg(tmp)
    client = MlflowClient(f"sqlite:///{tmp}/mlflow.db")
    exp = client.get_experiment_by_name("boom-ik-tiny")
    runs = client.search_runs([exp.experiment_id])
    by_name = {r.info.run_name: r for r in runs}
    assert {f"train-{m}-seed{k}" for m in METHODS for k in (0, 1)} | {"evaluate"} <= set(by_name)  # tiny: 2 seeds
    for m, seed in [(m, k) for m in METHODS for k in (0, 1)]:
        run = by_name[f"train-{m}-seed{seed}"]
        assert run.info.status == "FINISHED"
        assert run.data.params["method.name"] == m and run.data.params["model.width"] == str(cfg.model.width)
        assert run.data.params["safety.wall"] == "0.5"
        # only the settings training reads: no other stage's, and no other method's
        assert not [k for k in run.data.params if k.split(".")[0] in ("benchmark", "eval", "baselines", "calibration",
                                                                       "solve", "export", "tracking", "paths")]
        assert run.data.params["train.lr"] == "0.001" and run.data.params["train.steps"] == "150"
        final = json.loads((tmp / "data" / "models" / f"{m}_seeds" / f"{m}_seed{seed}_final.json").read_text())
        assert run.data.tags["seed"] == str(seed) == run.data.params["train.seed"]
        assert run.data.metrics["summary/val_hole_mm"] == float(f"{final['val_hole_mm']:.4g}")
        assert run.data.metrics["summary/kept_step"] == final["kept_step"]
        steps = [x.step for x in client.get_metric_history(run.info.run_id, "val_hole_mm")]
        assert steps == [0, 50, 100, 149]
        artifacts = {a.path for a in client.list_artifacts(run.info.run_id)}
        assert {"figures", f"{m}_seed{seed}.pt"} <= artifacts
        assert run.outputs.model_outputs or client.search_logged_models([exp.experiment_id])
    ev = by_name["evaluate"]
    assert math.isfinite(ev.data.metrics["cuikm.hole_mm_mean"])
    paths = {a.path for a in client.list_artifacts(ev.info.run_id, "tables")}
    assert {"tables/collisions.json", "tables/metrics.json"} <= paths


@pytest.mark.slow
def test_checkpoint_loads_alone_and_reproduces_predictions(study):
    tmp, _, _ = study
    model, meta = load_checkpoint(tmp / "data" / "models" / "cuikm.pt")
    assert meta["method"] == "cuikm" and meta["boom"]["name"] == "jumbo8"
    pred = pd.read_parquet(tmp / "data" / "eval" / "predictions" / "cuikm_group2.parquet")
    pose = torch.tensor(pred.iloc[:, 1:7].to_numpy())
    with torch.no_grad():
        q = model(pose.float()).double().numpy()
    assert np.allclose(q, pred.iloc[:, 7:].to_numpy(), atol=1e-6)


@pytest.mark.slow
def test_unsupervised_beats_supervised_on_face_holes(study):
    _, _, metrics = study
    assert metrics["uikm"]["hole_mm_mean"] < metrics["sikm"]["hole_mm_mean"]


# ------------------------------------------------------------ metrics on hand-built cases
def test_exact_joints_give_zero_error(safety):
    q = sample_joints(50, safety.boom, seed=3)
    table = solution_table(safety.boom.pose6(q), q, safety)
    assert table["hole_mm"].max() < 1e-9 and table["direction_deg"].max() < 1e-6


def test_known_collar_offset_gives_known_error(safety):
    q = sample_joints(20, safety.boom, seed=4)
    pose = safety.boom.pose6(q)
    target = pose.clone()
    target[:, :3] += torch.tensor([0.003, 0.0, 0.004], dtype=torch.float64)  # collar 5 mm off, preview exact
    table = solution_table(target, q, safety)
    assert np.allclose(table["start_mm"], 5.0) and np.allclose(table["preview_mm"], 0.0, atol=1e-9)
    assert np.allclose(table["hole_mm"], 2.5)
    summary = summarize(table)
    assert summary["hole_mm_mean"] == pytest.approx(2.5) and summary["solved_1mm_share"] == 0.0


def test_collision_rate_counts_each_kind(safety):
    r = math.radians
    q = torch.tensor([[0, 0, 3.5, 0, 0, 0, 0, 2.5],  # clean
                      [0, r(20), 3.5, 0, r(90), 0, r(-90), 2.5],  # self only
                      [0, r(-30), 4.6, 0, 0, 0, 0, 2.5]], dtype=torch.float64)  # ground only
    s = summarize(solution_table(safety.boom.pose6(q), q, safety))
    assert (s["collisions_self"], s["collisions_ground"], s["collisions_wall"]) == (1, 1, 0)
    assert s["collision_rate_paper"] == pytest.approx(2 / 3) and s["any_violation_share"] == pytest.approx(2 / 3)


# ------------------------------------------------------------ learning
@pytest.mark.parametrize("method", METHODS)
def test_a_few_steps_lower_each_methods_loss(safety, method):
    torch.manual_seed(0)
    boom = safety.boom
    pose, _ = sample_holes(512, safety, HoleSampling(), seed=21)
    q_sup = sample_joints(512, boom, seed=22)
    src = boom.pose6(q_sup) if method == "sikm" else pose
    model = build_model(boom, src.mean(0), src.std(0), 64, 2, "gelu")
    objective = Objective(method == "sikm", 1.0, 10.0 if method == "cuikm" else 0.0, "norm")
    batches = dataset_batches(src.float(), q_sup.float() if method == "sikm" else None, 512, 0)
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    fixed = next(batches)

    def loss():
        return loss_terms(model, boom, safety, objective, *fixed)["loss"]

    before = float(loss().detach())
    for _ in range(60):
        opt.zero_grad()
        loss().backward()
        opt.step()
    assert float(loss().detach()) < 0.7 * before


@pytest.mark.parametrize(("supervised", "lam", "mu", "metric"), [
    (True, 1.0, 0.0, "pose"), (True, 1.0, 0.0, "range"), (True, 1.0, 1.0, "range"), (False, 1.0, 0.0, "range"),
    (False, 1.0, 10.0, "range")])
def test_steps_between_evaluations_skip_the_logged_terms_and_train_the_same_to_the_bit(
        safety, monkeypatch, supervised, lam, mu, metric):
    """``fit`` computes the terms that are only logged (the supervised rows' forward kinematics and
    clearances, UIKM's clearances) at its evaluation steps alone: the weights it ends with are those of
    the same training with every term computed at every step, bit for bit."""
    from pipeline.learning import training

    boom = safety.boom
    q_sup = sample_joints(256, boom, seed=25)
    src = boom.pose6(q_sup).float()
    objective = Objective(supervised, lam, mu, "norm", metric)
    full = training.loss_terms
    asked = []

    def trained(every_term: bool):
        torch.manual_seed(3)
        model = build_model(boom, src.mean(0), src.std(0), 32, 2, "gelu")
        batches = dataset_batches(src, q_sup.float() if supervised else None, 64, 4)

        def terms(*args, logged=True, **kwargs):
            asked.append(logged)
            return full(*args, logged=logged or every_term, **kwargs)

        monkeypatch.setattr(training, "loss_terms", terms)
        history = training.fit(model, boom, safety, objective, batches, 12, 1e-2, src[:32], eval_every=5,
                               progress=False)
        return model.state_dict(), history

    (fast, fast_history), (slow, slow_history) = trained(False), trained(True)
    for name in slow:
        assert torch.equal(fast[name], slow[name]), name
    assert [r["step"] for r in fast_history] == [0, 5, 10, 11]
    assert [{k: v for k, v in r.items() if k != "elapsed_s"} for r in fast_history] == \
        [{k: v for k, v in r.items() if k != "elapsed_s"} for r in slow_history]
    # not vacuous: fit asks for the loss alone between evaluations, which leaves out what the loss does not use
    assert asked[:12] == [s in (0, 5, 10, 11) for s in range(12)]
    between = full(build_model(boom, src.mean(0), src.std(0), 32, 2, "gelu"), boom, safety, objective, src[:8],
                   q_sup[:8].float() if supervised else None, logged=False)
    assert ("l_pos" in between) == (not supervised) and ("l_self" in between) == (mu > 0)
    if not supervised:  # and eq. 16 is the written sum, mu = 0 or not (the terms its shortcut leaves out: zero)
        logged = full(build_model(boom, src.mean(0), src.std(0), 32, 2, "gelu"), boom, safety, objective, src)
        assert torch.equal(logged["loss"], lam * logged["l_pos"] + mu * sum(logged[f"l_{k}"] for k in SAFETY_KINDS))


def test_penalty_step_through_the_network_reduces_violations(safety):
    """CUIKM's safety term, back-propagated into a network, pushes its solutions clear."""
    torch.manual_seed(1)
    boom = safety.boom
    pose, _ = sample_holes(256, safety, HoleSampling(), seed=23)
    model = build_model(boom, pose.mean(0), pose.std(0), 64, 2, "gelu")
    objective = Objective(False, 0.0, 1.0)  # penalties only
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    terms0 = loss_terms(model, boom, safety, objective, pose.float())
    assert float(terms0["loss"]) > 0
    terms0["loss"].backward()
    opt.step()
    assert float(loss_terms(model, boom, safety, objective, pose.float())["loss"]) < float(terms0["loss"])


def test_supervised_loss_is_eq6_alone_unless_mu_adds_the_penalties(safety):
    """``mu = 0`` (paper 000's SIKM) optimises eq. 6 and nothing else; ``mu > 0`` adds the four
    safety penalties beside it, and trained on labels that collide, the network then ends with
    less violation than the same training without them."""
    boom = safety.boom
    q_sup = sample_joints(512, boom, seed=24)  # full ranges: about half of these labels collide
    src = boom.pose6(q_sup).float()
    fixed = next(dataset_batches(src, q_sup.float(), 512, 0))

    def trained(mu):
        torch.manual_seed(2)
        model = build_model(boom, src.mean(0), src.std(0), 64, 2, "gelu")
        objective = Objective(True, 1.0, mu, "norm")
        opt = torch.optim.Adam(model.parameters(), lr=3e-3)
        for _ in range(80):
            opt.zero_grad()
            loss_terms(model, boom, safety, objective, *fixed)["loss"].backward()
            opt.step()
        with torch.no_grad():
            return loss_terms(model, boom, safety, objective, *fixed)

    plain, penalised = trained(0.0), trained(1.0)
    assert float(plain["loss"]) == float(plain["l_joint"])
    violation = {name: sum(float(t[f"l_{k}"]) for k in SAFETY_KINDS) for name, t in
                 (("plain", plain), ("penalised", penalised))}
    assert violation["plain"] > 0
    assert violation["penalised"] < 0.5 * violation["plain"]
    assert float(penalised["loss"]) == pytest.approx(float(penalised["l_joint"]) + violation["penalised"], rel=1e-5)


def test_the_pose_metric_of_a_joint_error_is_the_hole_error_it_causes_to_first_order(safety):
    """``label_pose_loss`` against forward kinematics: for small joint errors it equals the mean
    hole-seeking error of the moved joints (relative gap of the order of the step); along the
    boom's redundancy (the label's Jacobian's null space) it vanishes, which is why eq. 6 stays
    beside it."""
    from pipeline.geometry.kinematics import pose_errors
    from pipeline.learning.losses import label_pose_loss

    boom = safety.boom
    q = sample_joints(64, boom, seed=25)
    dq = 1e-5 * torch.randn(q.shape, generator=torch.Generator().manual_seed(0), dtype=q.dtype)
    by_fk = float(pose_errors(boom.pose6(q + dq), boom.pose6(q))["hole"].mean())
    assert float(label_pose_loss(boom, q + dq, q, "norm")) == pytest.approx(by_fk, rel=1e-3)
    sq = float((((boom.pose6(q + dq) - boom.pose6(q)) ** 2).sum(-1)).mean())
    assert float(label_pose_loss(boom, q + dq, q, "mse")) == pytest.approx(sq, rel=1e-3)
    null = torch.linalg.svd(boom.pose6_jacobian(boom.frames(q))).Vh[:, -1]  # (64, n_joints), J null = 0
    along = q + 1e-3 * null
    assert float(label_pose_loss(boom, along, q, "mse")) < 1e-20
    lo, hi = boom.limits(q.dtype)
    assert float(joint_loss((along - lo) / (hi - lo), (q - lo) / (hi - lo))) > 1e-9


def test_a_method_trains_at_most_its_own_step_budget():
    node = compose(["method=sikm"]).method
    assert node.max_steps is not None
    sikm = MethodSettings.from_config(node)
    assert sikm.steps(15000) == node.max_steps and sikm.steps(300) == 300  # a cap, never more than train.steps
    assert MethodSettings.from_config(compose(["method=cuikm"]).method).steps(15000) == 15000
    with pytest.raises(ConfigError, match=r"method.max_steps"):
        MethodSettings.from_config(compose(["method=sikm", "method.max_steps=0"]).method)


def test_bad_method_config_is_named(tmp_path):
    with pytest.raises(ConfigError, match=r"method.mu = -1.0: must be >= 0"):
        MethodSettings.from_config(compose(["method.mu=-1"]).method)
    with pytest.raises(ConfigError, match=r"method.pose_loss = 'l3'"):
        MethodSettings.from_config(compose(["method.pose_loss=l3"]).method)
    with pytest.raises(ConfigError, match=r"method.pose_loss = 'l3'"):
        from pipeline.learning.losses import pose_loss

        pose_loss(torch.zeros(2, 6), torch.zeros(2, 6), "l3")


def test_evaluate_without_models_says_what_is_missing(tiny_study, make_cfg):
    with pytest.raises(InputError, match=r"sikm.pt: no such model checkpoint"):  # the tiny study has CUIKM only
        evaluate.run(make_cfg(tiny_study))
    assert not (tiny_study / "data" / "eval").exists()  # nothing half-written


def test_a_training_prints_the_full_studys_figure_beside_its_own(tiny_study, make_cfg, caplog):
    """The quick experiment's ``tour`` (tiny inherits it): a short training's figure is read for what it is."""
    cfg = make_cfg(tiny_study, "method=cuikm", "train.steps=2", "train.eval_every=1", "runtime.log_model=false",
                   "tour.hole_mm.cuikm=1.25", "tour.collision_pct.cuikm=0.07")
    with caplog.at_level(logging.INFO, logger="pipeline.train"):
        train.run(cfg)
    lines = [r.getMessage() for r in caplog.records if "full study" in r.getMessage()]
    assert lines == ["the full study's cuikm (the README's first command) reaches 1.25 mm on its five test groups, "
                     "0.07 % collisions"]
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="pipeline.train"):  # a config without the node: nothing
        train.run(make_cfg(tiny_study, "method=cuikm", "train.steps=2", "runtime.log_model=false", "~tour"))
    assert not [r for r in caplog.records if "full study" in r.getMessage()]
    for override, error in [("+tour.hole_m={cuikm: 1}", r"tour.hole_m: unknown setting; did you mean 'hole_mm'"),
                            ("tour.hole_mm=3", r"tour.hole_mm = 3: expected a mapping"),
                            ("tour.collision_pct.cuikm=abc", r"tour.collision_pct.cuikm = 'abc': expected a number")]:
        with pytest.raises(ConfigError, match=error):  # before any work: a typo must not wait for the training
            train.run(make_cfg(tiny_study, override))
