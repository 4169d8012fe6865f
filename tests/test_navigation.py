"""Navigation: the pose's conventions against matrices built by hand, the fit against a known pose and a second
solver (numpy's SVD), its refusals, holes far from the rig, and the product stages on a plan in its own frame
(a vendor file in mine coordinates, a D-shaped drift, three measured points)."""

import json
import math
import time

import numpy as np
import pandas as pd
import pytest
from vendor_iredes import placement, vendor_drpplan

from pipeline.core.errors import ConfigError, InputError
from pipeline.core.settings import parse
from pipeline.plans.csv_plan import write_csv_plan
from pipeline.plans.model import COORDS, DrillPlan
from pipeline.plans.navigation import (
    IDENTITY,
    NavigationSettings,
    fit_pose,
    in_rig_frame,
    pose_from_angles,
    rig_pose,
)

D_SHAPE = "conf/tunnel/profiles/d_5x5.csv"


def rx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def ry(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def kabsch(rig: np.ndarray, plan: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rigid least-squares fit plan ~ R rig + t by numpy's SVD (a second solver beside scipy's)."""
    a, b = rig - rig.mean(0), plan - plan.mean(0)
    u, _, vt = np.linalg.svd(a.T @ b)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    R = vt.T @ np.diag([1, 1, d]) @ u.T
    return R, plan.mean(0) - R @ rig.mean(0)


def write_points(path, names, plan, rig):
    df = pd.DataFrame({"point": names, **{f"plan_{a}": plan[:, i] for i, a in enumerate("xyz")},
                       **{f"rig_{a}": rig[:, i] for i, a in enumerate("xyz")}})
    df.to_csv(path, index=False)
    return path


# reference prisms as a surveyor leaves them: on both walls and the roof, from 10 m behind the rig to the last
# round's markers 1.5 m short of the face (docs/plans_to_rig.md, "How good a measured pose is")
PRISMS_RIG = np.array([[-10.0, 2.4, 1.5], [5.0, -2.4, 3.0], [4.5, 2.4, 1.2], [-10.0, -2.4, 3.2], [-2.0, 0.5, 4.8]])
TRUE = [478_100.0, 6_771_700.0, 240.0, 37.5, 1.2, -0.8]  # the rig in mine coordinates: x y z, yaw pitch roll


# --- conventions -------------------------------------------------------------------------------------------------

def test_the_pose_is_rz_ry_rx_and_a_plan_point_goes_to_rig_by_the_transpose():
    pose = pose_from_angles([1.0, -2.0, 0.5, 30.0, 10.0, -20.0])
    R = rz(math.radians(30)) @ ry(math.radians(10)) @ rx(math.radians(-20))
    np.testing.assert_allclose(pose.R, R, atol=1e-15)
    p = np.array([[7.0, 1.0, 2.0], [0.0, 0.0, 0.0]])
    np.testing.assert_allclose(pose.to_rig(p), (p - [1.0, -2.0, 0.5]) @ R, atol=1e-12)
    np.testing.assert_allclose(pose.to_plan(pose.to_rig(p)), p, atol=1e-12)
    np.testing.assert_allclose(pose.to_plan(np.zeros(3)), [1.0, -2.0, 0.5])  # the rig's origin is (x, y, z)
    np.testing.assert_allclose(pose.as_pose(), [1.0, -2.0, 0.5, 30.0, 10.0, -20.0], atol=1e-12)
    # a pure yaw of 90 degrees: the rig's x axis (toward the face) is the plan's y axis
    np.testing.assert_allclose(pose_from_angles([0, 0, 0, 90, 0, 0]).to_plan(np.array([1.0, 0, 0])), [0, 1, 0],
                               atol=1e-15)


def test_settings_are_checked_before_any_work():
    with pytest.raises(ConfigError, match="give navigation.pose or navigation.points, not both"):
        parse(NavigationSettings, {"pose": [0, 0, 0, 0, 0, 0], "points": "p.csv"}, "navigation")
    with pytest.raises(ConfigError, match=r"navigation.pose = \[1.0, 2.0\]: expected \[x, y, z, yaw, pitch, roll\]"):
        parse(NavigationSettings, {"pose": [1, 2]}, "navigation")
    with pytest.raises(ConfigError, match=r"navigation.max_rms_m = 0"):
        parse(NavigationSettings, {"max_rms_m": 0}, "navigation")
    assert rig_pose(parse(NavigationSettings, {}, "navigation")) is IDENTITY


# --- the fit -----------------------------------------------------------------------------------------------------

def test_the_fit_recovers_a_known_pose_and_agrees_with_a_second_solver(tmp_path):
    true = pose_from_angles(TRUE)
    plan = true.to_plan(PRISMS_RIG)
    fitted = fit_pose(write_points(tmp_path / "p.csv", list("ABCDE"), plan, PRISMS_RIG))
    np.testing.assert_allclose(fitted.R, true.R, atol=1e-12)
    np.testing.assert_allclose(fitted.t, true.t, atol=1e-7)  # 1e-7 m on a 6.8e6 m coordinate
    assert fitted.fit["rms_m"] < 1e-7 and fitted.fit["points"] == 5
    g = np.random.default_rng(0)
    noisy = PRISMS_RIG[:4] + g.normal(0, 0.003, (4, 3))
    fitted = fit_pose(write_points(tmp_path / "n.csv", list("ABCD"), plan[:4], noisy))
    R, t = kabsch(noisy, plan[:4])
    np.testing.assert_allclose(fitted.R, R, atol=1e-10)
    np.testing.assert_allclose(fitted.t, t, atol=1e-6)
    residual = np.linalg.norm(plan[:4] - (noisy @ R.T + t), axis=1)
    assert fitted.fit["rms_m"] == pytest.approx(float(np.sqrt(np.mean(residual**2))), abs=1e-9)
    assert fitted.fit["worst_point"] == "ABCD"[int(residual.argmax())]


@pytest.mark.parametrize("n_points", [3, 4, 5])
def test_three_to_five_points_with_3_mm_noise_put_every_face_hole_within_10_mm(tmp_path, n_points):
    """The issue's target at the pose level: 200 draws of 3 mm noise (rms of each measured point's 3-D error,
    1.73 mm per axis) on the prisms; a face hole's collar and toe (x 6-11 m, anywhere in the 5 x 5 m drift) land
    where the fitted pose puts them, at most 10 mm from where the true pose does. The solver's own error
    (<= 0.01 mm on an ok hole) adds to it. (3 mm per axis, or prisms only behind the rig, miss it: the table in
    docs/plans_to_rig.md.)"""
    true = pose_from_angles(TRUE)
    plan = true.to_plan(PRISMS_RIG[:n_points])
    g = np.random.default_rng(n_points)
    face = np.stack(np.meshgrid([6.0, 8.5, 11.0], [-2.2, 0.0, 2.2], [0.3, 2.5, 4.8]), -1).reshape(-1, 3)
    worst, spent = 0.0, []
    for k in range(200):
        measured = PRISMS_RIG[:n_points] + g.normal(0, 0.003 / math.sqrt(3), (n_points, 3))
        path = write_points(tmp_path / f"p{k}.csv", [f"P{i}" for i in range(n_points)], plan, measured)
        start = time.perf_counter()
        fitted = fit_pose(path)
        spent.append(time.perf_counter() - start)
        worst = max(worst, float(np.linalg.norm(fitted.to_rig(true.to_plan(face)) - face, axis=1).max()))
    assert worst <= 0.010, f"{n_points} points: a face point {1000 * worst:.1f} mm off"
    assert worst > 0.0005  # the noise does reach the face: the bound is not met vacuously


@pytest.mark.parametrize(("rows", "message"), [
    (2, r"2 reference point\(s\); a pose needs at least three not on one line"),
    ("line", r"the points lie on one line \(the farthest, '[ABCD]', is 0.000 m from it; "
             r"navigation.min_off_line_m = 0.2\)"),
    ("outlier", r"rms residual is 0.0[0-9]+ m, over navigation.max_rms_m = 0.02 m; the worst point is 'C'"),
])
def test_a_fit_that_cannot_be_trusted_is_refused_naming_the_point(tmp_path, rows, message):
    true = pose_from_angles(TRUE)
    rig = PRISMS_RIG[:4].copy()
    if rows == 2:
        rig = rig[:2]
    elif rows == "line":
        rig = np.array([[-4.0, 2.4, 1.8], [-8.0, 2.4, 1.8], [0.0, 2.4, 1.8], [-2.0, 2.4, 1.8]])
    plan = true.to_plan(rig)
    if rows == "outlier":
        rig[2] += [0.0, 0.12, 0.0]  # one prism measured 12 cm off
    with pytest.raises(InputError, match=message):
        fit_pose(write_points(tmp_path / "p.csv", list("ABCD")[: len(rig)], plan, rig))


@pytest.mark.parametrize(("text", "message"), [
    ("point,plan_x,plan_y,plan_z,rig_x,rig_y\nA,1,2,3,4,5\n", r"without column\(s\) \['rig_z'\]"),
    ("point,plan_x,plan_y,plan_z,rig_x,rig_y,rig_z\nA,1,2,3,4,5,6\nB,1,x,3,4,5,6\n",
     r"row 3, point 'B', column plan_y: 'x' is not a finite number"),
    ("point,plan_x,plan_y,plan_z,rig_x,rig_y,rig_z\nA,1,2,3,4,5,6\nA,2,2,3,4,5,6\n",
     r"row 3: point 'A' again \(first at row 2\)"),
])
def test_a_bad_points_file_is_refused_naming_the_row(tmp_path, text, message):
    (tmp_path / "p.csv").write_text(text)
    with pytest.raises(InputError, match=message):
        fit_pose(tmp_path / "p.csv")


# --- holes far from the rig ---------------------------------------------------------------------------------------

def _plan(rows) -> DrillPlan:
    holes = pd.DataFrame(rows, columns=["hole_id", *COORDS])
    return DrillPlan(holes, source="p.csv", lines=np.arange(2, 2 + len(rows)))


def test_a_plan_in_another_frame_without_navigation_names_its_far_holes():
    near, far = ["A", 6.5, 0, 1.5, 10, 0, 1.5], ["B", 478_106.5, 6_771_700.0, 241.5, 478_110, 6_771_700.0, 241.5]
    plan = in_rig_frame(_plan([near, far]), IDENTITY)
    assert plan.holes["hole_id"].tolist() == ["A"]
    (p,) = plan.problems
    assert (p.row, p.hole_id, p.column) == (3, "B", "navigation") and "needs navigation.pose" in p.message
    assert plan.rejected["hole_id"].tolist() == ["B"] and plan.rejected["line"].tolist() == [3]
    with pytest.raises(InputError, match=r"p.csv: no usable hole in 1 row\(s\): row 2, hole 'B'"):
        in_rig_frame(_plan([far]), IDENTITY)
    moved = in_rig_frame(_plan([far]), pose_from_angles([478_100.0, 6_771_700.0, 240.0, 0, 0, 0]))
    np.testing.assert_allclose(moved.holes[COORDS].to_numpy()[0], [6.5, 0, 1.5, 10, 0, 1.5], atol=1e-9)


# --- the stages ---------------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def d_face(tmp_path_factory):
    """The designer's face for the D-shaped drift (rig frame), 14 holes of it."""
    from pipeline.assembly.build import build_safety
    from pipeline.plans.demo_face import demo_face

    safety = build_safety("jumbo8", {"kind": "profile", "file": D_SHAPE},
                          {"self": 0.1, "wall": 0.5, "ground": 0.1, "arch": 0.1})
    return demo_face(safety=safety).holes.iloc[::4].reset_index(drop=True)


@pytest.mark.slow
def test_a_vendor_plan_in_mine_coordinates_is_solved_through_three_measured_points(tiny_study, make_cfg, d_face):
    """The worked example of docs/plans_to_rig.md: an Epiroc-style file whose TMatrix places a local plan in
    mine coordinates, the rig navigated by three measured prisms, a D-shaped drift. Every hole is solved in
    the rig frame and reported back in the plan's: each solved collar and toe equals the file's hole (mine
    coordinates) to the solver's tolerance; the JSON and MLflow hold the fit."""
    from mlflow.tracking import MlflowClient

    from pipeline import solve

    true = pose_from_angles(TRUE)
    rig_holes = d_face[COORDS].to_numpy()
    local_to_mine = placement(37.5, (478_000.0, 6_771_600.0, 238.0))  # the file's own local frame
    mine = true.to_plan(rig_holes)
    local = (mine.reshape(-1, 3) - local_to_mine[:3, 3]) @ local_to_mine[:3, :3]  # its inverse, by hand
    plan = tiny_study / "round.xml"
    vendor_drpplan(plan, local.reshape(-1, 6), d_face["hole_id"].tolist(), local_to_mine)
    points = write_points(tiny_study / "prisms.csv", ["P1", "P2", "P3"], true.to_plan(PRISMS_RIG[:3]),
                          PRISMS_RIG[:3] + np.random.default_rng(1).normal(0, 0.001, (3, 3)))
    summary = solve.run(make_cfg(tiny_study, f"plan={plan}", f"navigation.points={points}", "tunnel=profile",
                                 f"tunnel.file={D_SHAPE}"))
    table = pd.read_csv(plan.with_name("round_solution.csv"), keep_default_na=False, dtype={"hole_id": str})
    record = json.loads(plan.with_name("round_solution.json").read_text())
    assert summary["ok"] == len(d_face) and (table["status"] == "ok").all()
    # the solution's points in mine coordinates: the fitted pose's image of the hole each solved joint drills
    solved = table[[f"solved_{c}" for c in COORDS]].to_numpy(float)
    assert np.abs(solved - mine).max() < 1e-4  # the solver's 0.01 mm, and the fit reproduces its own frame
    assert record["checksum"] == "verified" and record["checksum_convention"] == "empty-value"
    nav = record["navigation"]
    assert nav["source"].startswith("navigation.points=") and nav["points"] == 3 and nav["rms_m"] < 0.002
    np.testing.assert_allclose(nav["pose"][:3], TRUE[:3], atol=0.01)
    client = MlflowClient(f"sqlite:///{tiny_study}/mlflow.db")
    (run,) = client.search_runs([client.get_experiment_by_name("boom-ik-tiny").experiment_id],
                                "tags.stage = 'solve'")
    assert run.data.metrics["navigation_rms_m"] == pytest.approx(nav["rms_m"])
    assert set(k for k in run.data.metrics if k.startswith("navigation_residual_m.")) == {
        "navigation_residual_m.P1", "navigation_residual_m.P2", "navigation_residual_m.P3"}


@pytest.mark.slow
def test_a_round_in_a_profile_drift_and_a_plan_frame_passes_the_independent_checker(tmp_path, make_cfg, d_face):
    """schedule plans a twin round of a plan given in tunnel coordinates in the D-shaped drift; the checker,
    composing the same settings with its own code (profile, navigation), finds it clean, and without the
    navigation finds every collar elsewhere."""
    import subprocess
    import sys

    from conftest import CHECK_STAGE

    from pipeline import demo_face, schedule
    from pipeline.core.config import PROJECT_ROOT

    demo_face.run(make_cfg(tmp_path))  # the tiny study's network is not needed: schedule.network=null
    pose = [120.0, -40.0, 3.0, -15.0, 0.5, 0.0]  # the rig in the tunnel's chainage frame
    holes = d_face.iloc[:6].copy()
    holes[COORDS] = pose_from_angles(pose).to_plan(holes[COORDS].to_numpy())
    plan = tmp_path / "tunnel_plan.csv"
    write_csv_plan(holes, plan)
    stage = [*CHECK_STAGE, f"plan={plan}", "tunnel=profile", f"tunnel.file={D_SHAPE}",
             f"navigation.pose=[{','.join(map(str, pose))}]"]
    summary = schedule.run(make_cfg(tmp_path, *stage))
    assert summary["holes_drilled"] == len(holes) and summary["navigation"]["pose"] == pytest.approx(pose)
    trajectory = plan.with_name("tunnel_plan_trajectory.csv")
    check = [sys.executable, str(PROJECT_ROOT / "scripts/check_round.py"), str(trajectory), "experiment=tiny",
             f"paths.data={tmp_path}/data", *stage]
    done = subprocess.run(check, capture_output=True, text=True, cwd=PROJECT_ROOT)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    report = json.loads(done.stdout)
    assert report["tunnel"]["kind"] == "profile" and report["navigation"] is not None
    # the same check without the navigation finds every collar elsewhere
    wrong = subprocess.run([c for c in check if not c.startswith("navigation.")], capture_output=True, text=True,
                           cwd=PROJECT_ROOT)
    assert wrong.returncode == 1
