"""The generate stage: what it writes, and that the holes obey docs/reference.md section 3."""

import json
import math
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
import torch

from pipeline.core.config import PROJECT_ROOT, compose
from pipeline.core.errors import ConfigError
from pipeline.data.tables import POSE_COLUMNS
from pipeline.generate import run
from pipeline.geometry.collision import SAFETY_KINDS
from pipeline.geometry.tunnel import Horseshoe

SMALL = ["experiment=tiny", "tracking.enabled=false"]  # the tiny study's holes, without an MLflow store


@pytest.fixture(scope="module")
def generated(tmp_path_factory, copy_tiny_study):
    """This module's copy of the tiny study's holes (generated once per session), only read from."""
    out = copy_tiny_study(tmp_path_factory.mktemp("gen")) / "data"
    cfg = compose([*SMALL, f"paths.data={out}"])
    return out / "holes", json.loads((out / "holes" / "meta.json").read_text()), cfg


def test_files_and_columns(generated):
    holes, meta, cfg = generated
    names = ["train", *(f"test_group_{k}" for k in range(1, 6)), "sup"]
    for name in names:
        df = pd.read_parquet(holes / f"{name}.parquet")
        assert list(df.columns[:1]) == ["hole_id"] and set(POSE_COLUMNS) <= set(df.columns)
        assert np.isfinite(df[POSE_COLUMNS].to_numpy()).all()
    assert len(pd.read_parquet(holes / "train.parquet")) == cfg.holes.unsup.size
    assert len(pd.read_parquet(holes / "test_group_3.parquet")) == cfg.holes.test.size
    sup = pd.read_parquet(holes / "sup.parquet")
    assert list(sup.columns) == ["hole_id", *(f"q{i}" for i in range(1, 9)), *POSE_COLUMNS]
    on_disk = json.loads((holes / "meta.json").read_text())
    assert on_disk["seeds"] == {"unsup": 0, "sup": {"sup": 1, "sup_best": 2, "coupled": 3, "continuation": 4},
                                "test": [101, 102, 103, 104, 105]}
    assert 0 < on_disk["unsup_rejection"]["rejection_rate"] < 1
    assert set(on_disk["sup_sets"]["sup"]["violation_share"]) == {*SAFETY_KINDS, "any"}
    assert on_disk["config"]["boom"]["name"] == "jumbo8"


def test_every_supervised_set_reports_its_label_consistency(generated):
    _, meta, _ = generated
    for name, stats in meta["sup_sets"].items():
        c = stats["consistency"]
        assert c["pairs"] > 0 and c["ratio_p95"] >= c["ratio_median"] > 0, name
        assert 0 <= c["branch_jump_share"] <= 1, name
    # paper 000's sampled labels on 8 joints jump branches far more often than labels a solver chose
    for name in ("sup_best", "continuation"):
        assert meta["sup_sets"][name]["consistency"]["branch_jump_share"] < meta["sup_sets"]["sup"]["consistency"][
            "branch_jump_share"], name


def test_the_coupled_set_lies_on_its_couplings(generated, jumbo8):
    holes, meta, cfg = generated
    df = pd.read_parquet(holes / "coupled.parquet")
    q = torch.tensor(df[jumbo8.joint_names].to_numpy())
    assert len(df) == cfg.holes.sup_variants.coupled.size
    assert float((q[:, 1] + q[:, 4]).abs().max()) < 1e-12 and float((q[:, 0] - q[:, 5]).abs().max()) < 1e-12
    assert torch.allclose(jumbo8.pose6(q), torch.tensor(df[POSE_COLUMNS].to_numpy()), atol=1e-12)
    assert meta["sup_sets"]["coupled"]["couplings"] == [dict(r) for r in cfg.holes.sup_variants.coupled.couplings]


def test_the_continuation_set_labels_holes_drawn_like_omega_unsup(generated, jumbo8):
    holes, meta, cfg = generated
    df = pd.read_parquet(holes / "continuation.parquet")
    stats = meta["sup_sets"]["continuation"]
    # a hole no search solved is left out, and the share labelled is reported
    assert len(df) == stats["size"] == round(stats["relabelled_share"] * cfg.holes.sup_variants.continuation.size)
    assert len(df) > 0.8 * cfg.holes.sup_variants.continuation.size
    pose = torch.tensor(df[POSE_COLUMNS].to_numpy())
    assert torch.allclose(jumbo8.pose6(torch.tensor(df[jumbo8.joint_names].to_numpy())), pose, atol=1e-12)
    assert bool(((pose[:, 0] >= 6.0 - 1e-5) & (pose[:, 0] <= 7.0 + 1e-5)).all())  # collars on the face (labels exact)


@pytest.mark.parametrize("name", ["train", "test_group_1", "test_group_5"])
def test_holes_obey_the_sampling_rules(generated, safety, name):
    holes, _, cfg = generated
    df = pd.read_parquet(holes / f"{name}.parquet")
    pose = torch.tensor(df[POSE_COLUMNS].to_numpy())
    p, pp = pose[:, :3], pose[:, 3:]
    tunnel = Horseshoe()
    assert tunnel.contains(p[:, 1], p[:, 2], inset=cfg.holes.inset - 1e-12).all()
    assert ((p[:, 0] >= 6.0) & (p[:, 0] <= 7.0)).all()
    axis = pp - p
    assert torch.allclose(torch.linalg.vector_norm(axis, dim=-1), torch.full((len(df),), 3.3, dtype=torch.float64))
    angle = torch.rad2deg(torch.arccos((axis[:, 0] / 3.3).clamp(-1, 1)))
    assert (angle <= 15.0 + 1e-9).all() and angle.max() > 12  # the cone is filled, not just respected
    clear = safety.tool_body_clearances(p, axis / 3.3)
    assert all((clear[k] >= 0).all() for k in ("wall", "ground", "arch"))


def test_sup_poses_equal_forward_kinematics(generated, jumbo8):
    holes, _, _ = generated
    sup = pd.read_parquet(holes / "sup.parquet")
    q = torch.tensor(sup[jumbo8.joint_names].to_numpy())
    assert jumbo8.within_limits(q).all()
    assert torch.allclose(jumbo8.pose6(q), torch.tensor(sup[POSE_COLUMNS].to_numpy()), atol=1e-12)


def test_test_groups_differ_from_each_other_and_from_training(generated):
    holes, _, _ = generated
    tables = [pd.read_parquet(holes / f"{n}.parquet")[POSE_COLUMNS].to_numpy() for n in
              ["train", "test_group_1", "test_group_2"]]
    assert not np.allclose(tables[0][:len(tables[1])], tables[1]) and not np.allclose(tables[1], tables[2])


@pytest.mark.slow
def test_same_seed_gives_byte_identical_files(generated, tmp_path):
    holes, _, _ = generated
    run(compose([*SMALL, f"paths.data={tmp_path}"]))
    for f in sorted(holes.iterdir()):
        assert (tmp_path / "holes" / f.name).read_bytes() == f.read_bytes(), f.name


@pytest.mark.slow
def test_other_seed_changes_the_data(generated, tmp_path):
    holes, _, _ = generated
    run(compose([*SMALL, "holes.unsup.seed=7", f"paths.data={tmp_path}"]))
    assert (tmp_path / "holes" / "train.parquet").read_bytes() != (holes / "train.parquet").read_bytes()
    assert (tmp_path / "holes" / "test_group_1.parquet").read_bytes() == (holes / "test_group_1.parquet").read_bytes()


@pytest.mark.slow
def test_cone_angle_is_a_config_value(tmp_path):
    run(compose([*SMALL, "holes.cone_deg=5", f"paths.data={tmp_path}"]))
    df = pd.read_parquet(tmp_path / "holes" / "train.parquet")
    axis = df[POSE_COLUMNS[3:]].to_numpy() - df[POSE_COLUMNS[:3]].to_numpy()
    assert math.degrees(np.arccos(np.clip(axis[:, 0] / 3.3, -1, 1)).max()) <= 5 + 1e-9


@pytest.mark.parametrize(
    ("override", "pattern"),
    [
        ("safety.wall=-0.5", r"safety.wall = -0.5: a safety distance cannot be below zero"),
        ("holes.unsup.size=0", r"holes.unsup.size = 0: must be >= 1"),
        ("holes.cone_deg=120", r"holes.cone_deg = 120.0"),
        ("holes.face_x=[7.0,6.0]", r"holes.face_x = \[7.0, 6.0\]"),
        ("holes.test.seeds=[0,102,103,104,105]", r"seeds must all differ"),
        ("holes.sup_variants.continuation.labels=sampled", r"holes.sup_variants.continuation: .*draws no joints"),
        ("holes.sup_variants.coupled.couplings=[{coeffs:{q9:1}}]",
         r"holes.sup_variants.coupled.couplings\[0\].coeffs: 'q9' is not a joint"),
    ],
)
def test_bad_config_is_named_and_nothing_is_overwritten(generated, tmp_path, override, pattern):
    holes, _, _ = generated
    target = tmp_path / "holes"
    target.mkdir()
    keep = target / "train.parquet"
    keep.write_bytes((holes / "train.parquet").read_bytes())
    with pytest.raises(ConfigError, match=pattern):
        run(compose([*SMALL, override, f"paths.data={tmp_path}"]))
    assert keep.read_bytes() == (holes / "train.parquet").read_bytes()
    assert sorted(p.name for p in target.iterdir()) == ["train.parquet"]


@pytest.mark.slow
def test_cli_entry_point(tmp_path):
    """``python -m pipeline.generate`` as a user runs it (a bad override's exit code and message, with the known
    options named: tests/test_exit_codes.py)."""
    cmd = [sys.executable, "-m", "pipeline.generate", *SMALL, f"paths.data={tmp_path}", f"hydra.run.dir={tmp_path}/h"]
    done = subprocess.run(cmd, cwd=PROJECT_ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "holes" / "meta.json").is_file()
