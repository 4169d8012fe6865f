"""Stage schedule: the round of rig twin on a small face of the demo plan, checked from the files.

The checker (scripts/check_round.py, tests/test_check_round.py) shares no code with the planner: it
reads the round's files with the stage's composed settings and judges them with its own kinematics,
distances and certified sweep. Drilling times are the reference's formula by hand.
"""

import json
import shutil
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch

from pipeline import demo_face, schedule
from pipeline.core.config import PROJECT_ROOT, load_group_file
from pipeline.core.errors import ConfigError, InputError, StrictCheckFailed
from pipeline.motion.timing import motion_from_config

D = torch.float64
SPEC_DRILL = lambda L: 10.0 + L / 2.5 * 60.0 + L / 1.0  # noqa: E731  docs/reference.md section 7, by hand
FAST = ["rig=twin", "schedule.network=null", "round.solution_limit=50", "round.reopt_rounds=2",
        "round.posture_rounds=1", "schedule.replay_frames=8", "runtime.progress=false"]
COLS = ["hole_id", "collar_x", "collar_y", "collar_z", "toe_x", "toe_y", "toe_z"]


@pytest.fixture(scope="module")
def face_plan(tmp_path_factory, make_cfg):
    tmp = tmp_path_factory.mktemp("schedule")
    demo_face.run(make_cfg(tmp))
    holes = pd.read_csv(tmp / "data" / "plans" / "demo_face.csv")
    return tmp, holes


@pytest.fixture(scope="module")
def small_round(face_plan, make_cfg):
    tmp, holes = face_plan
    plan = tmp / "small.csv"
    holes.iloc[::8].reset_index(drop=True).to_csv(plan, index=False)  # 9 holes of every type
    cfg = make_cfg(tmp, *FAST, f"plan={plan}")
    summary = schedule.run(cfg)
    return tmp, cfg, summary, holes.iloc[::8].reset_index(drop=True)


def test_the_three_files_and_figures_are_written(small_round):
    tmp, _, summary, _ = small_round
    for suffix in ("_round.csv", "_trajectory.csv", "_round.json", "_round_face.png", "_round_gantt.png",
                   "_round_replay.html", "_actions.csv", "_interlocks.csv", "_round_executed.png",
                   "_round_executed_replay.html"):
        assert (tmp / f"small{suffix}").stat().st_size > 0, suffix
    # the zones file, for every rig: its header alone here (the search keeps no zone on this small round)
    assert (tmp / "small_zones.csv").read_text() == "zone,boom,first_action,last_action\n"
    on_disk = json.loads((tmp / "small_round.json").read_text())
    for key in ("makespan_s", "lower_bound_s", "naive_makespan_s", "nearest_makespan_s", "min_boom_clearance_m",
                "booms", "moves"):
        assert key in on_disk
    assert set(on_disk["booms"]) == {"L", "R"} and on_disk["booms"]["L"]["base"] == [0.0, 0.8, 0.0]
    assert on_disk["makespan_s"] >= on_disk["lower_bound_s"] > 0
    assert on_disk["makespan_s"] <= min(on_disk["naive_makespan_s"], on_disk["nearest_makespan_s"]) + 1e-9
    assert not list(tmp.glob(".small_round.*/"))  # the private staging folder is gone
    assert "plotly" in (tmp / "small_round_replay.html").read_text()[:200000]  # JS inlined: works offline


def test_every_hole_once_and_drilling_lasts_the_spec_time(small_round):
    tmp, _, _, holes = small_round
    r = pd.read_csv(tmp / "small_round.csv", keep_default_na=False, na_values=[""])
    assert sorted(r["hole_id"]) == sorted(holes["hole_id"])
    ok = r[r["status"] == "ok"]
    L = np.linalg.norm(holes[["toe_x", "toe_y", "toe_z"]].to_numpy() - holes[["collar_x", "collar_y",
                                                                               "collar_z"]].to_numpy(), axis=1)
    length = dict(zip(holes["hole_id"], L, strict=True))
    for _, row in ok.iterrows():
        assert row["t_end"] - row["t_start"] == pytest.approx(SPEC_DRILL(length[row["hole_id"]]), abs=1e-9)
    for b, g in ok.groupby("boom"):  # a boom drills one hole at a time, in its order
        g = g.sort_values("order")
        assert list(g["order"]) == list(range(1, len(g) + 1))
        assert (g["t_start"].to_numpy()[1:] >= g["t_end"].to_numpy()[:-1] - 1e-9).all(), b
    traj = pd.read_csv(tmp / "small_trajectory.csv", keep_default_na=False)
    drilled = traj[traj["event"] == "collar"]["hole_id"]
    assert sorted(drilled) == sorted(ok["hole_id"])  # each drilled hole collared exactly once


def _script(name):
    import importlib.util  # a script of scripts/, loaded by path (scripts/ is not a package)

    spec = importlib.util.spec_from_file_location(f"{name}_script", PROJECT_ROOT / "scripts" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_independent_checker_on_the_trajectory_file(small_round):
    """scripts/check_round.py with the stage's own overrides: every hole drilled at its joints for its
    time, boom-boom >= d_boom, self and tunnel clear (certified), joint speeds and limits kept."""
    tmp, _, summary, _ = small_round
    stage = ["experiment=tiny", f"paths.data={tmp}/data", *FAST, f"plan={tmp / 'small.csv'}"]
    out = _script("check_round").check(tmp / "small_trajectory.csv", stage)
    assert not out["violations"] and not out["not_certified"], out["violations"] + out["not_certified"]
    assert out["min_boom_distance_certified_m"] >= 0.3 and summary["min_boom_clearance_m"] >= 0.3
    assert out["min_boom_distance_m"] < 0.3 + 1.0  # the booms come close on this face: not vacuous
    assert set(out["booms"]) == {"L", "R"} and out["instants"] > 1000
    assert summary["moves"]["failed"] == len(summary["moves_not_clear"]) == 0


def test_the_round_runs_by_events_and_the_independent_checker_executes_it(small_round):
    """Spec section 8: the stage writes the actions and interlocks files; the independent checker (its own
    execution rule and geometry) executes 300 random draws of 0.7-1.5x, every hole alone at 3x and each
    boom slow while the other is quick: no deadlock, no break of d_boom, and with the reference's durations
    the execution reproduces the trajectory file. The stage's own draws say the same."""
    tmp, _, summary, _ = small_round
    assert (tmp / "small_actions.csv").stat().st_size > 0 and (tmp / "small_interlocks.csv").exists()
    ex = summary["execution"]
    assert ex["robust"] and ex["deadlocks"] == 0 and ex["interlocks"]["conflicts_left"] == 0
    assert ex["nominal_makespan_s"] == pytest.approx(summary["makespan_s"])
    stage = ["experiment=tiny", f"paths.data={tmp}/data", *FAST, f"plan={tmp / 'small.csv'}"]
    out = _script("check_round").check(tmp / "small_trajectory.csv", stage, execute=300)
    run = out["execution"]
    assert run["checked"] and not out["violations"], out["violations"]
    assert run["deadlocks"] == 0 and run["violating_draws"] == 0 and run["draws"] >= 300 + summary["holes_drilled"]
    assert run["makespan_s"]["nominal"] == pytest.approx(run["makespan_s"]["trajectory"], abs=1.0)


def test_joint_speeds_respected_between_trajectory_rows(small_round, jumbo8):
    tmp, _, _, _ = small_round
    traj = pd.read_csv(tmp / "small_trajectory.csv", keep_default_na=False)
    limits = motion_from_config(load_group_file("motion", "jumbo8"), jumbo8).joints
    names = list(jumbo8.joint_names)
    for name in ("L", "R"):
        rows = traj[traj["boom"] == name]
        assert rows["event"].iloc[0] == "park" and rows["event"].iloc[-1] == "done"
        dt = np.diff(rows["t"].to_numpy())
        assert (dt > 0).all()
        speed = np.abs(np.diff(rows[names].to_numpy(), axis=0)) / dt[:, None]
        assert (speed <= np.array(limits.v) * (1 + 1e-9)).all()


def test_unreachable_hole_keeps_its_row_and_single_hole_works(face_plan, make_cfg):
    tmp, holes = face_plan
    far = pd.DataFrame([["FAR", 14.0, 0.0, 2.0, 17.5, 0.0, 2.0]], columns=COLS)
    bad = pd.DataFrame([["BAD", "abc", 0.0, 2.0, 9.5, 0.0, 2.0]], columns=COLS)
    plan = tmp / "two.csv"
    pd.concat([holes[COLS].iloc[[3]], bad, far], ignore_index=True).to_csv(plan, index=False)
    s = schedule.run(make_cfg(tmp, *FAST, f"plan={plan}", "schedule.replay=false"))
    r = pd.read_csv(tmp / "two_round.csv", keep_default_na=False, na_values=[""])
    assert list(r["hole_id"]) == [holes["hole_id"].iloc[3], "BAD", "FAR"]  # the plan's order, invalid row in place
    assert r.loc[1, "status"] == "invalid" and "row 3" in r.loc[1, "reason"] and "collar_x" in r.loc[1, "reason"]
    assert s["invalid_rows"] == 1
    row = r[r["hole_id"] == "FAR"].iloc[0]
    assert row["status"] == "unreachable" and "no boom can drill it" in row["reason"] and pd.isna(row["boom"])
    assert s["holes_drilled"] == 1 and s["holes_unreachable"] == 1
    # the hole that is drillable makes a single-hole round: park, move, drill, home, by one boom
    one = r[r["status"] == "ok"].iloc[0]
    assert s["makespan_s"] > one["t_end"] > one["t_start"] > 0
    assert s["makespan_s"] >= s["lower_bound_s"] > 0


def _ignore_sigint():
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # as a shell's background job (`&`) inherits it


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT-in-background"])
def test_a_signal_leaves_no_half_written_output_and_no_running_run(face_plan, signum):
    """SIGTERM, and SIGINT sent to a stage started in the background (SIGINT inherited ignored: a
    tester's ``kill -INT`` once let the stage plan on, replace the previous set and exit 0)."""
    tmp, holes = face_plan
    name = f"term{int(signum)}"
    plan = tmp / f"{name}.csv"
    holes.to_csv(plan, index=False)
    (tmp / f"{name}_round.csv").write_text("the previous set\n")
    cmd = [sys.executable, "-m", "pipeline.schedule", "experiment=tiny", f"paths.data={tmp}/data",
           f"tracking.uri=sqlite:///{tmp}/{name}.db", f"tracking.artifact_root={tmp}/{name}_art", *FAST,
           # every re-optimisation run (no stop near the bound): the signal lands while it plans, however fast the
           # machine (with the defaults, a fast run once published its set before the signal came). Each routing
           # solve keeps its count of checks: OR-Tools holds a signal until its solve returns (seconds here)
           "round.solution_limit=1000000", "round.stop_ratio=1.0",
           f"plan={plan}", f"hydra.run.dir={tmp}/hydra", "runtime.threads=1"]  # the other worker has the other core
    proc = subprocess.Popen(cmd, cwd=PROJECT_ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            preexec_fn=_ignore_sigint)
    deadline = time.monotonic() + 180
    while time.monotonic() < deadline:  # wait for the run, then a little into the planning
        assert proc.poll() is None, proc.communicate()
        try:
            with sqlite3.connect(f"file:{tmp}/{name}.db?mode=ro", uri=True) as db:
                if db.execute("select count(*) from runs where status = 'RUNNING'").fetchone()[0]:
                    break
        except sqlite3.OperationalError:
            pass
        time.sleep(0.5)
    time.sleep(3.0)
    proc.send_signal(signum)
    out, _ = proc.communicate(timeout=120)
    assert proc.returncode == 128 + signum, out
    with sqlite3.connect(f"{tmp}/{name}.db") as db:
        status = [s for (s,) in db.execute("select status from runs")]
    assert status == ["KILLED"]
    assert (tmp / f"{name}_round.csv").read_text() == "the previous set\n"
    left = [p.name for p in Path(tmp).iterdir() if p.name.startswith((f".{name}_round.", f"{name}_traj"))
            and not p.name.endswith(".lock")]
    assert not left, left


def test_out_is_checked_against_the_plan_before_any_work(face_plan, make_cfg):
    tmp, holes = face_plan
    plan = tmp / "P_trajectory.csv"
    holes.iloc[:3].to_csv(plan, index=False)
    before = plan.read_bytes()
    started = time.perf_counter()
    with pytest.raises(InputError, match="is the input .* itself"):
        schedule.run(make_cfg(tmp, *FAST, f"plan={plan}", f"out={tmp / 'P.csv'}"))
    assert plan.read_bytes() == before
    assert time.perf_counter() - started < 5  # refused before the reach table (which takes far longer)
    with pytest.raises(ConfigError, match=r"round.precedence\[0\].*cannot come before itself"):
        h = holes.hole_id[0]
        schedule.run(make_cfg(tmp, *FAST, f"plan={plan}", f"round.precedence=[[{h},{h}]]"))
    with pytest.raises(ConfigError, match=r"round.precedence\[0\].*no hole 'nope'"):
        schedule.run(make_cfg(tmp, *FAST, f"plan={plan}", f"round.precedence=[[{holes.hole_id[0]},nope]]"))


def test_a_plan_no_boom_can_drill_gets_its_table_and_a_clear_status(face_plan, make_cfg):
    tmp, _ = face_plan
    plan = tmp / "far.csv"
    pd.DataFrame([["FAR", 14.0, 0.0, 2.0, 17.5, 0.0, 2.0], ["FAR2", 15.0, 0.0, 2.0, 18.5, 0.0, 2.0]],
                 columns=COLS).to_csv(plan, index=False)
    s = schedule.run(make_cfg(tmp, *FAST, f"plan={plan}", "schedule.replay=false"))
    assert s["status"] == "none drillable" and s["holes_drilled"] == 0 and s["makespan_over_bound"] is None
    on_disk = json.loads((tmp / "far_round.json").read_text())
    assert on_disk["status"] == "none drillable"
    r = pd.read_csv(tmp / "far_round.csv", keep_default_na=False)
    assert list(r["status"]) == ["unreachable", "unreachable"] and all("no boom can drill" in x for x in r["reason"])


def test_a_one_boom_round_writes_its_actions_and_an_interlocks_file_without_rows(face_plan, make_cfg):
    """Spec section 8 for every rig: one boom's round has its actions (park to park, each hole drilled once,
    back to back in the trajectory's clock) and an interlocks file with the header alone; its draws
    stand nowhere, and the independent checker executes it."""
    tmp, holes = face_plan
    plan = tmp / "one_boom.csv"
    holes.iloc[::8].reset_index(drop=True).to_csv(plan, index=False)
    overrides = [o for o in FAST if not o.startswith("rig=")] + ["rig=single", "schedule.replay=false"]
    s = schedule.run(make_cfg(tmp, *overrides, f"plan={plan}"))
    acts = pd.read_csv(tmp / "one_boom_actions.csv", keep_default_na=False, na_values=[""])
    inter = pd.read_csv(tmp / "one_boom_interlocks.csv")
    assert list(inter.columns) == ["boom", "action", "after_boom", "after_action"] and len(inter) == 0
    assert (tmp / "one_boom_zones.csv").read_text() == "zone,boom,first_action,last_action\n"
    assert set(acts["boom"]) == {"B"} and list(acts["action"]) == list(range(len(acts)))
    assert sorted(acts.loc[acts["kind"] == "drill", "hole_id"]) == sorted(holes["hole_id"].iloc[::8])
    assert acts["kind"].iloc[0] == acts["kind"].iloc[-1] == "move" and acts["t_start"].iloc[0] == 0.0
    assert np.allclose(acts["t_start"].to_numpy()[1:], acts["t_end"].to_numpy()[:-1])  # nothing to wait for
    assert acts["t_end"].iloc[-1] == pytest.approx(s["makespan_s"])
    ex = s["execution"]
    assert ex["robust"] and ex["deadlocks"] == 0 and ex["interlocks"]["interlocks"] == 0
    assert ex["interlocks"]["min_clearance_m"] is None  # no pair of booms to measure
    assert ex["random"]["standing_share_max"] == 0.0 and ex["nominal_makespan_s"] == pytest.approx(s["makespan_s"])
    stage = ["experiment=tiny", f"paths.data={tmp}/data", *overrides, f"plan={plan}"]
    out = _script("check_round").check(tmp / "one_boom_trajectory.csv", stage, execute=50)
    run = out["execution"]
    assert not out["violations"] and run["checked"] and run["deadlocks"] == run["violating_draws"] == 0
    assert run["makespan_s"]["nominal"] == pytest.approx(run["makespan_s"]["trajectory"], abs=1.0)


@pytest.mark.skipif(shutil.which("chromium") is None and shutil.which("chromium-browser") is None,
                    reason="no chromium (apt-get install -y chromium)")
def test_replay_renders_in_a_headless_browser(small_round):
    tmp, _, _, _ = small_round
    problems = _script("check_replay").check(tmp / "small_round_replay.html", tmp / "replay.png")
    assert not problems, problems


@pytest.mark.slow
def test_round_benchmark_writes_its_table_and_each_cells_trajectory(face_plan, make_cfg):
    tmp, _ = face_plan
    out = schedule.run(make_cfg(tmp, *FAST, "schedule.benchmark=true", "schedule.bench_faces=[20]",
                                "schedule.bench_rigs=[single]"))
    assert out == {"rows": 1}
    table = pd.read_csv(tmp / "data" / "benchmark" / "round_benchmark.csv")
    row = table.iloc[0]
    assert row["rig"] == "single" and row["drilled"] == row["holes"] > 0
    assert row["lower_bound_s"] <= row["makespan_s"] <= min(row["naive_s"], row["nearest_s"]) + 1e-9
    assert row["moves_failed"] == 0
    traj = pd.read_csv(tmp / "data" / "benchmark" / "rounds" / "gen20_single_trajectory.csv", keep_default_na=False)
    assert traj["t"].max() == pytest.approx(row["makespan_s"])
    assert (traj["event"] == "collar").sum() == row["drilled"]
    # the round made robust as the stage makes it (one boom: nothing to wait for, no price), and every
    # cell's set written as the stage writes it, so that the independent checker executes it
    assert row["plan_makespan_s"] == pytest.approx(row["makespan_s"]) and row["robust_price_pct"] == 0
    assert row["interlocks"] == 0 and row["deadlocks"] == 0 and row["standing_p95_pct"] == 0
    assert row["order_p95_pct"] == row["zone_p95_pct"] == row["idle_after_p95_pct"] == 0  # one boom: never idle
    assert (tmp / "data" / "benchmark" / "rounds" / "gen20_single_zones.csv").read_text().startswith("zone,boom")
    assert 1.0 < row["exec_p95"] < 1.5  # drilling drawn 0.7-1.5x: later than planned, never by more than 1.5x
    stage = ["experiment=tiny", f"paths.data={tmp}/data", *FAST, "rig=single"]
    stage.remove("rig=twin")
    out = _script("check_round").check(tmp / "data" / "benchmark" / "rounds" / "gen20_single_trajectory.csv", stage,
                                       execute=50)
    assert not out["violations"] and out["holes"]["drilled"] == row["drilled"], out["violations"]
    assert out["execution"]["checked"] and out["execution"]["violating_draws"] == 0


def test_the_face_is_drawn_as_seen_from_the_rig(small_round):
    """Boom L (base y = +0.8 m) on the left of the face figure: y decreasing to the right, said on the axis."""
    from pipeline.assembly.rig import composed_rig
    from pipeline.round.figures import face_figure

    tmp, cfg, _, holes = small_round
    rig = composed_rig(cfg)
    r = pd.read_csv(tmp / "small_round.csv", keep_default_na=False, na_values=[""])
    collars = holes[["collar_x", "collar_y", "collar_z"]].to_numpy(float)
    ax = face_figure(r, collars, rig).axes[0]
    ax.figure.canvas.draw()  # the Agg canvas: data -> screen transforms are final
    screen_x = {b: ax.transData.transform(collars[(r["boom"] == b).to_numpy()][:, 1:])[:, 0].mean() for b in "LR"}
    assert screen_x["L"] < screen_x["R"] and ax.xaxis_inverted()
    assert "y decreasing to the right" in ax.get_xlabel() and "L) on the left" in ax.get_xlabel()


def test_a_motion_setting_reaches_the_round(small_round, make_cfg):
    """motion.joint_speeds.q1=7.5 (half the file's swing speed), and nothing else changed, raises the lower
    bound and changes the makespan."""
    tmp, _, base, _ = small_round
    slow = schedule.run(make_cfg(tmp, *FAST, f"plan={tmp / 'small.csv'}", f"out={tmp / 'slow' / 'slow_round.csv'}",
                                 "motion.joint_speeds.q1=7.5", "schedule.figures=false", "schedule.replay=false",
                                 "schedule.baselines=false"))
    assert slow["lower_bound_s"] > base["lower_bound_s"] + 1e-3
    assert slow["makespan_s"] != pytest.approx(base["makespan_s"], abs=1e-3)


def test_a_calibrated_boom_model_reaches_the_round_and_its_independent_check(small_round, make_cfg, jumbo8):
    """boom_model= (a calibrated jumbo8) makes every drilled hole's joints put the calibrated boom's collar on
    the hole, which the nominal boom at those joints misses by more than 5 mm. The independent checker, given
    the same boom_model=, reads the model file itself and passes the round; without it, it judges the
    round with the nominal boom and finds the holes missed."""
    from pipeline.calibration.model_file import load_model, save_model

    tmp, _, _, holes = small_round
    twists = torch.zeros(jumbo8.n_rows, 6, dtype=D)
    twists[1, :3] = torch.tensor([0.0035, -0.002, 0.003], dtype=D)
    twists[2, 3:] = torch.tensor([0.003, -0.003, 0.002], dtype=D)
    model_path = tmp / "calibrated.yaml"
    save_model(model_path, jumbo8, twists)
    stage = [*FAST, f"plan={tmp / 'small.csv'}", f"boom_model={model_path}"]
    schedule.run(make_cfg(tmp, *stage, f"out={tmp / 'calib' / 'calib_round.csv'}", "schedule.figures=false",
                          "schedule.replay=false", "schedule.baselines=false"))
    r = pd.read_csv(tmp / "calib" / "calib_round.csv", keep_default_na=False, na_values=[""])
    ok = r[r["status"] == "ok"]
    assert len(ok) == len(holes)
    model = load_model(model_path, jumbo8)
    collars = holes.set_index("hole_id")[["collar_x", "collar_y", "collar_z"]]
    for name, rows in ok.groupby("boom"):
        base_y = 0.8 if name == "L" else -0.8  # conf/rig/twin.yaml
        q = torch.tensor(rows[jumbo8.joint_names].to_numpy(float), dtype=D)
        want = torch.tensor(collars.loc[rows["hole_id"]].to_numpy(), dtype=D) - torch.tensor([0, base_y, 0], dtype=D)
        assert (model.tool_pose(q)[0] - want).norm(dim=-1).max() < 2e-5, name
        assert (jumbo8.tool_pose(q)[0] - want).norm(dim=-1).min() > 5e-3, name
    checker = _script("check_round")
    common = ["experiment=tiny", f"paths.data={tmp}/data"]
    out = checker.check(tmp / "calib" / "calib_trajectory.csv", [*common, *stage])
    assert not out["violations"] and not out["not_certified"], out["violations"] + out["not_certified"]
    nominal = checker.check(tmp / "calib" / "calib_trajectory.csv", [*common, *stage[:-1]])
    missed = [v for v in nominal["violations"] if "from its collar" in v]
    assert len(missed) == len(holes), nominal["violations"]

def test_small_round_json_reports_certified_floors_at_least_the_margins(small_round):
    tmp, _, summary, _ = small_round
    on_disk = json.loads((tmp / "small_round.json").read_text())
    floors, margins = on_disk["certified_floor_m"], on_disk["margin_m"]
    assert set(floors) == set(margins) == {"self", "tunnel", "boom"}
    for kind in floors:
        assert floors[kind] is not None and floors[kind] >= margins[kind], (kind, floors, margins)
    # the boom-boom floor: the oracle's 2 traj_tol_m wherever a boom moves, never above a measured clearance
    assert floors["boom"] <= 0.002 + 1e-12 and floors["boom"] <= summary["min_boom_clearance_m"] - 0.3 + 1e-9
    assert on_disk["moves_failed"] == 0 and on_disk["reproducible"] is True
    assert "planning_s" not in on_disk and "reach_solve_s" not in on_disk  # wall time: MLflow only


def test_two_runs_of_the_same_command_write_the_same_bytes(face_plan, make_cfg):
    """Counts, not wall time, limit the planning: every output of a second run, into the same place,
    has the first run's MD5 (round and trajectory CSV, JSON, the PNGs, the replays, the actions and
    interlocks files)."""
    from pipeline.core.io import file_md5

    tmp, holes = face_plan
    plan = tmp / "twice.csv"
    holes.iloc[1::9].reset_index(drop=True).to_csv(plan, index=False)
    from pipeline.round.output import SUFFIXES

    names = [f"twice{s}" for s in SUFFIXES.values()]  # the executed round's files too (actions, interlocks, ...)
    runs = []
    for _ in range(2):
        schedule.run(make_cfg(tmp, *FAST, f"plan={plan}"))
        runs.append({n: file_md5(tmp / n) for n in names})
    assert runs[0] == runs[1]


@pytest.mark.parametrize("planted, says", [
    ({"conflicts_left": 2}, "2 boom-boom conflict(s) left"),
    ({"moves_failed": 3}, "3 move(s) not certified clear (move_unclear)"),
    ({"sequential_fallback": True}, "the one-boom-at-a-time fallback was used"),
    ({"execution": {"robust": False, "problem": "a cycle", "deadlocks": 0}}, "cannot make the round robust: a cycle"),
    ({"execution": {"robust": True, "problem": None, "deadlocks": 4}}, "deadlock in 4 draw(s)"),
])
def test_every_unsafe_round_is_named_for_strict(planted, says):
    """What schedule.strict exits 1 for, one planted defect at a time on a clean summary (which has none)."""
    clean = {"conflicts_left": 0, "moves_failed": 0, "sequential_fallback": False,
             "execution": {"robust": True, "problem": None, "deadlocks": 0}}
    assert schedule.round_problems(clean) == []
    (line,) = schedule.round_problems({**clean, **planted})
    assert says in line


def test_strict_exits_1_on_a_round_with_failed_moves_and_marks_them(face_plan, make_cfg):
    """Detours off and a self margin no move keeps: every move fails certification. The set is still
    written (as solve does), the trajectory marks the failed moves move_unclear, the JSON counts them,
    and strict exits 1 naming them; without strict the same round exits 0 with a warning."""
    tmp, holes = face_plan
    plan = tmp / "unsafe.csv"
    holes.iloc[2::12].reset_index(drop=True).to_csv(plan, index=False)
    planted = [*FAST, f"plan={plan}", "round.detours=false", "round.self_margin_m=5.0", "schedule.figures=false",
               "schedule.replay=false"]
    with pytest.raises(StrictCheckFailed, match="schedule.strict: .*not certified clear"):  # exit 1 (run_stage)
        schedule.run(make_cfg(tmp, *planted, "schedule.strict=true"))
    s = json.loads((tmp / "unsafe_round.json").read_text())
    traj = pd.read_csv(tmp / "unsafe_trajectory.csv", keep_default_na=False)
    assert s["moves_failed"] == s["moves"]["failed"] > 0 and len(s["moves_not_clear"]) == s["moves_failed"]
    assert s["certified_floor_m"]["self"] < s["margin_m"]["self"] == 5.0
    assert (traj["event"] == "move_unclear").any() and not (traj["event"] == "move").any()
    again = schedule.run(make_cfg(tmp, *planted))  # strict off: written, warned, exit 0
    assert again["moves_failed"] == s["moves_failed"]
