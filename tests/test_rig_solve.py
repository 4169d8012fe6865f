"""Solving for a rig: boom-boom rows in the hybrid (against autograd), a hole solved given where the other
boom stands (checked by an independent boom-boom evaluation), rig=single reproducing today's solve output
exactly, the reach table of twin on the demo face, a hole no boom can drill, and bad rigs through solve."""

import pandas as pd
import pytest
import torch

from pipeline import demo_face, generate, solve, train
from pipeline.assembly.rig import build_rig
from pipeline.core.errors import ConfigError, InputError, StrictCheckFailed
from pipeline.core.settings import parse
from pipeline.geometry.boom_pair import BoomPair
from pipeline.plans.csv_plan import read_csv_plan, write_csv_plan
from pipeline.plans.reach import BOOM_CLEARANCE, reach_table, rig_solvers
from pipeline.plans.read import read_plan
from pipeline.plans.solutions import CLEARANCE_COLUMNS
from pipeline.solvers.base import HoleTargets
from pipeline.solvers.hybrid import BoomObstacle, HybridSettings, HybridSolver

D = torch.float64
TINY = ["train.steps=400", "runtime.log_model=true", "holes.unsup.size=500", "holes.sup.size=300",
        "holes.test.size=20", "solver.deep_starts=32"]


def _shift(frames, base):
    """Frames moved into the rig frame by a base translation (independent of the rig's own code)."""
    out = frames.clone()
    out[..., :3, 3] += torch.tensor(base, dtype=frames.dtype)
    return out


def _independent_boom_gap(mount_a, qa, mount_b, qb):
    """Smallest capsule surface distance of two booms, from capsule ends of independently shifted frames and
    a dense sampling of both axes (201 points each): an upper bound within 1 mm-ish of the true distance."""
    s = torch.linspace(0, 1, 201, dtype=D)
    gaps = []
    fa, fb = _shift(mount_a.boom.frames(qa), mount_a.base), _shift(mount_b.boom.frames(qb), mount_b.base)
    for na, ba in mount_a.boom.bodies.items():
        pa0, pa1 = mount_a.boom.capsule_ends(fa, na)
        for nb, bb in mount_b.boom.bodies.items():
            pb0, pb1 = mount_b.boom.capsule_ends(fb, nb)
            A = pa0[None] + s[:, None] * (pa1 - pa0)[None]
            B = pb0[None] + s[:, None] * (pb1 - pb0)[None]
            gaps.append(torch.cdist(A, B).min() - ba.radius - bb.radius)
    return float(torch.stack(gaps).min())


@pytest.fixture(scope="module")
def twin():
    from pipeline.core.config import compose

    cfg = compose(["rig=twin"])
    return build_rig(cfg.rig, cfg.tunnel, cfg.safety)


@pytest.fixture(scope="module")
def study(tmp_path_factory, make_cfg):
    tmp = tmp_path_factory.mktemp("rig_solve")
    generate.run(make_cfg(tmp, *TINY))
    demo_face.run(make_cfg(tmp, *TINY))
    train.run(make_cfg(tmp, *TINY, "method=cuikm"))
    return tmp


def test_boom_boom_rows_are_the_clearance_and_its_autograd_gradient(twin):
    """With every row active (a large margin), the boom-boom row of the LM is w (c - margin) and its Jacobian
    row the autograd gradient of the clearance w.r.t. the moving boom's free joints."""
    L, R = twin.booms
    s = HybridSettings(margin=5.0, clearance_weight=1.7)
    solver = HybridSolver(L.boom, L.safety, None, s, base=L.base)
    g = torch.Generator().manual_seed(3)
    lo, hi = L.boom.limits(D)
    q = L.boom.with_locks(lo + (hi - lo) * torch.rand(6, L.boom.n_joints, generator=g, dtype=D))
    q_other = R.boom.with_locks(lo + (hi - lo) * torch.rand(6, R.boom.n_joints, generator=g, dtype=D))
    pair = BoomPair(L.boom, R.boom, twin.d_boom)
    other = _shift(R.boom.frames(q_other), R.base)
    x = q[:, solver.space.free]
    target = torch.zeros(len(q), 6, dtype=D)
    r, J, _, c, _ = solver._rows(x, target, torch.full((len(q), 5), -1.0, dtype=D), [(pair, other)])
    xg = x.clone().requires_grad_(True)
    value = pair.clearance(_shift(L.boom.frames(solver.space.full(xg)), L.base), other)
    (grad,) = torch.autograd.grad(value.sum(), xg)
    assert torch.equal(c[:, 4], value.detach())
    torch.testing.assert_close(r[:, -1], 1.7 * (value.detach() - 5.0), rtol=0, atol=1e-12)
    torch.testing.assert_close(J[:, -1], 1.7 * grad, rtol=0, atol=1e-9)
    assert (grad.abs().sum(-1) > 0).all()  # the rows carry a gradient


def test_a_hole_is_solved_clear_of_where_the_other_boom_stands(twin, tmp_path, make_cfg):
    """Boom R stands at its solution of one hole; a hole whose default (obstacle-free) solution of boom L
    breaks d_boom to it is solved ok with the boom-boom rows, checked by an independent evaluation."""
    demo_face.run(make_cfg(tmp_path))
    plan = read_plan(tmp_path / "data" / "plans" / "demo_face.csv")
    L, R = twin.booms
    targets = HoleTargets(plan.poses(L.boom.preview_depth), L.boom.preview_depth)
    s = HybridSettings(deep_starts=32)
    free_L = HybridSolver(L.boom, L.safety, None, s, base=L.base).solve(targets)
    free_R = HybridSolver(R.boom, R.safety, None, s, base=R.base).solve(targets)
    pair = BoomPair(L.boom, R.boom, twin.d_boom)
    ok_L = torch.tensor([st == "ok" for st in free_L.status])
    ok_R = torch.tensor([st == "ok" for st in free_R.status])
    fl = L.frames(free_L.q)
    # every (hole of L, stand of R) pairing: find L's default solutions that break d_boom to R standing
    gaps = pair.clearance(fl[:, None], R.frames(free_R.q)[None])
    # by more than 0.1 m; of those, the two collars farthest apart (two holes near each other, or the same
    # hole, may leave no room for both booms: that is the round planner's business, not a solver's)
    bad = (gaps < -0.1) & ok_L[:, None] & ok_R[None, :]
    assert bad.any(), "no default solution of L breaks d_boom to any stand of R on the demo face"
    collars = targets.pose[:, :3]
    i, j = divmod(int(torch.where(bad, torch.cdist(collars, collars), -1.0).flatten().argmax()), len(collars))
    stand = free_R.q[j]
    solver = HybridSolver(L.boom, L.safety, None, s, base=L.base)
    res = solver.solve(targets.subset([i]), obstacles=[BoomObstacle(pair, R.frames(stand), "R")])
    assert res.status == ["ok"], (plan.holes["hole_id"][i], res.status, res.clearances)
    gap = _independent_boom_gap(L, res.q[0], R, stand)
    assert gap >= twin.d_boom - 1e-9 and res.clearances["boom"][0] >= 0
    assert abs(gap - (float(res.clearances["boom"][0]) + twin.d_boom)) < 2e-3  # sampling within ~1 mm
    assert _independent_boom_gap(L, free_L.q[i], R, stand) < twin.d_boom  # the default one broke it
    tool = L.boom.tool_pose_from_frames(_shift(L.boom.frames(res.q), L.base))[0]  # the collar, rig frame
    assert (tool - targets.pose[i:i + 1, :3]).norm() < 2e-5
    assert all(float(v[0]) >= 0 for k, v in res.clearances.items())


def test_obstacles_that_do_not_fit_are_refused(twin, jumbo8):
    L, R = twin.booms
    solver = HybridSolver(L.boom, L.safety, None, HybridSettings(), base=L.base)
    targets = HoleTargets(torch.ones(1, 6, dtype=D), L.boom.preview_depth)
    stands = R.frames(torch.stack([R.park, R.park]))  # two stands for one hole
    with pytest.raises(InputError, match=r"obstacle 'R': frames of shape \(2, "):
        solver.solve(targets, obstacles=[BoomObstacle(BoomPair(L.boom, R.boom), stands, "R")])
    with pytest.raises(InputError, match=r"expected a BoomObstacle whose pair has this solver's boom"):
        solver.solve(targets, obstacles=[BoomObstacle(BoomPair(jumbo8, R.boom), R.frames(R.park), "R")])


def _read(path):
    return pd.read_csv(path, keep_default_na=False)


def test_single_rig_reproduces_todays_solve_output_exactly(study, make_cfg):
    """The rig path (a solver with the single rig's base offset, through the reach table) gives today's
    solve output bit for bit, and rig=single writes today's file format (no boom columns)."""
    tmp = study
    plan = tmp / "data" / "plans" / "demo_face.csv"
    cfg = make_cfg(tmp, *TINY, f"plan={plan}", "rig=single", f"out={tmp}/single.csv", "solve.figure=false")
    solve.run(cfg)
    today = _read(tmp / "single.csv")
    assert "boom" not in today.columns and BOOM_CLEARANCE not in today.columns
    rig = build_rig(cfg.rig, cfg.tunnel, cfg.safety)
    from pipeline.core.config import as_dict
    from pipeline.data.holes import joint_box
    from pipeline.learning.network_source import load_network
    from pipeline.solvers.base import NetworkSolver

    net = load_network(tmp / "data" / "models" / "cuikm.pt", rig.booms[0].boom)[0]
    solvers = rig_solvers(rig, lambda b: NetworkSolver(b, net, "cuikm"), parse(HybridSettings, cfg.solver, "solver"),
                          joint_box(rig.booms[0].boom, as_dict(cfg.holes.sup.box)))
    assert solvers[0].base is not None  # the offset path really runs
    reach = reach_table(read_plan(plan), rig, solvers, "hybrid (cuikm)").table
    assert set(reach["boom"]) == {"B"} and reach[BOOM_CLEARANCE].eq(float("inf")).all()
    pd.testing.assert_frame_equal(reach.drop(columns=["boom", BOOM_CLEARANCE]), today, check_exact=True)


def test_twin_reach_table_of_the_demo_face(study, make_cfg):
    """rig=twin: one row per hole and boom, hole-major, L then R, today's columns plus boom and
    clearance_boom_m; every hole ok by at least one boom; each ok row re-checked independently (collar
    from the shifted chain, clearances of the boom from its base, d_boom to the other boom at park)."""
    tmp = study
    plan = tmp / "data" / "plans" / "demo_face.csv"
    summary = solve.run(make_cfg(tmp, *TINY, f"plan={plan}", "rig=twin", "strict=true"))
    table = _read(plan.with_name("demo_face_solution.csv"))
    holes = read_csv_plan(plan).holes
    assert len(table) == 2 * len(holes) == 130
    assert table["hole_id"].tolist() == [h for h in holes["hole_id"] for _ in (0, 1)]
    assert table["boom"].tolist() == ["L", "R"] * len(holes)
    assert table.columns[:2].tolist() == ["hole_id", "boom"]
    assert table.columns.get_loc(BOOM_CLEARANCE) == table.columns.get_loc(CLEARANCE_COLUMNS[-1]) + 1
    ok = table[table["status"] == "ok"]
    assert set(ok["hole_id"]) == set(holes["hole_id"]) and summary["ok_by_none"] == 0
    assert plan.with_name("demo_face_solution.png").stat().st_size > 10_000
    cfg = make_cfg(tmp, "rig=twin")
    rig = build_rig(cfg.rig, cfg.tunnel, cfg.safety)
    collars = holes.set_index("hole_id")[["collar_x", "collar_y", "collar_z"]]
    for name, rows in ok.groupby("boom"):
        me, other = rig.booms[rig.index(name)], rig.booms[1 - rig.index(name)]
        q = torch.tensor(rows[me.boom.joint_names].to_numpy(), dtype=D)
        tool = me.boom.tool_pose_from_frames(_shift(me.boom.frames(q), me.base))[0]
        want = torch.tensor(collars.loc[rows["hole_id"]].to_numpy(), dtype=D)
        assert (tool - want).norm(dim=-1).max() < 2e-5  # joints in the boom's own base frame
        c = me.safety.clearances_from_frames(_shift(me.boom.frames(q), me.base))
        assert all(bool((v >= 0).all()) for v in c.values())
        for k in range(0, len(q), 7):  # a sample of rows: the dense-sampling oracle is slow
            assert _independent_boom_gap(me, q[k], other, other.park) >= rig.d_boom - 1e-9


def test_a_hole_no_boom_can_drill_stays_in_the_table_with_each_booms_status(study, make_cfg):
    tmp = study
    holes = read_csv_plan(tmp / "data" / "plans" / "demo_face.csv").holes.iloc[:3].copy()
    far = holes.iloc[[0]].copy()
    far["hole_id"] = "FAR"
    far[["collar_x", "toe_x"]] += 25.0  # 25 m beyond the face: out of every boom's reach
    plan = tmp / "data" / "plans" / "far.csv"
    write_csv_plan(pd.concat([holes, far], ignore_index=True), plan)
    with pytest.raises(StrictCheckFailed, match=r"1 hole\(s\) no boom can drill: \['FAR'\]"):
        solve.run(make_cfg(tmp, *TINY, f"plan={plan}", "rig=twin", "strict=true", "solve.figure=false"))
    table = _read(plan.with_name("far_solution.csv"))
    far_rows = table[table["hole_id"] == "FAR"]
    assert far_rows["boom"].tolist() == ["L", "R"]
    assert set(far_rows["status"]) == {"unreachable"}


@pytest.mark.parametrize(("override", "message"), [
    ("rig.booms.0.base=[0.0,3.0,0.0]", r"conf/rig/twin.yaml: boom 'L'.base = \[0.0, 3.0, 0.0\]: outside the tunnel"),
    ("rig.booms.1.boom=nope", r"conf/rig/twin.yaml: boom 'R'.boom = 'nope'"),
    ("rig.booms.1.base=[0.0,0.6,0.0]", r"conf/rig/twin.yaml: boom 'L' and boom 'R' overlap at park"),
])
def test_a_bad_rig_is_named_through_solve(tmp_path, make_cfg, override, message):
    with pytest.raises(ConfigError, match=message):
        solve.run(make_cfg(tmp_path, "rig=twin", override, f"plan={tmp_path}/none.csv"))


def test_a_calibrated_twin_is_solved_for_its_calibrated_booms(study, make_cfg, jumbo8):
    """boom_model= with rig=twin (once refused): every ok row's joints put the calibrated boom's
    collar on the hole (its own FK, shifted by the base), where the nominal boom at the same joints misses
    by centimetres: the reach table solved for the calibrated model, not the nominal one."""
    from pipeline.calibration.model_file import load_model, save_model

    tmp = study
    twists = torch.zeros(jumbo8.n_rows, 6, dtype=D)
    twists[1, :3] = torch.tensor([0.0035, -0.002, 0.003], dtype=D)
    twists[2, 3:] = torch.tensor([0.003, -0.003, 0.002], dtype=D)
    model_path = tmp / "calibrated.yaml"
    save_model(model_path, jumbo8, twists)
    holes = read_csv_plan(tmp / "data" / "plans" / "demo_face.csv").holes.iloc[::9].reset_index(drop=True)
    plan = tmp / "data" / "plans" / "calibrated_face.csv"
    write_csv_plan(holes, plan)
    solve.run(make_cfg(tmp, *TINY, f"plan={plan}", "rig=twin", f"boom_model={model_path}", "solve.figure=false"))
    table = _read(plan.with_name("calibrated_face_solution.csv"))
    ok = table[table["status"] == "ok"]
    assert set(ok["boom"]) == {"L", "R"} and len(set(ok["hole_id"])) == len(holes)
    model = load_model(model_path, jumbo8)
    collars = holes.set_index("hole_id")[["collar_x", "collar_y", "collar_z"]]
    for name, rows in ok.groupby("boom"):
        base = [0.0, 0.8, 0.0] if name == "L" else [0.0, -0.8, 0.0]  # conf/rig/twin.yaml
        q = torch.tensor(rows[jumbo8.joint_names].to_numpy(), dtype=D)
        want = torch.tensor(collars.loc[rows["hole_id"]].to_numpy(), dtype=D)
        calibrated = model.tool_pose_from_frames(_shift(model.frames(q), base))[0]
        nominal = jumbo8.tool_pose_from_frames(_shift(jumbo8.frames(q), base))[0]
        assert (calibrated - want).norm(dim=-1).max() < 2e-5, name
        assert (nominal - want).norm(dim=-1).min() > 0.005, name
