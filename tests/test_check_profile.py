"""scripts/check_round.py on tunnels of any cross-section (``tunnel=profile tunnel.file=<csv>``) and on plans
in their own frame (``navigation.pose`` / ``navigation.points``): the checker's own profile reader refuses
each malformed file by name and row; its capsule-profile clearance agrees with brute force (dense points on
the axis and on the outline) and, on the reference horseshoe written as a polyline, with its horseshoe
within the chord error; planted trajectories that the horseshoe passes hit the box profile's flat roof or
sloped floor; a plan moved into another frame checks clean only with the navigation that undoes it; the
points fit recovers a known pose and refuses too few, collinear or badly fitting points."""

import contextlib
import io
import json
import math
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
from round_checker import SCRIPT, cr

from pipeline.core.config import PROJECT_ROOT

rc_settings = cr.settings.settings
PROFILES = PROJECT_ROOT / "conf" / "tunnel" / "profiles"
BOX = ["tunnel=profile", f"tunnel.file={PROFILES / 'box_5.5x4.5.csv'}"]
HORSESHOE_CSV = ["tunnel=profile", "tunnel.file=conf/tunnel/profiles/horseshoe_5x5.7.csv"]  # from the project root
SAGITTA = 2.5 * (1 - math.cos(math.pi / 128))  # the 64-segment arch's chord error, about 0.75 mm


def _run(traj, *args):
    """The command in-process: (exit code, report or None, stderr text)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            rc = cr.main([str(traj), *args])
        except SystemExit as e:
            rc = e.code
    return rc, (json.loads(out.getvalue()) if out.getvalue() else None), err.getvalue()


def _profile(name):
    return rc_settings(["tunnel=profile", f"tunnel.file={PROFILES / name}"]).tunnel


# -- reading a profile: each refusal names the file and the row or segment (exit 2) ---------------

SQUARE = [(2.0, 0.0, "ground"), (-2.0, 0.0, "wall"), (-2.0, 4.0, "arch"), (2.0, 4.0, "wall")]


def _csv(path, rows, header="y,z,surface"):
    path.write_text(header + "\n" + "".join(",".join(str(v) for v in r) + "\n" for r in rows))
    return path


@pytest.mark.parametrize("rows, header, extra, needles", [
    (SQUARE, "y,z", [], ["missing column(s) ['surface']"]),
    (SQUARE[:2], "y,z,surface", [], ["2 vertices; a closed profile needs at least 3"]),
    (SQUARE, "y,z,surface", ["tunnel.max_vertices=3"], ["4 vertices, more than tunnel.max_vertices = 3"]),
    ([*SQUARE[:2], (-2.0, "inf", "arch"), SQUARE[3]], "y,z,surface", [], ["row 4: z = 'inf' is not a finite number"]),
    ([*SQUARE[:2], (-2.0, "x", "arch"), SQUARE[3]], "y,z,surface", [], ["row 4: z = 'x' is not a finite number"]),
    ([SQUARE[0], (-2.0, 0.0, "roof"), *SQUARE[2:]], "y,z,surface", [], ["row 3: surface 'roof' is not one of"]),
    ([*SQUARE[:2], (-2.0, 0.0, "wall"), *SQUARE[2:]], "y,z,surface", [],
     ["segment 1 (rows 3-4) is 0 m long, shorter than 1e-06 m"]),
    ([(2.0, 0.0, "ground"), (-2.0, 4.0, "wall"), (-2.0, 0.0, "arch"), (2.0, 4.0, "wall")], "y,z,surface", [],
     ["the polyline crosses itself: segment 0 (rows 2-3) meets segment 2 (rows 4-5)"]),
    ([(2.0, 0.0, "ground"), (-2.0, 0.0, "wall"), (-2.0, 4.0, "arch"), (0.0, 4.0, "arch"), (-1.0, 4.0, "arch"),
      (2.0, 4.0, "wall")], "y,z,surface", [], ["crosses itself: segment 3 (rows 5-6) folds back over segment 2"]),
    ([(2.0, 0.0, "ground"), (-2.0, 0.0, "wall"), (-2.0, 4.0, "wall"), (2.0, 4.0, "wall")], "y,z,surface", [],
     ["no segment of kind ['arch']"]),
])
def test_a_malformed_profile_is_refused_naming_the_file_and_the_row(tmp_path, rows, header, extra, needles):
    bad = _csv(tmp_path / "bad.csv", rows, header)
    traj = _csv(tmp_path / "any.csv", [], "boom")  # settings are read before the trajectory
    rc, report, err = _run(traj, "tunnel=profile", f"tunnel.file={bad}", *extra, "--trajectory-only")
    assert rc == 2 and report is None, (rc, err)
    assert f"tunnel.file {bad}" in err and "Traceback" not in err, err
    for n in needles:
        assert n in err, (n, err)


def test_the_profile_setting_itself(tmp_path):
    """No file, a missing file, an unknown kind, an unknown group or key (Hydra's message): exit 2, one line."""
    traj = _csv(tmp_path / "any.csv", [], "boom")
    for args, needle in ((["tunnel=profile"], "tunnel.file = None: expected the path of a profile CSV"),
                         (["tunnel=profile", "tunnel.file=no/such.csv"], "no/such.csv: no such tunnel profile"),
                         (["tunnel.kind=oval"], "tunnel.kind = 'oval': expected horseshoe"),
                         (["tunnel=oval"], "settings ['tunnel=oval']"),
                         (["tunnel=profile", "tunnel.no_such=1"], "settings")):
        rc, _, err = _run(traj, *args, "--trajectory-only")
        assert rc == 2 and needle in err and "Traceback" not in err, (args, err)
    assert rc_settings([]).tunnel.describe() == {"kind": "horseshoe", "width": 5.0, "wall_height": 3.2}
    assert rc_settings(["rig=trio"]).tunnel.describe()["width"] == 8.0
    # a tunnel node without a kind but with a width is a horseshoe (the settings of older configs)
    assert cr.settings._tunnel({"width": 6.0, "wall_height": 3.0}).describe()["width"] == 6.0


def test_the_example_profiles_read():
    for name, kinds in (("box_5.5x4.5.csv", (2, 2, 17)), ("d_5x5.csv", (2, 1, 32)),
                        ("horseshoe_5x5.7.csv", (2, 1, 64)), ("three_centred_6x5.5.csv", (2, 1, 40))):
        d = _profile(name).describe()
        assert d["kind"] == "profile" and d["file"] == str(PROFILES / name)
        assert tuple(d["segments"][s] for s in ("wall", "ground", "arch")) == kinds
        assert d["vertices"] == sum(kinds)
    st = rc_settings(HORSESHOE_CSV)  # a relative file: from the project root
    assert st.half_width is None and st.tunnel.file == str(PROFILES / "horseshoe_5x5.7.csv")


# -- the clearance against brute force ----------------------------------------------------------

def _dense_outline(prof, step=1e-3):
    pts, kinds = [], []
    for a, b, k in zip(prof.a, prof.b, prof.kind, strict=True):
        n = max(2, int(np.ceil(np.linalg.norm(b - a) / step)) + 1)
        pts.append(a + np.linspace(0, 1, n)[:, None] * (b - a))
        kinds.append(np.full(n, k))
    return np.concatenate(pts), np.concatenate(kinds), step


def _brute(prof, p0, p1, n_axis=401):
    """The definition by dense points: v_k = least distance from dense axis points to dense points of kind k,
    and an end outside the polygon (matplotlib's point-in-polygon, not the checker's) adds -(its distance to
    the dense outline) to the kind(s) nearest. Also the per-kind distances of each end."""
    from matplotlib.path import Path as MPath
    from scipy.spatial import cKDTree

    P, K, step = _dense_outline(prof)
    trees = [cKDTree(P[K == k]) for k in range(3)]
    poly = MPath(prof.vertices)
    u = np.linspace(0, 1, n_axis)
    along = (p0[:, None, 1:] + u[:, None] * (p1 - p0)[:, None, 1:]).reshape(-1, 2)
    v = np.stack([trees[k].query(along)[0].reshape(len(p0), -1).min(1) for k in range(3)], 1)
    outside, near_tie = [], np.zeros(len(p0), bool)
    for e in (p0[:, 1:], p1[:, 1:]):
        out = ~(poly.contains_points(e, radius=1e-9) | poly.contains_points(e, radius=-1e-9))
        dk = np.stack([trees[k].query(e)[0] for k in range(3)], 1)
        gap = dk.min(1, keepdims=True)
        v = np.where(out[:, None] & (dk <= gap + 1e-9), np.minimum(v, -gap), v)
        outside.append(out)
        # two kinds nearly (not exactly) as near: which one is nearest is beyond the dense points' accuracy
        second = np.sort(dk, 1)[:, 1] - gap[:, 0]
        near_tie |= out & (second > 1e-9) & (second < 1e-5)
    slack = np.linalg.norm(p1[:, 1:] - p0[:, 1:], axis=1) / (2 * (n_axis - 1)) + step
    return v, slack, outside[0] | outside[1], near_tie


def _random_axes(prof, rng, n=180):
    lo, hi = prof.vertices.min(0) - 0.5, prof.vertices.max(0) + 0.5
    p0 = np.c_[rng.uniform(0, 6, n), rng.uniform(lo, hi, (n, 2))]
    p1 = np.c_[rng.uniform(0, 6, n), rng.uniform(lo, hi, (n, 2))]
    p1[: n // 3] = p0[: n // 3] + rng.normal(0, 0.3, (n // 3, 3))  # short ones too
    p1[n // 3: n // 3 + 10, 1:] = p0[n // 3: n // 3 + 10, 1:]  # along x: a point in the profile's plane
    return p0, p1


@pytest.mark.parametrize("name", ["box_5.5x4.5.csv", "d_5x5.csv", "horseshoe_5x5.7.csv", "three_centred_6x5.5.csv"])
def test_the_profile_clearance_against_brute_force(name):
    """Random axes in and around each example profile: the exact v_k of each kind within the dense points'
    spacing of the brute force; inside the profile never above it (it is the least over the whole axis)."""
    prof = _profile(name)
    rng = np.random.default_rng(sum(map(ord, name)))
    p0, p1 = _random_axes(prof, rng)
    exact = prof.clearances(p0, p1)
    brute, slack, out, near_tie = _brute(prof, p0, p1)
    assert exact.shape == (len(p0), 3) and near_tie.sum() < 5
    ok = ~near_tie
    assert (np.abs(exact - brute)[ok] <= slack[ok, None] + 1e-9).all(), np.abs(exact - brute)[ok].max()
    assert (np.abs(exact.min(1) - brute.min(1)) <= slack + 1e-9).all()  # the verdict: every axis
    inside = ~out & (exact.min(1) > 0)
    assert inside.sum() > 40 and out.sum() > 40  # both kinds of case are well represented
    assert (exact[inside] <= brute[inside] + 1e-9).all()
    # an end outside the profile makes some kind negative; an axis wholly inside has none
    assert (exact[out].min(1) < 0).all() and (exact[~out].min(1) >= 0).all()
    # any batch shape: (2, n/2) gives the same numbers
    again = prof.clearances(p0.reshape(2, -1, 3), p1.reshape(2, -1, 3))
    np.testing.assert_array_equal(again.reshape(-1, 3), exact)


def test_either_direction_around_the_profile(tmp_path):
    """The box written clockwise (each segment keeping its kind: vertex j now carries segment j-1's) gives
    the same clearances, kind by kind."""
    box = pd.read_csv(PROFILES / "box_5.5x4.5.csv")
    rev = pd.DataFrame({"y": box["y"][::-1].to_numpy(), "z": box["z"][::-1].to_numpy(),
                        "surface": np.roll(box["surface"].to_numpy(), 1)[::-1]})
    rev.to_csv(tmp_path / "clockwise.csv", index=False)
    a = _profile("box_5.5x4.5.csv")
    b = rc_settings(["tunnel=profile", f"tunnel.file={tmp_path / 'clockwise.csv'}"]).tunnel
    p0, p1 = _random_axes(a, np.random.default_rng(11))
    np.testing.assert_allclose(b.clearances(p0, p1), a.clearances(p0, p1), atol=1e-12)


def test_by_hand_on_the_box():
    """The box's flat roof (z = 4.5 between its rounded corners) and its floor falling 2 % toward +y."""
    prof = _profile("box_5.5x4.5.csv")
    wall, ground, arch = prof.clearances(np.array([[0, -1.0, 4.0], [0, 2.0, 1.0]]),
                                         np.array([[3, 1.0, 4.0], [5, -1.0, 1.0]])).T
    assert arch[0] == pytest.approx(0.5, abs=1e-12)  # under the flat roof
    assert ground[1] == pytest.approx((1.0 - 0.02) / math.sqrt(1 + 0.02 ** 2), abs=1e-12)  # z = -0.02 y at y = -1
    assert wall[1] == pytest.approx(0.75, abs=1e-12)  # y = 2.0 against the wall at y = 2.75
    # through the roof: crosses the arch (0) and ends 0.3 m above it
    c = prof.clearances(np.array([0, 0.0, 4.0]), np.array([0, 0.0, 4.8]))
    assert c[2] == pytest.approx(-0.3, abs=1e-12) and c[0] > 0 and c[1] > 0


def test_the_horseshoe_polyline_equals_the_horseshoe_within_its_chord_error():
    """conf/tunnel/profiles/horseshoe_5x5.7.csv (64 arch segments) against the checker's horseshoe, for axes
    inside it: floor and walls the same, the arch within the sagitta r (1 - cos(pi/128))."""
    prof = _profile("horseshoe_5x5.7.csv")
    horse = rc_settings([]).tunnel
    assert int((prof.kind == 2).sum()) == 64 and SAGITTA == pytest.approx(7.53e-4, abs=1e-6)
    rng = np.random.default_rng(7)
    pts = []
    while len(pts) < 800:  # inside the horseshoe by more than the sagitta: inside the polyline too
        y, z = rng.uniform(-2.5, 2.5), rng.uniform(0, 5.7)
        if z <= 3.2 or math.hypot(y, z - 3.2) <= 2.5 - 1e-3:
            pts.append((rng.uniform(0, 8), y, z))
    pts = np.array(pts)
    p0, p1 = pts[:400], pts[400:]
    p1[:100] = p0[:100] + rng.normal(0, 0.2, (100, 3))
    keep = np.ones(400, bool)
    keep[:100] = (p1[:100, 2] >= 0) & (np.abs(p1[:100, 1]) <= 2.5) & (
        (p1[:100, 2] <= 3.2) | (np.hypot(p1[:100, 1], p1[:100, 2] - 3.2) <= 2.499))
    p0, p1 = p0[keep], p1[keep]
    a, b = prof.clearances(p0, p1), horse.clearances(p0, p1)
    assert (a >= 0).all()
    np.testing.assert_allclose(a[:, :2], b[:, :2], atol=1e-12)  # wall, ground: the same segments
    # the file's vertices are rounded to 1e-6 m (their radii 2.5 m within 5e-7)
    assert (np.abs(a[:, 2] - b[:, 2]) <= SAGITTA + 1e-6).all()
    assert (a[:, 2] <= b[:, 2] + 1e-6).all()  # the inscribed polyline is nowhere farther than the arc
    assert np.abs(a[:, 2] - b[:, 2]).max() > 0.5 * SAGITTA  # and the difference is the chord error's size


# -- planted faults: clear in the horseshoe, not in the box profile ------------------------------

PARK = np.array([0, 0, 3.0, 0, 0, 0, 0, 1.0])  # rig=single's boom B (deg -> rad below)
SPEED = np.radians([15, 12, 0, 20, 15, 15, 25, 0]) + np.array([0, 0, 0.3, 0, 0, 0, 0, 0.5])
# the feed low and level at y ~ -1.85, 8 mm over the horseshoe's floor clearance; the box floor is
# 3.7 cm higher there (it falls 2 % toward +y)
NEAR_THE_FLOOR = np.array([-0.1121, -0.0867, 3.6399, -0.7833, -1.0965, -0.0751, -1.0501, 3.0238])
# the feed raised to z ~ 5.3: clear of the horseshoe's crown (5.7 m), through the box's flat roof (4.5 m)
UNDER_THE_CROWN = np.array([-0.0183, 0.8498, 3.0156, 0.0027, 0.4203, -0.5082, -0.5084, 2.3598])
CLEAR = np.array([0.18413, 0.22881, 3.3557, 0.26040, -0.31224, 0.09983, -0.51784, 1.692])


def _held(path, q, hold=5.0):
    """Boom B from park to ``q`` (slower than its speeds), held there, and back to park."""
    T = 1.5 * np.abs((q - PARK) / SPEED).max()
    rows = [(0.0, PARK, "move"), (T, q, "wait"), (T + hold, q, "move"), (2 * T + hold, PARK, "done")]
    pd.DataFrame([{"boom": "B", "t": t, **{f"q{j + 1}": v for j, v in enumerate(qq)}, "event": e, "hole_id": ""}
                  for t, qq, e in rows]).to_csv(path, index=False)
    return path


@pytest.mark.parametrize("q, surface", [(NEAR_THE_FLOOR, "ground"), (UNDER_THE_CROWN, "arch")])
def test_a_move_clear_in_the_horseshoe_hits_the_box_profile(tmp_path, q, surface):
    traj = _held(tmp_path / "held.csv", q)
    rc, report, err = _run(traj, "--trajectory-only")
    assert rc == 0, (err, report and report["violations"])
    assert report["tunnel"]["kind"] == "horseshoe"
    assert 0 <= report["booms"]["B"]["tunnel_m"][surface]["certified"] < 0.02  # close, but clear
    rc, report, err = _run(traj, *BOX, "--trajectory-only")
    assert rc == 1, err
    assert report["tunnel"] == {"kind": "profile", "file": str(PROFILES / "box_5.5x4.5.csv"), "vertices": 21,
                                "segments": {"wall": 2, "ground": 2, "arch": 17}}
    assert any("boom B, t=" in v and f"{surface} clearance of the feed" in v for v in report["violations"]), report
    assert report["booms"]["B"]["tunnel_m"][surface]["sampled"] < -0.02


def test_a_clear_move_passes_in_the_box_profile_with_certified_floors(tmp_path):
    traj = _held(tmp_path / "held.csv", CLEAR)
    rc, report, err = _run(traj, *BOX, "--trajectory-only")
    assert rc == 0, (err, report and report["violations"], report and report["not_certified"])
    for s in ("wall", "ground", "arch"):
        own = report["booms"]["B"]["tunnel_m"][s]
        assert own["sampled"] >= own["certified"] >= 0.5


def test_the_command_line_resolves_a_relative_profile_from_the_project_root(tmp_path):
    traj = _held(tmp_path / "held.csv", UNDER_THE_CROWN)
    p = subprocess.run([sys.executable, str(SCRIPT), str(traj), *HORSESHOE_CSV, "--trajectory-only"],
                       cwd="/", capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    arch = json.loads(p.stdout)["booms"]["B"]["tunnel_m"]["arch"]["sampled"]
    rc, report, _ = _run(traj, "--trajectory-only")  # the horseshoe: the same within the chord error
    assert -1e-6 <= report["booms"]["B"]["tunnel_m"]["arch"]["sampled"] - arch <= SAGITTA + 1e-6


def test_the_planned_round_in_the_horseshoe_polyline(small_twin_round):
    """The small twin round, planned in the horseshoe, checked against the horseshoe as a polyline (on purpose:
    ``--other-tunnel``; without it another tunnel than the round's is refused): clean, every boom's sampled
    clearances within the chord error of the horseshoe's (the same instants)."""
    tmp, overrides = small_twin_round
    traj = tmp / "small_trajectory.csv"
    rc, horse, err = _run(traj, *overrides)
    assert rc == 0, err
    rc, _, err = _run(traj, *overrides, *HORSESHOE_CSV)  # another tunnel than the round's: refused unless asked for
    assert rc == 2 and "planned with another tunnel" in err and "--other-tunnel" in err, err
    rc, poly, err = _run(traj, *overrides, *HORSESHOE_CSV, "--other-tunnel")
    assert rc == 0, (err, poly and poly["violations"], poly and poly["not_certified"])
    said = poly["planned_with"]
    assert said["planned"]["kind"] == "horseshoe" and said["checked"]["kind"] == "profile"
    assert poly["tunnel"]["kind"] == "profile" and horse["tunnel"]["kind"] == "horseshoe"
    for b in ("L", "R"):
        for s in ("wall", "ground", "arch"):
            h, p = horse["booms"][b]["tunnel_m"][s], poly["booms"][b]["tunnel_m"][s]
            assert abs(h["sampled"] - p["sampled"]) <= SAGITTA + 1e-6, (b, s, h, p)
            assert p["certified"] >= 0


# -- navigation: a plan in its own frame ---------------------------------------------------------

POSE = [12.5, -3.25, 1.75, 33.0, 2.5, -1.5]  # x y z (m) yaw pitch roll (deg)


def test_the_rotation_order_and_the_transform():
    nav = cr.settings.read_navigation({"pose": [1.0, 2.0, 3.0, 90.0, 0.0, 0.0], "max_rms_m": 0.02}, PROJECT_ROOT)
    np.testing.assert_allclose(nav.to_rig(np.array([1.0, 3.0, 3.0])), [1, 0, 0], atol=1e-12)  # rig x = plan y
    R = cr.navigation.rotation(90, 90, 0)  # Rz(yaw) Ry(pitch): the rig's x axis points down, its y along -x
    np.testing.assert_allclose(R @ [1, 0, 0], [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(R @ [0, 1, 0], [-1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(cr.navigation.rotation(0, 0, 90) @ [0, 1, 0], [0, 0, 1], atol=1e-12)  # roll about x
    R = cr.navigation.rotation(*POSE[3:])
    np.testing.assert_allclose(cr.navigation.angles(R), POSE[3:], atol=1e-12)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)


def _to_plan_frame(rig_xyz, pose=POSE):
    R = cr.navigation.rotation(*pose[3:])
    return rig_xyz @ R.T + np.asarray(pose[:3])


def _plan_in_its_frame(src, dst, pose=POSE):
    plan = pd.read_csv(src)
    for end in ("collar", "toe"):
        cols = [f"{end}_{c}" for c in "xyz"]
        plan[cols] = _to_plan_frame(plan[cols].to_numpy(float), pose)
    plan.to_csv(dst, index=False)
    return dst


def _points(path, rig, plan, names=None):
    names = names or [f"P{i + 1}" for i in range(len(rig))]
    pd.DataFrame({"point": names, **{f"plan_{c}": plan[:, i] for i, c in enumerate("xyz")},
                  **{f"rig_{c}": rig[:, i] for i, c in enumerate("xyz")}}).to_csv(path, index=False)
    return path


REFERENCE = np.array([[8.0, 2.6, 1.5], [8.5, -2.6, 2.0], [9.0, 0.3, 5.4], [2.0, 2.4, 3.5], [3.0, -2.5, 0.8]])


def test_a_plan_in_its_own_frame_checks_clean_with_its_pose(small_twin_round, tmp_path):
    tmp, overrides = small_twin_round
    traj, src = tmp / "small_trajectory.csv", next(o for o in overrides if o.startswith("plan=")).split("=", 1)[1]
    moved = _plan_in_its_frame(src, tmp_path / "plan_frame.csv")
    pose = f"navigation.pose=[{','.join(map(str, POSE))}]"
    rc, report, err = _run(traj, *overrides, pose, "--plan", str(moved))
    assert rc == 0, (err, report and report["violations"])
    assert report["navigation"] == {"given": "pose", "pose": POSE}
    assert max(report["booms"][b]["collar_error_max_mm"] for b in "LR") < 0.1
    rc, report, _ = _run(traj, *overrides, "--plan", str(moved))  # the same plan taken as the rig frame's
    assert rc == 1 and report["navigation"]["given"] is None
    assert sum("mm from its collar" in v for v in report["violations"]) == 6
    # the pose as exact measured points: the fit gives it back (rms ~ 0)
    pts = _points(tmp_path / "points.csv", REFERENCE, _to_plan_frame(REFERENCE))
    rc, report, err = _run(traj, *overrides, f"navigation.points={pts}", "--plan", str(moved))
    assert rc == 0, (err, report and report["violations"])
    nav = report["navigation"]
    assert nav["given"] == "points" and nav["n"] == 5 and nav["rms_m"] < 1e-9 and nav["points"] == str(pts)
    np.testing.assert_allclose(nav["pose"], POSE, atol=1e-9)


@pytest.mark.parametrize("n", [3, 4, 5])
def test_the_points_fit_recovers_a_known_pose_from_noisy_points(tmp_path, n):
    rng = np.random.default_rng(n)
    rig = REFERENCE[:n] + rng.normal(0, 0.002, (n, 3))  # measured from the rig, 2 mm noise
    plan = _to_plan_frame(REFERENCE[:n])
    st = rc_settings([f"navigation.points={_points(tmp_path / 'p.csv', rig, plan)}"])
    nav = st.navigation
    assert nav.doc["rms_m"] < 0.005 and nav.doc["worst_point"] in [f"P{i + 1}" for i in range(n)]
    np.testing.assert_allclose(nav.pose()[3:], POSE[3:], atol=0.15)  # degrees
    # where the holes are (a face 3-8 m ahead), the fitted transform is within a centimetre of the true one
    face = np.c_[rng.uniform(3, 8, 50), rng.uniform(-2.5, 2.5, 50), rng.uniform(0, 5, 50)]
    assert np.linalg.norm(nav.to_rig(_to_plan_frame(face)) - face, axis=1).max() < 0.01
    # noise-free: exact
    exact = rc_settings([f"navigation.points={_points(tmp_path / 'q.csv', REFERENCE[:n], plan)}"]).navigation
    np.testing.assert_allclose(exact.pose(), POSE, atol=1e-9)
    np.testing.assert_allclose(exact.R, cr.navigation.rotation(*POSE[3:]), atol=1e-12)


def test_the_points_fit_is_never_a_reflection():
    rig = REFERENCE[:4]
    mirrored = rig * [1, -1, 1]  # a mirror image: the best rotation, not the reflection that fits exactly
    R, _ = cr.navigation.fit(rig, mirrored)
    assert np.linalg.det(R) == pytest.approx(1.0)


def test_navigation_refusals(tmp_path):
    traj = _csv(tmp_path / "any.csv", [], "boom")
    plan = _to_plan_frame(REFERENCE)
    two = _points(tmp_path / "two.csv", REFERENCE[:2], plan[:2])
    line = np.array([[1.0, 0, 0], [2.0, 0.5, 0.25], [4.0, 1.5, 0.75], [5.0, 2.0, 1.0]])
    collinear = _points(tmp_path / "line.csv", line, _to_plan_frame(line))
    off = plan.copy()
    off[2] += [0.0, 0.0, 0.12]  # P3 measured 12 cm off
    bad_fit = _points(tmp_path / "off.csv", REFERENCE, off, ["A", "B", "P3", "D", "E"])
    nocol = tmp_path / "nocol.csv"
    pd.read_csv(bad_fit).drop(columns=["rig_z"]).to_csv(nocol, index=False)
    nan = tmp_path / "nan.csv"
    pd.read_csv(bad_fit).assign(plan_y=["1", "2", "inf", "4", "5"]).to_csv(nan, index=False)
    for args, needles in (
            ([f"navigation.points={two}"], [f"navigation.points {two}", "2 point(s); the rigid fit needs at least"]),
            ([f"navigation.points={collinear}"], [f"navigation.points {collinear}", "lie on one line as measured"]),
            ([f"navigation.points={bad_fit}"], [f"navigation.points {bad_fit}", "exceeds navigation.max_rms_m = 0.02 m",
                                                "worst point 'P3' (row 4)"]),
            ([f"navigation.points={nocol}"], [f"navigation.points {nocol}", "missing column(s) ['rig_z']"]),
            ([f"navigation.points={nan}"], [f"navigation.points {nan}", "row 4: plan_y = 'inf' is not a finite"]),
            ([f"navigation.points={tmp_path / 'none.csv'}"], ["none.csv: no such navigation points file"]),
            (["navigation.pose=[1,2,3,4,5]"], ["navigation.pose = [1, 2, 3, 4, 5]: expected [x, y, z, yaw, pitch"]),
            (["navigation.pose=[0,0,0,0,0,0]", f"navigation.points={bad_fit}"], ["give at most one"]),
            (["navigation.max_rms_m=0"], ["navigation.max_rms_m = 0: expected a positive number"]),
            (["navigation.no_such=1"], ["settings"])):
        rc, _, err = _run(traj, *args, "--trajectory-only")
        assert rc == 2 and "Traceback" not in err, (args, err)
        for n in needles:
            assert n in err, (n, err)
    # the same points pass with a looser limit; the 12 cm point is the worst
    nav = rc_settings([f"navigation.points={bad_fit}", "navigation.max_rms_m=0.1"]).navigation
    assert nav.doc["worst_point"] == "P3" and 0.02 < nav.doc["rms_m"] < 0.1


@pytest.mark.parametrize("q", [NEAR_THE_FLOOR, CLEAR])
def test_the_certified_floor_in_a_profile_lies_under_a_dense_resampling(tmp_path, q):
    """The sweep's certificate with a profile's distances (1-Lipschitz inside it): around the least sampled
    clearance of each key, a dense resampling finds nothing below the certified floor."""
    st = rc_settings(["tunnel=profile", f"tunnel.file={PROFILES / 'd_5x5.csv'}"])
    rows = cr.files.read_trajectory(_held(tmp_path / "held.csv", q), {"B": st.booms[0].model.joint_names})
    sw = cr.sweep.Sweep(st, rows, 0.005)
    res = sw.run()
    assert np.isfinite(res.certified).all() and not res.unclear
    for k in range(len(sw.keys)):
        t = np.clip(res.sampled_at[k] + np.linspace(-0.5, 0.5, 4001), 0, None)
        dense = sw.measure(t)[:, k].min()
        assert res.certified[k] <= dense + 1e-12, sw.keys[k]
        assert dense <= res.sampled[k] + 1e-12
