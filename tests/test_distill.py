"""The hybrid's distilled start network (pipeline/learning/distillation.py, stage pipeline/distill.py)."""

import json

import mlflow
import pytest
import torch

from pipeline import distill
from pipeline.core.errors import ConfigError, InputError
from pipeline.data.holes import sample_holes
from pipeline.learning.distillation import DistillSettings, distil, imitation_metrics, student_like
from pipeline.learning.models import build_model, load_checkpoint
from pipeline.learning.training import pose_metrics


@pytest.fixture(scope="module")
def teacher_and_holes(safety):
    from pipeline.assembly.build import hole_sampling
    from pipeline.core.config import compose

    pose, _ = sample_holes(1500, safety, hole_sampling(compose([]).holes), 3)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(5)
        teacher = build_model(safety.boom, pose.mean(0), pose.std(0), 24, 2, "tanh").eval()
    return teacher, pose.float()


def _dev(student, teacher, pose) -> float:
    with torch.no_grad():
        return float(((student(pose) - teacher(pose)).abs() / teacher.span).amax(-1).mean())


def test_the_student_learns_the_teachers_joints(teacher_and_holes, one_torch_thread):
    """On holes it never saw, the distilled student lies far closer to the teacher than the same network
    untrained, and it keeps the teacher's normalisation and ranges (so its joints stay inside the limits)."""
    teacher, pose = teacher_and_holes
    train, held_out = pose[:1000], pose[1000:]
    student, history = distil(teacher, train, 32, 2, "relu", 400, 256, 5e-3, 1e-4, seed=0)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(0)
        untrained = student_like(teacher, 32, 2, "relu")
    assert _dev(student, teacher, held_out) < 0.2 * _dev(untrained, teacher, held_out)
    for buf in ("lower", "span", "in_mean", "in_std"):
        assert torch.equal(getattr(student, buf), getattr(teacher, buf))
    assert history[-1]["loss"] < history[0]["loss"] and [r["step"] for r in history] == list(range(40, 401, 40))
    again, _ = distil(teacher, train, 32, 2, "relu", 400, 256, 5e-3, 1e-4, seed=0)  # seeded: the same weights
    pairs = zip(student.state_dict().values(), again.state_dict().values(), strict=True)
    assert all(torch.equal(a, b) for a, b in pairs)


def test_imitation_metrics_against_the_training_code_and_a_copy(teacher_and_holes, jumbo8):
    teacher, pose = teacher_and_holes
    copy = student_like(teacher, 24, 2, "tanh")
    copy.load_state_dict(teacher.state_dict())
    same = imitation_metrics(copy, teacher, jumbo8, pose)
    assert same["joint_dev_max"] == 0 and same["student_hole_mm_mean"] == same["teacher_hole_mm_mean"]
    # the hole error by the training loop's own held-out metric (a second implementation)
    assert same["teacher_hole_mm_mean"] == pytest.approx(pose_metrics(teacher, jumbo8, pose)["val_hole_mm"], rel=1e-9)
    with torch.no_grad():
        copy.net[-1].bias += 0.5  # every joint moved: the deviation is what the outputs say
    moved = imitation_metrics(copy, teacher, jumbo8, pose)
    with torch.no_grad():
        brute = max(float(((copy(p[None]) - teacher(p[None])).abs() / teacher.span).max()) for p in pose[:50])
    assert moved["joint_dev_max"] >= brute > 0.01
    assert moved["joint_dev_mean"] <= moved["joint_dev_p95"] <= moved["joint_dev_max"]


@pytest.mark.parametrize("override, match", [
    (["distill.name=cuikm"], "teacher's name"),
    (["distill.width=0"], "distill.width"),
    (["distill.activation=swish"], "distill.activation"),
    (["distill.lr_min=1.0"], "lr_min"),
    # a name is a file name in paths.data/models, never a path (it crashed); sizes have ranges
    (["distill.name=../escaped"], r"distill.name = '../escaped': expected a network name"),
    (["distill.name=sub/net"], r"distill.name = 'sub/net': expected a network name"),
    (["distill.teacher=../../etc/x"], r"distill.teacher = '../../etc/x': expected a network name"),
    (["distill.pool=1000000000"], r"distill.pool = 1000000000: must be <= 1000000"),
    (["distill.batch_size=100000000"], r"distill.batch_size = 100000000: must be <= 65536"),
    (["distill.batch_size=4096"], r"distill.batch_size = 4096: more than distill.pool = 2000"),
    (["distill.width=1000000"], r"distill.width = 1000000: must be <= 4096"),
])
def test_bad_settings_are_named_before_any_work(override, match, make_cfg, tmp_path):
    with pytest.raises(ConfigError, match=match):
        distill.run(make_cfg(tmp_path, *override))
    assert not (tmp_path / "data").exists()


def test_a_trained_network_is_never_replaced_by_a_student(tiny_study, make_cfg):
    """distill.name naming a trained network's file is refused, the file left as it was; an earlier
    student is replaced."""
    models = tiny_study / "data" / "models"
    before = (models / "cuikm.pt").read_bytes()
    (models / "uikm.pt").write_bytes(before)  # a trained network under another name
    with pytest.raises(InputError, match=r"uikm\.pt: holds a network that was not distilled \(method 'cuikm'\)"):
        distill.run(make_cfg(tiny_study, "distill.name=uikm"))
    assert (models / "uikm.pt").read_bytes() == before
    distill.run(make_cfg(tiny_study, "distill.steps=5"))
    first = (models / "cuikm_start.pt").read_bytes()
    distill.run(make_cfg(tiny_study, "distill.steps=6"))
    assert (models / "cuikm_start.pt").read_bytes() != first


def test_a_missing_teacher_is_named(make_cfg, tmp_path):
    with pytest.raises(InputError, match=r"cuikm\.pt: no such model checkpoint"):
        distill.run(make_cfg(tmp_path))
    assert not (tmp_path / "data" / "models" / "cuikm_start.pt").exists()


@pytest.mark.slow
def test_the_stage_writes_a_checkpoint_that_loads_alone_and_logs_its_run(tiny_study, make_cfg):
    models = tiny_study / "data" / "models"
    teacher_bytes = (models / "cuikm.pt").read_bytes()
    cfg = make_cfg(tiny_study)
    final = distill.run(cfg)
    assert (models / "cuikm.pt").read_bytes() == teacher_bytes  # the input is never touched
    student, meta = load_checkpoint(models / "cuikm_start.pt")  # weights only
    s = DistillSettings.from_config(cfg.distill)
    assert student.hparams == {"width": s.width, "depth": s.depth, "activation": s.activation}
    assert meta["method"] == "cuikm_start" and meta["config"]["distill"]["teacher"] == "cuikm"
    assert json.loads((models / "cuikm_start_final.json").read_text()) == pytest.approx(final)
    assert not [p for p in models.iterdir() if p.name.startswith(".")]  # no private folder left
    client = mlflow.tracking.MlflowClient(f"sqlite:///{tiny_study}/mlflow.db")
    run = client.get_run(meta["mlflow_run_id"])
    assert run.info.status == "FINISHED" and run.data.tags["stage"] == "distill"
    assert run.data.metrics["joint_dev_p95"] == pytest.approx(final["joint_dev_p95"])
    assert [m.step for m in client.get_metric_history(run.info.run_id, "loss")][-1] == s.steps
