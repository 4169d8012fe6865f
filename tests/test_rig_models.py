"""Which model each rig boom drills with (docs/rig.md): the composed ``boom`` node (``boom.*`` overrides),
``boom_model`` (a calibrated model: every boom of its kind), ``boom_models`` (one per boom); and a missing
or bad model file refused by name before any work in solve, schedule and move_benchmark alike."""

import pytest
import torch

from pipeline import move_benchmark, schedule, solve
from pipeline.assembly.rig import composed_rig
from pipeline.calibration.error_model import BoomWithErrors
from pipeline.calibration.model_file import load_model, model_setting, save_model
from pipeline.core.config import compose
from pipeline.core.errors import ConfigError

D = torch.float64
Q = torch.tensor([0.1, 0.2, 3.6, 0.3, -0.1, 0.05, 0.4, 1.5], dtype=D)  # a configuration in range (rad, m)


def _collar(boom, q=Q):
    return boom.tool_pose(q)[0]


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory, jumbo8):
    """A calibrated jumbo8: 0.2 deg and 3 mm error twists on three rows (a few cm at the collar)."""
    twists = torch.zeros(jumbo8.n_rows, 6, dtype=D)
    twists[1, :3] = torch.tensor([0.0035, -0.002, 0.003], dtype=D)
    twists[2, 3:] = torch.tensor([0.003, -0.003, 0.002], dtype=D)
    twists[5, :3] = torch.tensor([-0.003, 0.0035, 0.0], dtype=D)
    path = tmp_path_factory.mktemp("models") / "calibrated.yaml"
    save_model(path, jumbo8, twists)
    return path


def test_a_boom_override_reaches_every_boom_of_a_rig(jumbo8):
    """boom.dh.7.a (the feed's D-H length, 0.8 m) at 0.9 m: each rig boom's collar moves by exactly the
    0.1 m of the change (a translation along its last frame's x axis), at any joints."""
    rig = composed_rig(compose(["rig=twin", "boom.dh.7.a=0.9"]))
    for mount in rig.booms:
        moved = (_collar(mount.boom) - _collar(jumbo8)).norm()
        assert float(moved) == pytest.approx(0.1, abs=1e-12), mount.name
    nominal = composed_rig(compose(["rig=twin"]))
    assert all(float((_collar(m.boom) - _collar(jumbo8)).norm()) == 0.0 for m in nominal.booms)


def test_boom_model_calibrates_every_boom_of_its_kind(calibrated, jumbo8):
    rig = composed_rig(compose(["rig=twin", f"boom_model={calibrated}"]), model_setting)
    model = load_model(calibrated, jumbo8)
    for mount in rig.booms:
        assert isinstance(mount.boom, BoomWithErrors), mount.name
        assert torch.equal(_collar(mount.boom), _collar(model))
        assert float((_collar(mount.boom) - _collar(jumbo8)).norm()) > 0.005  # differs from nominal
        # frames in the rig frame follow the calibrated chain, shifted by the base only
        assert torch.allclose(mount.frames(Q)[..., :3, 3] - torch.tensor(mount.base, dtype=D),
                              model.frames(Q)[..., :3, 3], atol=1e-15)


def test_boom_models_calibrates_one_boom_by_name(calibrated, jumbo8):
    rig = composed_rig(compose(["rig=twin", f"boom_models={{L: {calibrated}}}"]), model_setting)
    L, R = rig.booms
    assert isinstance(L.boom, BoomWithErrors) and not isinstance(R.boom, BoomWithErrors)
    assert torch.equal(_collar(R.boom), _collar(jumbo8))


def test_a_calibrated_model_sits_on_the_composed_boom(calibrated, jumbo8):
    """The model's twists apply on top of the composed boom of its kind, `boom.*` overrides included."""
    rig = composed_rig(compose(["rig=twin", "boom.dh.7.a=0.9", f"boom_model={calibrated}"]), model_setting)
    nominal = rig.booms[0].boom.nominal
    assert float((_collar(nominal) - _collar(jumbo8)).norm()) == pytest.approx(0.1, abs=1e-12)


@pytest.mark.parametrize(("overrides", "message"), [
    (["boom_model=/no/such/file.yaml"], r"^boom_model = '/no/such/file\.yaml': .*no such boom model file"),
    (["boom_model=conf"], r"^boom_model = 'conf': .*no such boom model file"),  # a folder
    (["boom_models={X: a.yaml}"], r"^boom_models: no boom \['X'\] in rig 'twin' \(conf/rig/twin\.yaml\)"),
    (["boom_models={L: /no/such.yaml}"], r"^boom_models\.L = '/no/such\.yaml': "),
    (["boom_models=[a.yaml]"], r"^boom_models = \['a\.yaml'\]: expected a mapping rig boom name -> model file"),
])
def test_bad_boom_models_name_the_setting(overrides, message):
    with pytest.raises(ConfigError, match=message):
        composed_rig(compose(["rig=twin", *overrides]), model_setting)


def test_a_model_file_that_is_not_a_model_names_boom_model(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("format: something-else\n")
    with pytest.raises(ConfigError, match=r"^boom_model = '.*bad\.yaml': .*format = 'something-else'"):
        composed_rig(compose(["rig=twin", f"boom_model={bad}"]), model_setting)


def test_a_model_of_another_kind_is_refused_for_the_rig(tmp_path, jumbo8):
    """Kinds: a composed boom renamed jumbo8b is another kind. A jumbo8b model on twin (two jumbo8) is
    refused; on a rig whose R is a jumbo8b, a jumbo8 model for R is refused, and so is the jumbo8 motion."""
    from pipeline.assembly.build import load_boom
    from pipeline.motion.timing import rig_motions

    other = load_boom(compose(["boom.name=jumbo8b"]).boom)
    path = tmp_path / "b.yaml"
    save_model(path, other, torch.zeros(other.n_rows, 6, dtype=D))
    with pytest.raises(ConfigError, match=r"^boom_model = .*a model of boom 'jumbo8b', but rig 'twin' .*\['jumbo8'\]"):
        composed_rig(compose(["rig=twin", "boom.name=jumbo8b", f"boom_model={path}"]), model_setting)
    mixed = ["rig=twin", "boom.name=jumbo8b", "rig.booms.1.boom=jumbo8b"]
    rig = composed_rig(compose(mixed))
    assert [m.boom.name for m in rig.booms] == ["jumbo8", "jumbo8b"]
    jumbo = tmp_path / "j.yaml"
    save_model(jumbo, jumbo8, torch.zeros(jumbo8.n_rows, 6, dtype=D))
    with pytest.raises(ConfigError, match=r"^boom_models\.R = .*a model of boom 'jumbo8', but boom 'R' .* is a "
                                          r"'jumbo8b'"):
        composed_rig(compose([*mixed, f"boom_models={{R: {jumbo}}}"]), model_setting)
    with pytest.raises(ConfigError, match=r"^rig boom 'R' \(a 'jumbo8b'\): motion\.boom = 'jumbo8'"):
        rig_motions(compose(mixed).motion, rig.booms)


@pytest.mark.parametrize("stage", [schedule, solve, move_benchmark])
@pytest.mark.parametrize("rig", ["single", "twin"])
def test_every_stage_refuses_a_missing_boom_model_before_any_work(stage, rig, tmp_path, make_cfg):
    """No plan exists: the model file is checked before the plan is read (or anything is written)."""
    if stage is move_benchmark and rig == "single":
        rig = "trio"  # the move benchmark needs two booms
    cfg = make_cfg(tmp_path, f"rig={rig}", "boom_model=/no/such/file.yaml", f"plan={tmp_path}/none.csv",
                   f"out={tmp_path}/out/x.csv")
    with pytest.raises(ConfigError, match=r"^boom_model = '/no/such/file\.yaml'"):
        stage.run(cfg)
    assert not [p for p in tmp_path.rglob("*") if p.is_file()]  # nothing written (solve makes out's folder)
