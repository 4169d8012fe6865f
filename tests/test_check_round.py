"""scripts/check_round.py, the independent round checker: it passes a good round and fails
each planted fault with the right message and exit code; it imports nothing of ``pipeline``; its
geometry agrees with independent values (the reference's test vectors, brute force over dense points)."""

import json
import math
import shutil
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
from round_checker import SCRIPT, cr, run_checker

from pipeline.core.config import PROJECT_ROOT

rc_distance, rc_settings, Sweep = cr.distance, cr.settings.settings, cr.sweep.Sweep  # the checker's own modules


@pytest.fixture(scope="module")
def good(small_twin_round):
    """One small twin round (6 holes of the demo face), planned once a session: the files and the overrides."""
    return small_twin_round


_run = run_checker


def _plant(good, name, traj=None, table=None, summary=None):
    """A copy of the good set under ``name`` with the trajectory, round table or JSON changed."""
    tmp, _ = good
    dst = tmp / name
    dst.mkdir()
    t = pd.read_csv(tmp / "small_trajectory.csv", keep_default_na=False, dtype={"hole_id": str})
    r = pd.read_csv(tmp / "small_round.csv", keep_default_na=False)
    s = json.loads((tmp / "small_round.json").read_text())
    t = traj(t) if traj else t
    r = table(r) if table else r
    s = summary(s) if summary else s
    t.to_csv(dst / "small_trajectory.csv", index=False)
    r.to_csv(dst / "small_round.csv", index=False)
    (dst / "small_round.json").write_text(json.dumps(s))
    return dst / "small_trajectory.csv"


def _boom_rows(t, boom):
    return t.index[t["boom"] == boom]


def _hole_rows(t, boom="L", nth=0):
    """Index of the collar row of ``boom``'s nth hole, then drill, retract, end."""
    k = t.index[(t["boom"] == boom) & (t["event"] == "collar")][nth]
    return [k, k + 1, k + 2, k + 3]


def _move_row(t, boom="L"):
    rows = t.index[(t["boom"] == boom) & (t["event"] == "move")]
    return rows[len(rows) // 3]


def _fails(good, traj_path, *needles, code=1, extra=()):
    rc, report, err = _run(traj_path, good[1], *extra)
    text = "\n".join(report["violations"] + report["not_certified"]) if report else err
    assert rc == code, (rc, text)
    for n in needles:
        assert n in text, (n, text)
    return report, text


# -- the good set ---------------------------------------------------------------------------------

def test_the_good_round_passes_with_certified_floors(good):
    tmp, overrides = good
    rc, report, err = _run(tmp / "small_trajectory.csv", overrides)
    assert rc == 0, (err, report and report["violations"], report and report["not_certified"])
    assert report["holes"]["drilled"] == report["holes"]["plan"] == 6
    for b in ("L", "R"):
        own = report["booms"][b]
        assert own["self_m"]["certified"] >= 0 and own["self_m"]["sampled"] >= own["self_m"]["certified"]
        for s in ("wall", "ground", "arch"):
            assert own["tunnel_m"][s]["sampled"] >= own["tunnel_m"][s]["certified"] >= 0
        assert own["speed_ratio_max"] <= 1 + 1e-9 and own["collar_error_max_mm"] < 0.1
    pair = report["pairs"]["L-R"]["distance_m"]
    assert pair["sampled"] >= pair["certified"] >= 0.3
    assert report["makespan_s"] == pytest.approx(report["json_makespan_s"], abs=1e-9)


def test_the_command_imports_nothing_of_pipeline(good):
    """A subprocess where ``pipeline`` is importable: after a whole check no pipeline module is loaded."""
    import os

    tmp, overrides = good
    code = ("import runpy, sys\n"
            f"sys.argv = [{str(SCRIPT)!r}, {str(tmp / 'small_trajectory.csv')!r}, *{overrides!r}]\n"
            "try:\n    runpy.run_path(sys.argv[0], run_name='__main__')\n"
            "except SystemExit as e:\n    print('RC', e.code)\n"
            "print('LOADED', sorted(m for m in sys.modules if m.split('.')[0] == 'pipeline'))\n"
            "import pipeline.core.config\nprint('IMPORTABLE')\n")
    env = {**os.environ, "PYTHONPATH": str(PROJECT_ROOT)}
    p = subprocess.run([sys.executable, "-c", code], cwd=PROJECT_ROOT, env=env, capture_output=True, text=True,
                       timeout=300)
    assert "RC 0" in p.stdout and "IMPORTABLE" in p.stdout, p.stderr[-3000:]
    assert "LOADED []" in p.stdout


def test_the_command_line_exit_code_and_json(good):
    tmp, overrides = good
    p = subprocess.run([sys.executable, str(SCRIPT), str(tmp / "small_trajectory.csv"), *overrides],
                       cwd="/", capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["rig"] == "twin"


# -- planted violations (exit 1) ------------------------------------------------------------------

def test_two_booms_brought_together_for_one_instant(good):
    tmp, overrides = good
    t_close = _run(tmp / "small_trajectory.csv", overrides)[1]["pairs"]["L-R"]["at_s"]  # where they come closest

    def bring(t):
        rows = _boom_rows(t, "R")
        k = rows[np.argmin(np.abs(t.loc[rows, "t"].to_numpy() - t_close))]
        k = k if t.loc[k, "event"] == "move" else k + 1
        t.loc[k, "q1"] += 0.3  # R swings toward L (its base is at y = -0.8)
        return t

    _fails(good, _plant(good, "together", bring), "booms L and R", "boom-boom clearance")


def test_one_joint_too_fast(good):
    def fast(t):
        t.loc[_move_row(t), "q5"] += 0.05
        return t

    _fails(good, _plant(good, "fast", fast), "boom L", "q5 at", "x its speed")


def test_joint_speeds_come_from_the_composed_motion(good):
    tmp, overrides = good
    rc, report, _ = _run(tmp / "small_trajectory.csv", [*overrides, "motion.joint_speeds.q7=2"])
    assert rc == 1 and any("q7 at" in v and "x its speed" in v for v in report["violations"])


def test_safety_distances_come_from_the_composed_config(good):
    tmp, overrides = good
    rc, report, _ = _run(tmp / "small_trajectory.csv", [*overrides, "safety.wall=0.8"])
    assert rc == 1 and any("wall clearance" in v for v in report["violations"])


def test_the_feed_through_the_wall(good):
    def wall(t):
        k = _move_row(t)
        t.loc[k, ["q1", "q2", "q3", "q4", "q5", "q6", "q7", "q8"]] = [0.7, 0.0, 4.0, 0.0, 0.0, 0.0, math.pi, 3.0]
        return t

    _fails(good, _plant(good, "wall", wall), "boom L", "wall clearance of the feed")


def test_a_hole_never_drilled(good):
    def drop(t):
        return t.drop(index=_hole_rows(t, "R", 0)[:3]).reset_index(drop=True)

    _fails(good, _plant(good, "undrilled", drop), "never drilled, though the round table says boom R")


def test_a_plan_hole_neither_drilled_nor_reported(good):
    def drop(t):
        return t.drop(index=_hole_rows(t, "R", 0)[:3]).reset_index(drop=True)

    def forget(r):
        gone = r[r["boom"] == "R"].sort_values("t_start")["hole_id"].iloc[0]
        return r[r["hole_id"] != gone]

    _fails(good, _plant(good, "unreported", drop, forget), "neither drilled nor reported in the round table")


def test_a_hole_drilled_twice(good):
    def twice(t):
        r = t[t["boom"] == "R"]
        t.loc[r.index[r["event"] == "collar"][1]:r.index[r["event"] == "collar"][1] + 2, "hole_id"] = \
            t.loc[r.index[r["event"] == "collar"][0], "hole_id"]
        return t

    _fails(good, _plant(good, "twice", twice), "drilled 2 times")


def test_a_boom_that_never_leaves_park(good):
    def stay(t):
        r = t[t["boom"] == "R"]
        keep = t.loc[[r.index[0], r.index[-1]]]
        return pd.concat([t[t["boom"] != "R"], keep], ignore_index=True)

    _fails(good, _plant(good, "parked", stay), "boom R: never leaves park", "never drilled")


def test_a_hole_drilled_with_q8_two_cm_short(good):
    def short(t):
        t.loc[_hole_rows(t, "L", 1), "q8"] -= 0.02
        return t

    _, text = _fails(good, _plant(good, "short", short), "drill end 20.0")
    assert "mm from its collar" in text


def test_a_timestamp_moved_back_one_second(good):
    def back(t):
        t.loc[_hole_rows(t, "L", 0)[2], "t"] -= 1.0  # the retract row: drilling 1 s short, retraction 1 s long
        return t

    _fails(good, _plant(good, "back", back), "the model time for its")


def test_a_boom_moving_between_drill_and_retract(good):
    def moving(t):
        t.loc[_hole_rows(t, "R", 1)[2], "q2"] += 0.001
        return t

    _fails(good, _plant(good, "moving", moving), "boom R", "joints move between the collar row and the end")


def test_a_joint_beyond_its_limit(good):
    def beyond(t):
        k = _move_row(t, "R")
        t.loc[k - 3:k + 3, "q2"] = math.radians(66.0)
        return t

    _fails(good, _plant(good, "limit", beyond), "boom R", "q2 = 66.0000 deg outside its range")


def test_a_makespan_in_the_json_that_disagrees(good):
    _fails(good, _plant(good, "makespan", summary=lambda s: {**s, "makespan_s": s["makespan_s"] + 1.0}),
           "makespan:", "says")


def test_a_move_the_planner_could_not_clear(good):
    def unclear(t):
        k = _move_row(t)
        t.loc[k - 2:k + 2, "event"] = "move_unclear"
        return t

    _fails(good, _plant(good, "unclear", unclear), "boom L", "move not cleared by the planner")


def test_a_boom_not_ending_at_park(good):
    def end(t):
        t.loc[_boom_rows(t, "L")[-1], "q3"] += 0.0001
        return t

    _fails(good, _plant(good, "noend", end), "boom L", "does not end at its park")


def test_a_coarse_sweep_is_reported_not_certified(good):
    tmp, _ = good
    _fails(good, tmp / "small_trajectory.csv", "not certified", extra=("--spacing-m", "0.5", "--levels", "0"))


# -- input errors (exit 2) ------------------------------------------------------------------------

def test_a_repeated_timestamp(good):
    def repeat(t):
        k = _move_row(t)
        t.loc[k, "t"] = t.loc[k - 1, "t"]
        return t

    _fails(good, _plant(good, "repeat", repeat), "boom 'L', row", "repeats the time", code=2)


def test_unsorted_rows(good):
    def swap(t):
        k = _move_row(t)
        return t.iloc[list(range(k)) + [k + 1, k] + list(range(k + 2, len(t)))].reset_index(drop=True)

    _fails(good, _plant(good, "unsorted", swap), "boom 'L', row", "goes back in time", code=2)


def test_one_booms_rows_reversed(good):
    def reverse(t):
        return pd.concat([t[t["boom"] == "L"], t[t["boom"] == "R"].iloc[::-1]], ignore_index=True)

    _fails(good, _plant(good, "reversed", reverse), "boom 'R'", "goes back in time", code=2)


def test_a_missing_boom(good):
    _fails(good, _plant(good, "missing", lambda t: t[t["boom"] != "R"]), "no rows for boom(s) ['R']", code=2)


def test_a_renamed_boom(good):
    renamed = _plant(good, "renamed", lambda t: t.replace({"boom": {"R": "X"}}))
    _fails(good, renamed, "boom 'X' is not a boom of the rig", code=2)


def test_a_nan_cell(good):
    def nan(t):
        t["q3"] = t["q3"].astype(object)
        t.loc[_move_row(t, "R"), "q3"] = "nan"
        return t

    _fails(good, _plant(good, "nan", nan), "boom 'R', row", "q3 = 'nan' is not a finite number", code=2)


def test_a_missing_column(good):
    _fails(good, _plant(good, "nocol", lambda t: t.drop(columns=["q6"])), "missing column(s) ['q6']", code=2)


def test_missing_files_bad_arguments_and_unsupported_settings(good, tmp_path):
    tmp, overrides = good
    traj = tmp / "small_trajectory.csv"
    assert _run(tmp_path / "none_trajectory.csv", overrides)[0] == 2
    shutil.copy(traj, tmp_path / "lone_trajectory.csv")
    rc, _, err = _run(tmp_path / "lone_trajectory.csv", overrides)
    assert rc == 2 and "lone_round.json: no such round JSON" in err
    rc, _, err = _run(traj, overrides, "--spacing-m", "0")
    assert rc == 2 and "--spacing-m" in err
    rc, _, err = _run(traj, overrides, "--no-such-flag")
    assert rc == 2 and "unrecognized" in err
    rc, _, err = _run(traj, [o for o in overrides if o != "rig=twin"])  # the default rig is single
    assert rc == 2 and "planned for rig 'twin'" in err and "pass rig=twin" in err
    rc, _, err = _run(traj, [*overrides, "boom_model=/no/such/model.yaml"])
    assert rc == 2 and "boom_model = '/no/such/model.yaml': cannot read it" in err
    rc, _, err = _run(traj, [*overrides, "boom_models={X: /no/such/model.yaml}"])
    assert rc == 2 and "boom_models: no boom ['X'] in rig 'twin'" in err
    rc, _, err = _run(traj, [*overrides, "no_such_group=3"])
    assert rc == 2 and "settings" in err


# -- the geometry against independent values ------------------------------------------------------

def test_a_calibrated_model_s_frames_equal_the_planner_s(tmp_path, jumbo8):
    """The checker's own calibrated chain (``P exp(hat(xi)) P^-1`` by the matrix series) against the project's
    error model (the adjoint, then the closed-form SE(3) exponential), on errors far above a real boom's;
    given per boom (``boom_models.R``), the other boom stays nominal; a model of another boom is refused."""
    import torch

    from pipeline.calibration.error_model import BoomWithErrors, ErrorLevel, draw_errors
    from pipeline.calibration.model_file import save_model

    twists = draw_errors(jumbo8, ErrorLevel(angle_deg=2.0, tilt_deg=1.5, offset_mm=20.0), seed=3, distribution="normal")
    save_model(tmp_path / "r.yaml", jumbo8, twists)
    st = rc_settings(["rig=twin", f"boom_models={{R: {tmp_path / 'r.yaml'}}}"])
    left, right = st.booms
    g = np.random.default_rng(4)
    q = left.model.lo + (left.model.hi - left.model.lo) * g.random((300, len(left.model.lo)))
    qt = torch.tensor(q, dtype=torch.float64)
    calibrated = BoomWithErrors(jumbo8, twists)
    project = calibrated.frames(qt).numpy()[:, : jumbo8.n_rows + 1]  # base and row frames (then the tool's)
    assert np.abs(right.model.frames(q) - project).max() < 1e-12
    assert np.abs(right.model.tool_pose(q)[0] - calibrated.tool_pose(qt)[0].numpy()).max() < 1e-12
    nominal = jumbo8.frames(qt).numpy()[:, : jumbo8.n_rows + 1]
    assert np.abs(left.model.frames(q) - nominal).max() < 1e-12 and np.abs(project - nominal).max() > 0.01
    doc = (tmp_path / "r.yaml").read_text().replace("boom: jumbo8", "boom: huang9")
    (tmp_path / "other.yaml").write_text(doc)
    with pytest.raises(cr.InputError, match="a model of boom 'huang9'"):
        rc_settings(["rig=twin", f"boom_model={tmp_path / 'other.yaml'}"])


@pytest.fixture(scope="module")
def jumbo():
    return rc_settings(["rig=twin"]).booms[0].model


def test_forward_kinematics_meets_the_spec_test_vectors(jumbo):
    q = np.array([[0, 0, 3.5, 0, 0, 0, 0, 2.5],
                  [0.174533, 0.261799, 4.0, 0.523599, -0.349066, 0.174533, 0.785398, 2.0],
                  [-0.523599, 0.698132, 3.2, -2.094395, 0.610865, -0.872665, -1.570796, 3.1]])
    want = np.array([[6.35, -0.8, 1.6, 9.65, -0.8, 1.6],
                     [6.046605, 0.865722, 1.623475, 9.259662, 1.492682, 1.207315],
                     [5.034832, -2.479663, 2.146972, 7.639759, -4.226459, 1.120783]])
    H, z = jumbo.tool_pose(q)
    # the vectors' q are rounded to 1e-6 rad: the poses agree to a few 1e-6 m
    np.testing.assert_allclose(np.c_[H, H + 3.3 * z], want, atol=1e-5)


def test_bodies_agree_with_the_pipelines_kinematics(jumbo):
    """A second method, in a test only: the planner's own frames give the same capsule ends."""
    import torch

    from pipeline.assembly.build import load_boom

    q = np.random.default_rng(0).uniform(jumbo.lo, jumbo.hi, (64, 8))
    f = load_boom("jumbo8").frames(torch.as_tensor(q)).numpy()
    P = jumbo.body_points(jumbo.frames(q))
    H, z = f[..., -1, :3, 3], f[..., -1, :3, 2]
    np.testing.assert_allclose(P[:, 0, 0], f[..., 2, :3, 3], atol=1e-12)  # A = origin of frame 2
    np.testing.assert_allclose(P[:, 0, 1], f[..., 3, :3, 3], atol=1e-12)  # C = origin of frame 3
    np.testing.assert_allclose(P[:, 1, 1], H, atol=1e-12)
    np.testing.assert_allclose(P[:, 1, 0], H - 4.5 * z, atol=1e-12)


def test_lever_bound_holds_for_random_small_moves(jumbo):
    rng = np.random.default_rng(1)
    q0 = rng.uniform(jumbo.lo, jumbo.hi, (2000, 8))
    dq = rng.normal(0, 0.02, (2000, 8)) * rng.integers(0, 2, (2000, 8))
    moved = np.linalg.norm(jumbo.body_points(jumbo.frames(q0 + dq)) - jumbo.body_points(jumbo.frames(q0)), axis=-1)
    bound = np.abs(dq) @ jumbo.lever().T  # (n, bodies)
    assert (moved.max(-1) <= bound + 1e-12).all()
    assert (moved.max(-1) > 0.3 * bound).mean() > 0.5  # not vacuous: the bound is of the right size


def _brute_segments(p1, q1, p2, q2, n=401):
    u = np.linspace(0, 1, n)
    a = p1[:, None] + u[:, None] * (q1 - p1)[:, None]
    b = p2[:, None] + u[:, None] * (q2 - p2)[:, None]
    return np.linalg.norm(a[:, :, None] - b[:, None, :], axis=-1).min((1, 2))


def test_segment_distance_against_brute_force():
    rng = np.random.default_rng(2)
    p1, q1, p2, q2 = (rng.normal(0, 1, (120, 3)) for _ in range(4))
    q2[:50] = p2[:50] + 0.7 * (q1[:50] - p1[:50])  # parallel pairs
    q1[50:60] = p1[50:60]  # a point against a segment
    q2[60:70] = p2[60:70]
    q1[70:75], q2[70:75] = p1[70:75], p2[70:75]  # two points
    p2[75:85] = p1[75:85] + 0.25 * (q1[75:85] - p1[75:85])  # collinear, overlapping
    q2[75:85] = p1[75:85] + 1.5 * (q1[75:85] - p1[75:85])
    exact = rc_distance.segment_distance(p1, q1, p2, q2)
    brute = _brute_segments(p1, q1, p2, q2)
    seg = np.maximum(np.linalg.norm(q1 - p1, axis=1), np.linalg.norm(q2 - p2, axis=1))
    assert (exact <= brute + 1e-12).all()  # exact is the least: never above any pair of points
    assert (exact >= brute - seg / 400).all()  # and the dense points come within their spacing
    assert exact[75:85] == pytest.approx(0.0, abs=1e-12)
    assert rc_distance.segment_distance(np.array([0., 0, 0]), np.array([1., 0, 0]), np.array([2., 1, 0]),
                                        np.array([3., 1, 0])) == pytest.approx(math.sqrt(2))  # end to end


def _outline(r=2.5, h=3.2, n=2001):
    s = np.linspace(0, 1, n)
    floor = np.c_[-r + 2 * r * s, 0 * s]
    walls = np.r_[np.c_[r + 0 * s, h * s], np.c_[-r + 0 * s, h * s]]
    a = math.pi * s
    arch = np.c_[r * np.cos(a), h + r * np.sin(a)]
    return {"ground": floor, "wall": walls, "arch": arch}


def test_tunnel_distance_over_a_segment_against_dense_points():
    """Segments inside the reference profile: the exact least distance to each surface piece against
    dense points on the segment and on the outline (floor, both walls, the arch)."""
    rng = np.random.default_rng(3)
    r, h = 2.5, 3.2
    pts = []
    while len(pts) < 48:  # ends inside the profile (it is convex: the whole segment is)
        y, z = rng.uniform(-r, r), rng.uniform(0, h + r)
        if z <= h or y * y + (z - h) ** 2 <= r * r:
            pts.append((rng.uniform(0, 8), y, z))
    pts = np.array(pts)
    p0, p1 = pts[:24], pts[24:]
    exact = rc_distance.segment_tunnel(p0, p1, r, h)
    outline = _outline(r, h)
    u = np.linspace(0, 1, 201)
    for k, s in enumerate(rc_distance.SURFACES):
        along = p0[:, None, 1:] + u[:, None] * (p1 - p0)[:, None, 1:]
        brute = np.linalg.norm(along[:, :, None] - outline[s][None, None], axis=-1).min((1, 2))
        slack = np.linalg.norm(p1[:, 1:] - p0[:, 1:], axis=1) / 200 + 2 * math.pi * r / 2000
        assert (exact[:, k] <= brute + 1e-9).all(), s
        assert (exact[:, k] >= brute - slack).all(), s
    # by hand: the least distance to the wall's top end (above the springing line) and to the arch's end
    # (below it) both lie inside the segment, where no end point sees them
    ends = np.array([[0, 1.5, 3.0], [0, 2.3, 2.0]]), np.array([[0, 2.3, 3.8], [0, 1.9, 3.1]])
    hand = rc_distance.segment_tunnel(*ends, r, h)
    assert hand[0, 0] == pytest.approx(0.4 * math.sqrt(2), abs=1e-12)
    assert hand[1, 2] == pytest.approx(0.70 / math.sqrt(1.37), abs=1e-12)
    # outside: negative beyond the surface crossed
    out = rc_distance.point_distances(np.array([2.7, 0.0, 0.0]), np.array([1.0, -0.2, 5.9]), r, h)
    assert out["wall"][0] == pytest.approx(-0.2) and out["ground"][1] == pytest.approx(-0.2)
    assert out["arch"][2] == pytest.approx(-0.2)


def test_certified_floor_lies_under_a_dense_resampling(good):
    """Around the least sampled clearance of each kind, a 50x denser sweep finds nothing below the
    certified floor."""
    tmp, overrides = good
    st = rc_settings(overrides)
    rows = cr.files.read_trajectory(tmp / "small_trajectory.csv", {b.name: b.model.joint_names for b in st.booms})
    sw = Sweep(st, rows, 0.005)
    res = sw.run()
    for k in range(len(sw.keys)):
        t = res.sampled_at[k] + np.linspace(-0.5, 0.5, 20001)
        dense = sw.measure(t)[:, k].min()
        assert res.certified[k] <= dense + 1e-12, sw.keys[k]
        assert dense <= res.sampled[k] + 1e-12


def test_trajectory_only_checks_the_motion_alone(good, tmp_path):
    """A trajectory file without its siblings (the round benchmark's cells): motion checks only."""
    tmp, overrides = good
    lone = tmp_path / "cell.csv"
    shutil.copy(tmp / "small_trajectory.csv", lone)
    rc, report, err = _run(lone, overrides, "--trajectory-only")
    assert rc == 0, err
    assert "holes" not in report and report["checked"].startswith("trajectory only")
    t = pd.read_csv(lone, keep_default_na=False, dtype={"hole_id": str})
    t.loc[_move_row(t), "q5"] += 0.05
    t.to_csv(lone, index=False)
    rc, report, _ = _run(lone, overrides, "--trajectory-only")
    assert rc == 1 and any("q5 at" in v for v in report["violations"])


def test_settings_follow_the_composed_config():
    trio = rc_settings(["rig=trio"])  # trio's rig file selects its own, wider tunnel
    assert [b.name for b in trio.booms] == ["L", "M", "R"] and (trio.half_width, trio.wall_height) == (4.0, 3.0)
    st = rc_settings(["rig=twin", "boom.bodies.feed.radius=0.2", "motion.joint_speeds.q1=7.5", "safety.self=0.2",
                      "rig.d_boom=0.4", "motion.drilling.collaring_s=12"])
    assert [b.radius for b in st.booms[1].model.bodies] == [0.2, 0.2]  # the composed boom node reaches every boom
    assert st.booms[0].speed[0] == pytest.approx(math.radians(7.5)) and st.safety["self"] == 0.2
    assert st.d_boom == 0.4 and st.drill_times(np.array([2.5]))[0] == pytest.approx([12.0, 60.0, 2.5])
    np.testing.assert_allclose(st.booms[0].park, np.radians([0, 0, 0, 0, 0, 0, 180, 0]) + [0, 0, 3.0, 0, 0, 0, 0, 1.0])


# -- the checker's own input problems: exit 2 naming them; its own failure exit 3 ----------------

@pytest.mark.parametrize("extra, needle", [
    (["--seed", "-1"], "--seed = -1: must be a whole number in 0..4294967295"),
    (["--spacing-m", "1e-9"], "--spacing-m = 1e-09: must be a number in [0.001, 1] m"),
    (["--execute", "100000000"], "--execute = 100000000: must be a whole number of draws in 0..10000"),
    (["--angle-tol-deg", "1e9"], "--angle-tol-deg = 1000000000.0: must be a number in (0, 180]"),
])
def test_arguments_out_of_range_are_input_errors(good, extra, needle):
    """Once a crash reported as violations (exit 1): --seed -1, --spacing-m 1e-9 (memory), --execute 1e8."""
    tmp, overrides = good
    rc, report, err = _run(tmp / "small_trajectory.csv", overrides, *extra)
    assert rc == 2 and needle in err and report is None, err


def test_oversized_lines_cells_and_files_are_refused_before_parsing(good, monkeypatch):
    """A huge cell once took the checker to 8.9 GB (a text column becomes fixed-width numpy strings): a line over
    64 KiB, a used column's cell over 256 characters and a file over the size bound are refused, named."""
    def cell(n):
        def plant(t):
            t["hole_id"] = t["hole_id"].astype(object)
            t.loc[_move_row(t, "R"), "hole_id"] = "x" * n
            return t
        return plant

    long = _plant(good, "long_line", cell(100_000))
    _fails(good, long, "long_line/small_trajectory.csv: line ", "bytes long, over the checker's 65536", code=2)
    wide = _plant(good, "long_cell", cell(300))
    _fails(good, wide, "long_cell/small_trajectory.csv: row ", "the hole_id cell is 300 characters long", code=2)
    monkeypatch.setattr(cr.files, "MAX_CSV_MB", 0.001)
    _fails(good, good[0] / "small_trajectory.csv", "small_trajectory.csv: ", "MB, over the checker's 0.001 MB", code=2)


def test_a_fault_of_the_checker_s_own_is_exit_3_never_a_verdict(good, monkeypatch):
    """An unexpected exception in the checker is neither clean (0) nor violations (1): exit 3, its traceback."""
    def broken(*args, **kw):
        raise RuntimeError("a planted bug")

    monkeypatch.setattr(sys.modules["round_check.rules"], "makespan", broken)  # the checker's own module
    rc, report, err = _run(good[0] / "small_trajectory.csv", good[1])
    assert rc == 3 and report is None, err
    assert "Traceback" in err and "a planted bug" in err and "internal error" in err


@pytest.mark.parametrize("extra, needle", [
    (["tunnel=horseshoe_wide"], "tunnel.width: planned 5.0, composed 8.0"),
    (["rig.booms.0.base=[0.0,0.9,0.0]"], "rig.booms[0].base[1]: planned 0.8, composed 0.9"),
    (["rig.d_boom=0.2"], "rig.d_boom: planned 0.3, composed 0.2"),
])
def test_a_tunnel_or_rig_other_than_the_round_s_is_refused(good, extra, needle):
    """The round JSON records what it was planned with (planned_with); the checker holds its composed settings
    to it (once it judged a round in whatever tunnel it was given)."""
    tmp, overrides = good
    rc, report, err = _run(tmp / "small_trajectory.csv", [*overrides, *extra])
    assert rc == 2 and needle in err and report is None, err
    assert "planned with another" in err


def test_a_profile_is_compared_by_its_content_not_its_path(good, tmp_path):
    import hashlib

    src = PROJECT_ROOT / "conf" / "tunnel" / "profiles" / "d_5x5.csv"
    digest = hashlib.md5(src.read_bytes()).hexdigest()

    def profiled(s):
        s["planned_with"]["tunnel"] = {"kind": "profile", "file": "conf/tunnel/profiles/d_5x5.csv", "md5": digest}
        return s

    traj = _plant(good, "profiled", summary=profiled)
    edited = tmp_path / "d_5x5.csv"  # the same name, one vertex moved 1 cm
    lines = src.read_text().splitlines()
    y, z, kind = lines[2].split(",")
    lines[2] = ",".join([repr(float(y) + 0.01), z, kind])
    edited.write_text("\n".join(lines) + "\n")
    rc, _, err = _run(traj, [*good[1], "tunnel=profile", f"tunnel.file={edited}"])
    assert rc == 2 and "tunnel.md5: planned" in err, err
    moved = cr.settings.record({"name": "r", "d_boom": 0.3, "booms": []}, {"kind": "profile", "file": str(src)})
    assert cr.settings.differences({"kind": "profile", "file": "elsewhere/d.csv", "md5": digest}, moved["tunnel"]) == []
