"""Kinematic error compensation (paper 004): error model, measurements, SSA, networks,
identification, model files and the calibrate stage."""

import math

import pandas as pd
import pytest
import torch

from pipeline.calibrate import face_holes, residual_errors
from pipeline.calibrate import run as run_calibrate
from pipeline.calibration.compensation import INITS, NetworkParams, fit_compensator, training_pairs
from pipeline.calibration.error_model import BoomWithErrors, ErrorLevel, draw_errors
from pipeline.calibration.identification import identifiable_basis, identify
from pipeline.calibration.measurements import Measurements, Sensor, read_measurements, simulate, write_measurements
from pipeline.calibration.model_file import load_model, save_model
from pipeline.core.config import compose
from pipeline.core.errors import InputError
from pipeline.data.holes import HoleSampling
from pipeline.geometry.collision import SafetyModel
from pipeline.geometry.rotations import se3_exp
from pipeline.optim.swarm import PSOParams, SSAParams, pso_minimize, rastrigin, sphere, ssa_minimize

FIELD = ErrorLevel(0.2, 0.2, 5.0)
DEG = math.pi / 180


def _joints(boom, n, seed):
    g = torch.Generator().manual_seed(seed)
    lo, hi = boom.limits()
    return lo + torch.rand(n, boom.n_joints, generator=g, dtype=torch.float64) * (hi - lo)


pytestmark = pytest.mark.usefixtures("one_torch_thread")  # the stage's runtime.calibrate_threads


@pytest.fixture(scope="module")
def basis(jumbo8):
    return identifiable_basis(jumbo8, n_poses=60, seed=3)


@pytest.fixture(scope="module")
def face(safety):
    """Face-like joint vectors (nominal NM solutions of face holes) and held-out holes with theirs."""
    ik = compose([]).calibration.ik
    _, q = face_holes(safety, HoleSampling(), 150, 7, ik)
    holes, theta = face_holes(safety, HoleSampling(), 80, 8, ik)
    return q, holes, theta


# ---------------------------------------------------------------- error model
def test_zero_errors_give_exactly_the_nominal_boom(jumbo8, safety):
    q = _joints(jumbo8, 300, 0)
    true = BoomWithErrors(jumbo8, torch.zeros(jumbo8.n_rows, 6, dtype=torch.float64))
    assert torch.equal(true.frames(q), jumbo8.frames(q))
    assert torch.equal(true.frames(q.float()), jumbo8.frames(q.float()))
    twin = SafetyModel(true, safety.tunnel, safety.distances, safety.points_per_capsule, safety.exact)
    for kind, c in twin.clearances(q).items():
        assert torch.equal(c, safety.clearances(q)[kind])


def test_se3_exp_matches_the_matrix_exponential():
    xi = torch.randn(50, 6, generator=torch.Generator().manual_seed(1), dtype=torch.float64) * 0.4
    xi[:10, :3] *= 1e-6  # the small-angle series
    hat = torch.zeros(50, 4, 4, dtype=torch.float64)
    w = xi[:, :3]
    hat[:, 0, 1], hat[:, 0, 2], hat[:, 1, 2] = -w[:, 2], w[:, 1], -w[:, 0]
    hat[:, 1, 0], hat[:, 2, 0], hat[:, 2, 1] = w[:, 2], -w[:, 1], w[:, 0]
    hat[:, :3, 3] = xi[:, 3:]
    assert torch.allclose(se3_exp(xi), torch.linalg.matrix_exp(hat), atol=1e-14)


def test_angle_errors_are_joint_offsets_and_tilts_move_the_axis(jumbo8):
    q = _joints(jumbo8, 50, 2)
    twists = torch.zeros(8, 6, dtype=torch.float64)
    twists[3, 2] = 0.01  # q4's rotation-angle error = its zero offset
    twists[7, 5] = 0.004  # q8's (prismatic) offset along its axis = its length offset
    shifted = q.clone()
    shifted[:, 3] += 0.01
    shifted[:, 7] += 0.004
    assert torch.allclose(BoomWithErrors(jumbo8, twists).frames(q), jumbo8.frames(shifted), atol=1e-12)
    # with tilts and offsets everywhere, joint i still turns about z of frames[i] through its origin
    true = BoomWithErrors(jumbo8, draw_errors(jumbo8, FIELD, 5))
    i, d = 4, 0.3  # turn q5 (row 5) by 0.3 rad
    q2 = q.clone()
    q2[:, i] += d
    F1, F2 = true.frames(q), true.frames(q2)
    axis, origin = F1[:, i + 1, :3, 2], F1[:, i + 1, :3, 3]
    K = torch.zeros(50, 3, 3, dtype=torch.float64)
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -axis[:, 2], axis[:, 1], -axis[:, 0]
    K = K - K.transpose(1, 2)
    R = torch.eye(3, dtype=torch.float64) + math.sin(d) * K + (1 - math.cos(d)) * K @ K  # Rodrigues
    tool1, tool2 = F1[:, -1, :3, 3], F2[:, -1, :3, 3]
    expected = origin + (R @ (tool1 - origin).unsqueeze(-1)).squeeze(-1)
    assert torch.allclose(tool2, expected, atol=1e-12)
    assert not torch.allclose(true.frames(q), jumbo8.frames(q), atol=1e-3)  # the errors do act


def test_error_levels_give_the_papers_magnitudes(jumbo8):
    q = _joints(jumbo8, 400, 3)
    p0, z0 = jumbo8.tool_pose(q)
    p1, z1 = BoomWithErrors(jumbo8, draw_errors(jumbo8, FIELD, 13)).tool_pose(q)
    collar_mm = 1e3 * (p1 - p0).norm(dim=-1).mean()
    assert 20 < collar_mm < 150  # paper 004's real robot: 50 mm before compensation
    twists = draw_errors(jumbo8, ErrorLevel(0.01, 0.01, 0.1), 13)
    assert torch.allclose(twists.abs()[:, :3], torch.full((8, 3), 0.01 * DEG, dtype=torch.float64))
    assert torch.allclose(twists.abs()[:, 3:], torch.full((8, 3), 1e-4, dtype=torch.float64))


# ---------------------------------------------------------------- SSA / PSO
@pytest.mark.parametrize("fn", [sphere, rastrigin])
@pytest.mark.parametrize("shift", [0.0, 1.3])  # shifted: SSA's producers shrink towards 0, so test off-origin too
def test_ssa_finds_the_minimum_of_standard_functions(fn, shift):
    for dim in (2, 5):
        res = ssa_minimize(lambda x: fn(x - shift), -5.12, 5.12, dim, SSAParams(population=30, iterations=200), 0)
        assert res.f < 1e-8 and (res.x - shift).abs().max() < 1e-3
        assert all(a >= b for a, b in zip(res.history, res.history[1:], strict=False))


def test_pso_finds_the_minimum_of_the_sphere():
    res = pso_minimize(lambda x: sphere(x - 1.3), -5.12, 5.12, 3, PSOParams(population=30, iterations=200), 0)
    assert res.f < 1e-8


# ---------------------------------------------------------------- measurements
def test_simulated_noise_has_the_sensor_sigma(jumbo8):
    q = _joints(jumbo8, 4000, 4)
    exact = simulate(jumbo8, q, Sensor(0.0, 0.0), 0)
    noisy = simulate(jumbo8, q, Sensor(1.0, 0.05), 0)
    assert torch.allclose(exact.collar, jumbo8.tool_pose(q)[0])
    assert abs(float((noisy.collar - exact.collar).std()) - 1e-3) < 5e-5
    tilt = torch.linalg.cross(noisy.direction, exact.direction, dim=-1).norm(dim=-1)  # ~ Rayleigh, sigma per axis
    assert abs(float(tilt.pow(2).mean().sqrt()) / (math.sqrt(2) * 0.05 * DEG) - 1) < 0.05


def _good_table(jumbo8, n=3):
    q = _joints(jumbo8, n, 6)
    m = simulate(jumbo8, q, Sensor(0.0, 0.0), 0)
    df = pd.DataFrame(q.numpy(), columns=jumbo8.joint_names)
    for k, c in enumerate(["collar_x", "collar_y", "collar_z"]):
        df[c] = m.collar[:, k].numpy()
    for k, c in enumerate(["dir_x", "dir_y", "dir_z"]):
        df[c] = 2 * m.direction[:, k].numpy()  # any length: normalised on read
    return df, m


def test_measurement_file_round_trip_and_units(jumbo8, tmp_path):
    df, m = _good_table(jumbo8)
    df.to_csv(tmp_path / "m.csv", index=False)
    back = read_measurements(tmp_path / "m.csv", jumbo8)
    assert torch.allclose(back.q, m.q) and torch.allclose(back.collar, m.collar)
    assert torch.allclose(back.direction, m.direction)
    deg = df.copy()
    for j in jumbo8.joints:
        deg[j.name] = df[j.name] / DEG if j.revolute else df[j.name] * 1e3
    for c in ["collar_x", "collar_y", "collar_z"]:
        deg[c] = df[c] * 1e3
    deg.to_csv(tmp_path / "deg.csv", index=False)
    back = read_measurements(tmp_path / "deg.csv", jumbo8, angle_unit="deg", length_unit="mm")
    assert torch.allclose(back.q, m.q) and torch.allclose(back.collar, m.collar)
    write_measurements(back, jumbo8, tmp_path / "w.csv")
    assert torch.allclose(read_measurements(tmp_path / "w.csv", jumbo8).q, m.q)


def _set(col, row, value):
    return lambda df: df.assign(**{col: df[col].astype(object).where(df.index != row, value)})


@pytest.mark.parametrize("edit, message", [
    (lambda df: df.drop(columns=["dir_y"]), r"missing column\(s\) \['dir_y'\]"),
    (_set("q5", 1, "abc"), r"row 2 \(line 3\), column 'q5'.*'abc'"),
    (_set("collar_z", 2, float("inf")), r"row 3 \(line 4\), column 'collar_z'"),
    (_set("q2", 0, float("nan")), r"row 1 \(line 2\), column 'q2'"),
    (lambda df: df.drop(columns=["q8"]), r"joint columns \['q1'.*'q7'\] do not match boom 'jumbo8', which has 8"),
    (lambda df: df.assign(q9=0.0), r"do not match boom 'jumbo8'"),
    (lambda df: _set("dir_z", 1, 0.0)(df.assign(dir_x=0.0, dir_y=0.0)), r"row 2 \(line 3\).*zero"),
    (_set("q1", 0, 40.0), r"row 1 \(line 2\), column 'q1'.*outside the joint range"),
])
def test_bad_measurement_files_name_file_row_and_column(jumbo8, tmp_path, edit, message):
    df, _ = _good_table(jumbo8)
    path = tmp_path / "bad.csv"
    edit(df).to_csv(path, index=False)
    with pytest.raises(InputError, match=message) as info:
        read_measurements(path, jumbo8)
    assert str(path) in str(info.value)


# ---------------------------------------------------------------- identification
def test_identifiable_basis_merges_aliased_parameters(jumbo8, basis):
    merged = basis.merged
    assert len(basis.kept) == 31  # jumbo8, collar + direction: 48 components, 17 aliased or invisible
    # independent check: rank of a central-difference Jacobian of BoomWithErrors' collar and direction
    q, eps, cols = _joints(jumbo8, 60, 14), 1e-6, []
    for k in range(48):
        t = torch.zeros(48, dtype=torch.float64)
        t[k] = eps
        (p1, z1), (p0, z0) = (BoomWithErrors(jumbo8, s.reshape(8, 6)).tool_pose(q) for s in (t, -t))
        cols.append(torch.cat([p1 - p0, 10 * (z1 - z0)], -1).reshape(-1) / (2 * eps))
    J = torch.stack(cols, -1)
    sv = torch.linalg.svdvals(J / J.norm(dim=0).clamp_min(1e-30))  # q8.rz moves nothing: a zero column
    assert int((sv > 1e-6 * sv[0]).sum()) == 31 and sv[30] > 1e-3 * sv[0]
    assert merged["q3.rz"] == [("q4.rz", pytest.approx(1.0, abs=1e-6))]  # extension tube roll = q4 rotation
    assert merged["q8.rz"] == []  # roll about the drill axis: invisible
    assert "q4.rz" in basis.kept_names and "q8.tz" in basis.kept_names


def test_identification_recovers_injected_errors_without_noise(jumbo8, basis):
    q = _joints(jumbo8, 40, 9)
    truth = torch.zeros(48, dtype=torch.float64)
    truth[basis.kept] = draw_errors(jumbo8, FIELD, 21, "normal").reshape(-1)[basis.kept]
    true = BoomWithErrors(jumbo8, truth.reshape(8, 6))
    fit = identify(jumbo8, simulate(true, q, Sensor(0.0, 0.0), 0), basis)
    assert torch.allclose(fit.twists, true.twists, atol=1e-10)
    assert fit.rank == 31 and fit.collar_rms_mm < 1e-8
    # every component wrong (aliased ones too): the merged basis still reproduces the boom at new poses
    true = BoomWithErrors(jumbo8, draw_errors(jumbo8, FIELD, 22))
    fit = identify(jumbo8, simulate(true, q, Sensor(0.0, 0.0), 0), basis)
    q_new = _joints(jumbo8, 100, 10)
    p_fit, z_fit = BoomWithErrors(jumbo8, fit.twists).tool_pose(q_new)
    p_true, z_true = true.tool_pose(q_new)
    assert (p_fit - p_true).norm(dim=-1).max() < 1e-9 and (z_fit - z_true).norm(dim=-1).max() < 1e-11


def test_unidentifiable_setups_raise_clear_errors(jumbo8, basis):
    q = _joints(jumbo8, 40, 11)
    m = simulate(jumbo8, q, Sensor(0.0, 0.0), 0)
    with pytest.raises(InputError, match=r"5 measurement\(s\) give 25 equations .* 31 identifiable parameters; need at "
                                         r"least 7"):
        identify(jumbo8, m.subset(slice(0, 5)), basis)
    same = Measurements(q[:1].expand(40, -1), m.collar[:1].expand(40, -1), m.direction[:1].expand(40, -1), "one pose")
    with pytest.raises(InputError, match=r"one pose: the 40 measurement poses cannot separate .*rank 5 of 31"):
        identify(jumbo8, same, basis)
    frozen = q.clone()
    frozen[:, 6] = 0.0  # the roll-over joint never moves
    fm = simulate(jumbo8, frozen, Sensor(0.0, 0.0), 0)
    with pytest.raises(InputError, match=r"cannot separate .*q7"):
        identify(jumbo8, fm, basis)
    bad = Measurements(m.q, m.collar.clone(), m.direction, "nan data")
    bad.collar[3, 1] = float("nan")
    with pytest.raises(InputError, match="nan data: non-finite collar in measurement row 4"):
        identify(jumbo8, bad, basis)


# ---------------------------------------------------------------- compensation
def test_each_network_lowers_the_held_out_error(jumbo8, safety, face):
    q, holes, theta_h = face
    true = BoomWithErrors(jumbo8, draw_errors(jumbo8, FIELD, 13))
    measured = simulate(true, q, Sensor(), 1)
    theta, qq, ok = training_pairs(jumbo8, measured)
    assert ok.float().mean() > 0.95
    before = residual_errors(true, safety, theta_h, holes)["collar_mm_mean"]
    params = NetworkParams(iterations=100)  # the paper's settings: gradient descent, lr 0.1, 8 hidden
    swarm = {"pso": PSOParams(population=20, iterations=20), "ssa": SSAParams(population=20, iterations=20)}
    after = {}
    for method in INITS:
        comp = fit_compensator(theta[ok], qq[ok], params, method, 0, **swarm)
        after[method] = residual_errors(true, safety, comp(theta_h), holes)["collar_mm_mean"]
    assert all(v < 0.6 * before for v in after.values()), (before, after)


# ---------------------------------------------------------------- model file and stage
def test_model_file_round_trip_and_errors(jumbo8, tmp_path):
    twists = draw_errors(jumbo8, FIELD, 3, "normal")
    save_model(tmp_path / "m.yaml", jumbo8, twists, ["q1.rx"], {"n_measurements": 10})
    model = load_model(tmp_path / "m.yaml")
    assert isinstance(model, BoomWithErrors) and model.name == "jumbo8"
    assert torch.allclose(model.twists, twists, rtol=1e-14, atol=0)
    text = (tmp_path / "m.yaml").read_text()
    (tmp_path / "bad.yaml").write_text(text.replace("    tz:", "    tzz:", 1))
    with pytest.raises(InputError, match=r"bad.yaml: errors.q1 must give"):
        load_model(tmp_path / "bad.yaml")
    (tmp_path / "other.yaml").write_text(text.replace("boom: jumbo8", "boom: nosuch"))
    with pytest.raises(InputError, match=r"other.yaml: boom = 'nosuch'"):
        load_model(tmp_path / "other.yaml")


@pytest.mark.slow
def test_calibrate_stage_end_to_end_and_field_fit(jumbo8, tmp_path, make_cfg):
    df = run_calibrate(make_cfg(tmp_path))  # experiment=tiny: the field level, 10 and 40 measurements
    out = tmp_path / "data" / "calibration"
    table = pd.read_csv(out / "results.csv")
    assert list(table.columns[:6]) == ["method", "level", "n_measurements", "collar_mm_mean", "collar_mm_max",
                                       "direction_deg_mean"]
    assert len(table) == len(df) == 10 and set(table["method"]) == {"uncompensated", "bp", "pso-bp", "ssa-bp",
                                                                    "identification"}
    assert table[["collar_mm_mean", "collar_mm_max", "direction_deg_mean"]].notna().all().all()
    ident = table[(table["method"] == "identification") & (table["n_measurements"] == 40)].iloc[0]
    unc = table[table["method"] == "uncompensated"].iloc[0]
    assert ident["collar_mm_mean"] < 0.1 * unc["collar_mm_mean"]
    assert (out / "figures" / "residual_vs_measurements.png").stat().st_size > 10_000
    assert isinstance(load_model(out / "models" / "identified_field.yaml"), BoomWithErrors)
    from mlflow.tracking import MlflowClient

    client = MlflowClient(f"sqlite:///{tmp_path}/mlflow.db")
    (run,) = client.search_runs([client.get_experiment_by_name("boom-ik-tiny").experiment_id])
    assert run.data.metrics["field.identification.n40.collar_mm_mean"] == pytest.approx(ident["collar_mm_mean"])
    # field mode: a measurement file in degrees and millimetres -> an identified model file
    true = load_model(out / "models" / "true_field.yaml")
    q = _joints(jumbo8, 60, 12)
    fit_cfg = make_cfg(tmp_path, "tracking.enabled=false", f"measurements={tmp_path}/field.csv",
                       f"calibration.model_file={tmp_path}/fitted.yaml")
    # noise-free data fitted as a 1 mm instrument: below the noise, the quality gate refuses it
    write_measurements(simulate(true, q, Sensor(0.0, 0.0), 0), jumbo8, tmp_path / "field.csv")
    with pytest.raises(InputError, match=r"calibration fit rejected.*noise: .*below the instrument's noise"):
        run_calibrate(fit_cfg)
    assert not (tmp_path / "fitted.yaml").exists()
    write_measurements(simulate(true, q, Sensor(1.0, 0.05), 0), jumbo8, tmp_path / "field.csv")  # a total station
    run_calibrate(fit_cfg)
    model = load_model(tmp_path / "fitted.yaml")
    q_new = _joints(jumbo8, 50, 13)
    assert (model.tool_pose(q_new)[0] - true.tool_pose(q_new)[0]).norm(dim=-1).mean() < 1e-3
