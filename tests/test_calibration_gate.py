"""The calibration quality gate: a careless or hostile measurement file never becomes the boom model."""

import math

import pytest
import torch

from pipeline.calibrate import run as run_calibrate
from pipeline.calibration.error_model import BoomWithErrors, ErrorLevel, draw_errors
from pipeline.calibration.identification import Weights, identifiable_basis, identify
from pipeline.calibration.measurements import Measurements, Sensor, simulate, write_measurements
from pipeline.calibration.model_file import load_model, save_model
from pipeline.calibration.quality import GateSettings, assess, duplicate_rows
from pipeline.core.config import compose
from pipeline.core.errors import ConfigError, InputError

FIELD = ErrorLevel(angle_deg=0.2, tilt_deg=0.2, offset_mm=5.0)  # the field level of conf/calibration/level
TOTAL_STATION = Sensor(1.0, 0.05)  # the instrument the default weights describe


pytestmark = pytest.mark.usefixtures("one_torch_thread")  # the stage's runtime.calibrate_threads


def _joints(boom, n, seed):
    g = torch.Generator().manual_seed(seed)
    lo, hi = boom.limits()
    return lo + torch.rand(n, boom.n_joints, generator=g, dtype=torch.float64) * (hi - lo)


@pytest.fixture(scope="module")
def basis(jumbo8):
    return identifiable_basis(jumbo8, n_poses=60, seed=0)


@pytest.fixture(scope="module")
def true_boom(jumbo8):
    return BoomWithErrors(jumbo8, draw_errors(jumbo8, FIELD, seed=13))


@pytest.fixture(scope="module")
def good(jumbo8, true_boom):
    return simulate(true_boom, _joints(jumbo8, 60, 12), TOTAL_STATION, seed=3)


def _gate(jumbo8, basis, meas, settings: GateSettings | None = None):
    fit = identify(jumbo8, meas, basis)
    return fit, assess(jumbo8, meas, basis, Weights(), fit, settings or GateSettings())


def test_a_sound_field_fit_passes_every_rule_and_is_accurate(jumbo8, basis, good, true_boom):
    fit, report = _gate(jumbo8, basis, good)
    assert report.accepted, report.as_dict()
    noise = next(r for r in report.rules if r.name == "noise")
    assert 0.8 < noise.value < 1.2  # the residual is the instrument's noise, as the weights say
    q = _joints(jumbo8, 200, 99)  # new poses: the identified model is close to the true boom
    err = (BoomWithErrors(jumbo8, fit.twists).tool_pose(q)[0] - true_boom.tool_pose(q)[0]).norm(dim=-1)
    assert float(err.mean()) < 1e-3


def _edited(meas: Measurements, **kw) -> Measurements:
    return Measurements(kw.get("q", meas.q), kw.get("collar", meas.collar), kw.get("direction", meas.direction),
                        "edited.csv")


def test_collars_in_millimetres_are_rejected_with_the_cause(jumbo8, basis, good):
    _, report = _gate(jumbo8, basis, _edited(good, collar=good.collar * 1e3))
    assert not report.accepted and "noise" in report.failed
    assert any("millimetres" in c for c in report.causes)


def test_swapped_collar_and_direction_columns_are_rejected(jumbo8, basis, good):
    _, report = _gate(jumbo8, basis, _edited(good, collar=good.direction.clone(),
                                             direction=good.collar / good.collar.norm(dim=-1, keepdim=True)))
    assert not report.accepted and any("swapped" in c for c in report.causes)


def test_ten_degrees_of_noise_on_one_joint_is_rejected(jumbo8, basis, good):
    g = torch.Generator().manual_seed(5)
    q = good.q.clone()
    q[:, 4] += math.radians(10.0) * torch.randn(len(q), generator=g, dtype=q.dtype)
    _, report = _gate(jumbo8, basis, _edited(good, q=q))
    assert not report.accepted and "noise" in report.failed


def test_a_huge_collar_is_never_called_identified(jumbo8, basis, good):
    collar = good.collar.clone()
    collar[7, 0] = 1e308
    _, report = _gate(jumbo8, basis, _edited(good, collar=collar))
    assert not report.accepted and "noise" in report.failed
    assert any("row(s) [8]" in c for c in report.causes)


def test_seven_poses_overfit_and_are_rejected(jumbo8, basis, good):
    fit, report = _gate(jumbo8, basis, good.subset(slice(0, 7)))
    assert fit.collar_rms_mm < 1.0  # below the instrument's 1.7 mm (3-D): the fit follows the noise
    assert not report.accepted and "poses" in report.failed
    assert any("follows the noise" in c for c in report.causes)


def test_duplicated_poses_are_refused_or_warned(jumbo8, basis, good):
    dup = Measurements(torch.cat([good.q, good.q[:2]]), torch.cat([good.collar, good.collar[:2]]),
                       torch.cat([good.direction, good.direction[:2]]), "dup.csv")
    assert duplicate_rows(dup) == [[0, 60], [1, 61]]
    _, refused = _gate(jumbo8, basis, dup)
    assert "duplicates" in refused.failed
    _, warned = _gate(jumbo8, basis, dup, GateSettings(duplicates="warn"))
    assert warned.accepted and "rows 1, 61" in warned.warnings[0]


def test_gate_settings_are_checked(jumbo8):
    with pytest.raises(ConfigError, match=r"calibration.gate.residual_ratio"):
        GateSettings.from_config({"residual_ratio": [1.5, 3.0]})
    with pytest.raises(ConfigError, match=r"calibration.gate.duplicates = 'keep'"):
        GateSettings.from_config({"duplicates": "keep"})


@pytest.mark.slow
def test_a_rejected_fit_leaves_the_current_model_and_exits_with_the_report(jumbo8, good, tmp_path):
    model = tmp_path / "boom_model.yaml"
    save_model(model, jumbo8, torch.zeros(jumbo8.n_rows, 6, dtype=torch.float64), fit={"note": "the good one"})
    before = model.read_bytes()
    write_measurements(_edited(good, collar=good.collar * 1e3), jumbo8, tmp_path / "mm.csv")
    cfg = compose([f"paths.data={tmp_path}/data", "tracking.enabled=false", f"measurements={tmp_path}/mm.csv",
                   f"calibration.model_file={model}", "calibration.identification.basis_poses=60"])
    with pytest.raises(InputError, match=r"mm.csv: calibration fit rejected, the model file was not changed\. "
                                         r"noise: .*millimetres.*boom_model.rejected.yaml"):
        run_calibrate(cfg)
    assert model.read_bytes() == before
    assert "noise:" in (tmp_path / "boom_model.rejected.yaml").read_text()
    write_measurements(good, jumbo8, tmp_path / "good.csv")
    run_calibrate(compose([f"paths.data={tmp_path}/data", "tracking.enabled=false", f"measurements={tmp_path}/good.csv",
                           f"calibration.model_file={model}", "calibration.identification.basis_poses=60"]))
    assert model.read_bytes() != before and isinstance(load_model(model), BoomWithErrors)
    assert not (tmp_path / "boom_model.rejected.yaml").exists()
