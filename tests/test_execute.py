"""The execute stage and the interrupted round (docs/round.md, "The execute stage and an interrupted round").

One small twin round with interlocks is planned once (six holes of the demo face); the execute stage runs it
under drawn drilling times, interrupts one hole and hands the round on, and every executed set is
judged by the independent checker (a separate process) as well as by these tests' own counts.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from conftest import CHECK_STAGE

from pipeline.core.config import compose
from pipeline.core.errors import ConfigError, InputError

# the round planned with its postures chosen (round.postures at its default): the hand-on rebuilds them
STAGE = [s for s in CHECK_STAGE if s not in ("schedule.interlocks=false", "round.postures=1")] + [
    "draws.count=20", "execute.replay=false", "execute.figures=false"]


@pytest.fixture(scope="module")
def planned(tmp_path_factory):
    """A twin round of six demo-face holes, with its actions, interlocks and move book."""
    from pipeline import demo_face, schedule

    tmp = tmp_path_factory.mktemp("execute")
    base = ["experiment=tiny", f"paths.data={tmp}/data", f"tracking.uri=sqlite:///{tmp}/mlflow.db",
            f"tracking.artifact_root={tmp}/artifacts"]
    demo_face.run(compose(base))
    holes = pd.read_csv(tmp / "data" / "plans" / "demo_face.csv")
    plan = tmp / "small.csv"
    holes.iloc[::11].reset_index(drop=True).to_csv(plan, index=False)
    overrides = [*base, *STAGE, f"plan={plan}"]
    schedule.run(compose(overrides))
    return tmp, overrides


def run(planned, *extra, folder=None):
    from pipeline import execute

    tmp, overrides = planned
    ov = [*overrides, *extra] + ([f"execute.out={folder}"] if folder else [])
    return execute.run_execute(compose(ov), ov)


def first_drill(tmp, boom="L"):
    acts = pd.read_csv(tmp / "small_actions.csv", keep_default_na=False)
    return acts[(acts["boom"] == boom) & (acts["kind"] == "drill")].iloc[0]


@pytest.mark.slow
def test_rows_retimed_at_planned_times_are_the_planned_file(planned):
    """The realised-trajectory writer, given the planned times, gives back the planned trajectory file."""
    from pipeline.events.actions import actions_from_table, read_actions
    from pipeline.events.trajectory import action_rows, retimed

    tmp, _ = planned
    traj = pd.read_csv(tmp / "small_trajectory.csv", keep_default_na=False)
    ids = pd.read_csv(tmp / "small.csv")["hole_id"].astype(str).tolist()
    acts = actions_from_table(read_actions(tmp / "small_actions.csv"), ("L", "R"), ids)
    joints = [c for c in traj.columns if c.startswith("q")]
    again = retimed(acts, action_rows(traj, acts, joints), acts.t_start, acts.t_end, joints)
    assert list(again["event"]) == list(traj["event"])
    assert list(again["hole_id"]) == list(traj["hole_id"])
    np.testing.assert_allclose(again["t"], traj["t"], atol=1e-9)
    np.testing.assert_array_equal(again[joints].to_numpy(), traj[joints].to_numpy())


@pytest.mark.slow
def test_executed_draw_is_checked_and_reports_what_ran_long(planned, tmp_path):
    out = run(planned, "execute.draw=3", folder=tmp_path)
    assert out["status"] == "complete" and out["holes_left"] == []
    assert out["checks"]["planned_draws"]["exit"] == 0, out["checks"]
    assert out["checks"]["realised"]["exit"] == 0, out["checks"]
    assert out["checks"]["planned_draws"]["verdict"]["execution"]["violating_draws"] == 0
    table = pd.read_csv(tmp_path / "small_executed_round.csv", keep_default_na=False)
    assert (table["status"] == "ok").all()
    draws = pd.read_csv(tmp_path / "small_draws.csv", keep_default_na=False)
    f = draws[draws["draw"] == 3].set_index("hole_id")["factor"]
    took = (table["t_end"] - table["t_start"]).to_numpy()
    acts = pd.read_csv(planned[0] / "small_actions.csv", keep_default_na=False)
    planned_s = acts[acts["kind"] == "drill"].set_index("hole_id").eval("t_end - t_start")
    np.testing.assert_allclose(took, f[table["hole_id"]].to_numpy() * planned_s[table["hole_id"]].to_numpy(),
                               rtol=1e-9)
    long = {r["hole_id"] for r in out["ran_long"]}
    assert long == {h for h in table["hole_id"] if f[h] > 1} or len(long) == 10
    doc = json.loads((tmp_path / "small_executed.json").read_text())
    assert doc["checks"] == out["checks"] and doc["makespan_s"] == pytest.approx(
        pd.read_csv(tmp_path / "small_executed_trajectory.csv")["t"].max())


@pytest.mark.slow
def test_interrupted_hole_is_left_and_the_rest_handed_on(planned, tmp_path):
    tmp, _ = planned
    d = first_drill(tmp)
    at = 0.5 * (d["t_end"] - d["t_start"])
    out = run(planned, "execute.draw=nominal", f"execute.interrupt.hole={d['hole_id']}", f"execute.interrupt.at_s={at}",
              folder=tmp_path)
    assert out["status"] == "interrupted" and out["holes_left"] == [d["hole_id"]]
    assert out["interrupt"]["move_book"] is True  # the planner's book, re-used: the same joints rebuilt
    chose = json.loads((tmp / "small_round.json").read_text())["postures"]
    assert chose["chosen"] and chose["changed"] > 0  # ... from the round table's postures, not the reach table's
    assert out["handed_on"]["robust"] and out["handed_on"]["conflicts_left"] == 0
    assert out["checks"]["realised"]["exit"] == 0, out["checks"]
    table = pd.read_csv(tmp_path / "small_executed_round.csv", keep_default_na=False)
    status = table.set_index("hole_id")["status"]
    assert status[d["hole_id"]] == "interrupted"
    assert (status.drop(d["hole_id"]) == "ok").all()  # every other hole drilled ...
    traj = pd.read_csv(tmp_path / "small_executed_trajectory.csv", keep_default_na=False)
    collars = traj[traj["event"] == "collar"]["hole_id"]
    assert sorted(collars) == sorted(table["hole_id"])  # ... once each, the left one collared once
    row = table.set_index("hole_id").loc[d["hole_id"]]
    assert row["t_end"] - row["t_start"] == pytest.approx(at)
    # before the interruption the round is the planned one (nominal durations: the same rows at the same
    # times), but for the interrupted hole's own drilling, cut short
    plan_traj = pd.read_csv(tmp / "small_trajectory.csv", keep_default_na=False)
    t_i = out["interrupt"]["t_s"]

    def early(df):
        keep = (df["t"] < t_i - 1e-6) & ~((df["boom"] == "L") & (df["t"] >= d["t_start"] - 1e-9))
        return df[keep].sort_values(["boom", "t"]).reset_index(drop=True)

    pd.testing.assert_frame_equal(early(traj), early(plan_traj), check_dtype=False)


@pytest.mark.slow
def test_interrupted_round_goes_on_without_replanning(planned, tmp_path):
    tmp, _ = planned
    d = first_drill(tmp, "R")
    out = run(planned, f"execute.interrupt.hole={d['hole_id']}", "execute.interrupt.at_s=5", "execute.replan=false",
              "execute.monte_carlo=false", folder=tmp_path)
    assert out["holes_left"] == [d["hole_id"]] and "handed_on" not in out
    assert out["checks"]["realised"]["exit"] == 0, out["checks"]
    table = pd.read_csv(tmp_path / "small_executed_round.csv", keep_default_na=False)
    assert (table["status"] == "ok").sum() == len(table) - 1


@pytest.mark.slow
def test_bad_settings_and_inputs_are_named(planned, tmp_path):
    tmp, _ = planned
    d = first_drill(tmp)
    with pytest.raises(ConfigError, match="at_s"):
        run(planned, f"execute.interrupt.hole={d['hole_id']}", "execute.interrupt.at_s=99999", folder=tmp_path)
    with pytest.raises(ConfigError, match="no such hole"):
        run(planned, "execute.interrupt.hole=NOPE", "execute.interrupt.at_s=1", folder=tmp_path)
    with pytest.raises(ConfigError, match="both hole and at_s"):
        run(planned, f"execute.interrupt.hole={d['hole_id']}", folder=tmp_path)
    with pytest.raises(ConfigError, match="draws.factors.NOPE"):
        run(planned, "+draws.factors.NOPE=2.0", folder=tmp_path)
    with pytest.raises(ConfigError, match="planned round .* is of rig 'twin'"):
        run(planned, "rig=trio", folder=tmp_path)
    with pytest.raises(InputError, match="not found"):
        run(planned, f"execute.round={tmp_path}/elsewhere_round.csv", folder=tmp_path)
    assert not list(tmp_path.glob("small_executed*"))  # nothing written for any of them


def test_fixed_factors_and_stalls_in_every_draw():
    from pipeline.events.actions import Actions
    from pipeline.events.draws import draws, parse_draws

    acts = Actions(("L",), ("a", "b", "c"), np.zeros(7, int), np.arange(7),
                   np.array(["move", "drill"] * 3 + ["move"]), np.array([-1, 0, -1, 1, -1, 2, -1]),
                   np.array([3, 0, 0, 1, 1, 2, 2]), np.array([0, 0, 1, 1, 2, 2, 3]), np.arange(7.0), np.arange(1, 8.0))
    s = parse_draws({"count": 200, "stall_p": 0.25, "stall_factor": 3.0, "factors": {"b": 2.5}})
    d = draws(acts, s)
    assert np.all(d.factors[:, 1] == 2.5)
    rand = d.factors[:200, [0, 2]]
    stalled = rand > 1.5  # uniform 0.7-1.5, a stall x3 lifts it to 2.1-4.5
    assert 0.15 < stalled.mean() < 0.35 and np.all(rand[stalled] >= 2.1 - 1e-12)
    plain = draws(acts, parse_draws({"count": 200}))
    np.testing.assert_array_equal(plain.factors[:200, [0, 2]][~stalled], rand[~stalled])  # same seeded draws
    with pytest.raises(ConfigError, match="stall_p"):
        parse_draws({"stall_p": 1.5})


@pytest.mark.slow
def test_a_navigation_other_than_the_planned_one_is_refused_before_any_work(planned, tmp_path):
    """The round's joints drill the plan where its navigation put the rig: executing it with another pose (or a
    pose where it was planned with none) would drill the plan somewhere else."""
    with pytest.raises(ConfigError, match=r"navigation: .*small_round.json was planned with the rig at "
                                          r"\[0.0, 0.0, 0.0, 0.0, 0.0, 0.0\] \(\[x, y, z, yaw, pitch, roll\], none\), "
                                          r"this run puts it at \[0.5, 0.0, 0.0, 0.0, 0.0, 0.0\]"):
        run(planned, "navigation.pose=[0.5,0,0,0,0,0]", folder=tmp_path)
    assert not any(tmp_path.iterdir())  # nothing written


# ---------------------------------------------------------------------------------------------
# execute runs only the files it planned, publishes only what was checked, refuses with a name


PLANNED = ("small_trajectory.csv", "small_actions.csv", "small_interlocks.csv", "small_zones.csv", "small_round.csv",
           "small_round.json", "small_moves.npz", "small_problem.npz")


def _copy_set(planned, dst):
    """The plan and its planned set copied to ``dst`` (the module's own stay untouched): the overrides there."""
    import shutil

    tmp, overrides = planned
    dst.mkdir(parents=True, exist_ok=True)
    for name in ("small.csv", *PLANNED):
        shutil.copy(tmp / name, dst / name)
    return [o for o in overrides if not o.startswith("plan=")] + [f"plan={dst / 'small.csv'}"]


def _stage(overrides):
    """The stage as ``main`` runs it (``run_stage``): its exit code and what it said on stderr."""
    import contextlib
    import io

    from pipeline import execute
    from pipeline.core.stage import run_stage

    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        try:
            run_stage(compose(overrides), lambda c: execute.run_execute(c, overrides), threads=None)
            code = 0
        except SystemExit as e:
            code = e.code
    return code, err.getvalue()


def _rewrite_manifest(folder, name):
    """The JSON's manifest made to agree with an edited file (what a careful forger would do)."""
    from pipeline.core.io import file_md5

    doc = json.loads((folder / "small_round.json").read_text())
    doc["files"][name] = file_md5(folder / name)
    (folder / "small_round.json").write_text(json.dumps(doc))


def _edit_csv(path, edit):
    df = pd.read_csv(path, keep_default_na=False, dtype={"hole_id": str})
    edit(df)
    df.to_csv(path, index=False)


def _mark_all_clear(path):
    with np.load(path, allow_pickle=False) as z:
        data = {k: z[k] for k in z.files}
    data["status"] = np.ones_like(data["status"])  # every move "certified clear"
    with open(path, "wb") as f:
        np.savez_compressed(f, **data)


def _md5_edited(path):
    doc = json.loads(path.read_text())
    doc["files"]["small_trajectory.csv"] = "0" * 32
    path.write_text(json.dumps(doc))


TAMPERED = {  # what is edited -> (edit of the copy, the file the refusal names)
    "plan moved 0.5 m": (lambda d: _edit_csv(d / "small.csv", lambda df: df.__setitem__(
        "collar_x", df["collar_x"] + 0.5)), "small.csv"),
    "actions": (lambda d: _edit_csv(d / "small_actions.csv", lambda df: df.__setitem__(
        "t_end", df["t_end"] * 0.9)), "small_actions.csv"),
    "interlocks": (lambda d: _edit_csv(d / "small_interlocks.csv", lambda df: df.drop(df.index[:1], inplace=True)),
                   "small_interlocks.csv"),
    "a zone added": (lambda d: (d / "small_zones.csv").write_text(
        (d / "small_zones.csv").read_text() + "z,L,1,1\nz,R,1,1\n"), "small_zones.csv"),
    "trajectory joints": (lambda d: _edit_csv(d / "small_trajectory.csv", lambda df: df.__setitem__(
        "q1", df["q1"] + 0.01)), "small_trajectory.csv"),
    "round table": (lambda d: _edit_csv(d / "small_round.csv", lambda df: df.__setitem__(
        "boom", df["boom"][::-1].to_numpy())), "small_round.csv"),
    "move book marked all-clear": (lambda d: _mark_all_clear(d / "small_moves.npz"), "small_moves.npz"),
    "the JSON's MD5": (lambda d: _md5_edited(d / "small_round.json"), "small_trajectory.csv"),
    "problem's joints": (lambda d: _shift_problem(d / "small_problem.npz"), "small_problem.npz"),
}


def _shift_problem(path):
    """The round's problem with boom L's joints moved 0.01 rad: a valid file, just not the planned one."""
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["joints"] = arrays["joints"] + 0.01
    with open(path, "wb") as f:
        np.savez_compressed(f, **arrays)


@pytest.mark.slow
@pytest.mark.parametrize("what", list(TAMPERED))
def test_a_tampered_planned_file_is_refused_naming_it_and_nothing_is_written(planned, tmp_path, what):
    """Every file execute reads must be the one schedule wrote (the JSON's manifest) and the plan the one it
    was planned from (plan_md5): a plan moved 0.5 m, edited actions, interlocks, joints or round table, a
    move book marked all-clear or an edited MD5 is refused, exit 2 naming the file, before any work."""
    edit, named = TAMPERED[what]
    ov = _copy_set(planned, tmp_path / "set") + [f"execute.out={tmp_path / 'out'}", "execute.monte_carlo=false"]
    edit(tmp_path / "set")
    code, err = _stage(ov)
    assert code == 2, err
    assert named in err and ("changed since schedule wrote it" in err or "not the plan" in err), err
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())  # nothing written
    assert "Traceback" not in err


@pytest.mark.slow
def test_malformed_planned_files_are_named_never_a_traceback(planned, tmp_path):
    """A planned file that does not parse is refused naming the file and the place, also when its manifest was
    made to agree (a forger's edit); a truncated or foreign move book likewise."""
    from pipeline.round.move_file import load_book
    from pipeline.round.settings import RoundSettings

    ov = _copy_set(planned, tmp_path / "set") + [f"execute.out={tmp_path / 'out'}", "execute.monte_carlo=false"]
    d = tmp_path / "set"
    good = (d / "small_round.json").read_text()
    (d / "small_round.json").write_text(good[: len(good) // 2])  # truncated JSON
    from pipeline import execute

    with pytest.raises(InputError, match=r"small_round.json: not valid JSON \(line \d+, column \d+"):
        execute.run_execute(compose(ov), ov)
    (d / "small_round.json").write_text(good)
    text = (d / "small_trajectory.csv").read_text()
    (d / "small_trajectory.csv").write_text(text[: int(len(text) * 0.6)])  # cut mid-row
    _rewrite_manifest(d, "small_trajectory.csv")
    code, err = _stage(ov)
    assert code == 2 and "small_trajectory.csv: " in err and "Traceback" not in err, err
    book = d / "small_moves.npz"
    data = book.read_bytes()
    for bad in (data[: len(data) // 3], b"not a zip at all"):
        book.write_bytes(bad)
        with pytest.raises(InputError, match="small_moves.npz: cannot read it as a move book"):
            load_book(book, None, 6, RoundSettings())
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


@pytest.mark.slow
def test_an_iredes_plan_is_executed_with_its_checks_running_on_its_holes(planned, tmp_path):
    """The checker reads CSV plans only: for an IREDES plan the execute stage writes the holes it read, as CSV,
    into the set (``<stem>_executed_plan.csv``, in the JSON's ``plan_holes``) and the checks run on them.

    The set is the one schedule writes for the XML plan of the same holes (IREDES written with repr reads
    back to the same floats, checked here), so the CSV plan's set is re-labelled (its JSON's plan and
    plan_md5) rather than planned again (about 40 s)."""
    import subprocess
    import sys

    from pipeline.core.config import PROJECT_ROOT
    from pipeline.core.io import file_md5
    from pipeline.plans.iredes import write_iredes_plan
    from pipeline.plans.read import read_plan

    ov = _copy_set(planned, tmp_path / "set")
    d = tmp_path / "set"
    write_iredes_plan(read_plan(d / "small.csv"), d / "small.xml")
    a, b = read_plan(d / "small.csv").holes, read_plan(d / "small.xml").holes
    cols = ["hole_id", "collar_x", "collar_y", "collar_z", "toe_x", "toe_y", "toe_z"]
    pd.testing.assert_frame_equal(a[cols], b[cols])
    doc = json.loads((d / "small_round.json").read_text())
    doc.update(plan=str(d / "small.xml"), plan_md5=file_md5(d / "small.xml"))
    (d / "small_round.json").write_text(json.dumps(doc))
    ov = [o for o in ov if not o.startswith("plan=")] + [f"plan={d / 'small.xml'}", f"execute.out={tmp_path / 'out'}"]
    from pipeline import execute

    out = execute.run_execute(compose(ov), ov)
    assert out["plan_holes"] == "small_executed_plan.csv"
    for k in ("planned_draws", "realised"):
        c = out["checks"][k]
        assert c["exit"] == 0, out["checks"]
        assert c["verdict"]["plan"] == "small_executed_plan.csv"  # the checks read the holes as read ...
        assert c["verdict"]["holes"]["plan"] == 6 and c["verdict"]["holes"]["drilled"] == 6  # ... and judged them
    holes = pd.read_csv(tmp_path / "out" / "small_executed_plan.csv", dtype={"hole_id": str})
    pd.testing.assert_frame_equal(holes[cols], a[cols])
    # the published set checks again on its own, the checker finding the holes from the JSON
    p = subprocess.run([sys.executable, str(PROJECT_ROOT / "scripts" / "check_round.py"),
                        str(tmp_path / "out" / "small_executed_trajectory.csv"), *ov, "--realised"],
                       capture_output=True, text=True, cwd=PROJECT_ROOT)
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["plan"].endswith("small_executed_plan.csv")


@pytest.mark.slow
def test_a_signal_during_the_checks_leaves_the_previous_set_and_no_running_run(planned, tmp_path, monkeypatch):
    """SIGTERM or SIGINT while the checker runs: nothing unchecked is published (the previous set stays,
    byte for byte), no stage folder is left, the run ends KILLED, exit 128 + signum. A check that cannot
    judge the set (the checker's exit 2) or fails (exit 3) publishes nothing either."""
    import signal

    from mlflow.tracking import MlflowClient

    from pipeline import execute
    from pipeline.core.io import file_md5
    from pipeline.core.signals import Terminated

    out = tmp_path / "out"
    ov = [*planned[1], f"execute.out={out}", "execute.monte_carlo=false"]
    execute.run_execute(compose(ov), ov)  # the previous set
    before = {p.name: file_md5(p) for p in out.iterdir()}

    def interrupted(signum):
        def check(args, what):
            raise Terminated(signum)
        return check

    for signum in (signal.SIGTERM, signal.SIGINT):
        monkeypatch.setattr(execute, "_check", interrupted(signum))
        with pytest.raises(SystemExit) as e:
            execute.run_execute(compose(ov), ov)
        assert e.value.code == 128 + signum
        assert {p.name: file_md5(p) for p in out.iterdir()} == before  # no half-written or unchecked file
    for code, exit_code in ((2, 2), (3, 3)):
        monkeypatch.setattr(execute, "_check", lambda args, what, c=code: {"exit": c, "seconds": 0.0, "verdict": None,
                                                                          "stderr": "check_round: planted"})
        got, err = _stage(ov)
        assert got == exit_code and "nothing published" in err, err
        assert {p.name: file_md5(p) for p in out.iterdir()} == before
    client = MlflowClient(f"sqlite:///{planned[0]}/mlflow.db")
    runs = client.search_runs([e.experiment_id for e in client.search_experiments()],
                              "tags.stage = 'execute'", order_by=["attributes.start_time DESC"], max_results=4)
    assert [r.info.status for r in runs] == ["FAILED", "FAILED", "KILLED", "KILLED"]
    every = [e.experiment_id for e in client.search_experiments()]
    assert not client.search_runs(every, "attributes.status = 'RUNNING'")
    assert not [p for p in out.iterdir() if p.name.endswith(".tmp")]  # no stage folder or temporary file left


@pytest.mark.slow
def test_unknown_and_out_of_range_replan_round_settings_are_refused(planned, tmp_path):
    with pytest.raises(ConfigError, match="execute.replan_round.nope: unknown setting"):
        run(planned, "+execute.replan_round.nope=1", folder=tmp_path)
    with pytest.raises(ConfigError, match=r"execute.replan_round.postures = 100000: must be <= 64"):
        run(planned, "+execute.replan_round.postures=100000", folder=tmp_path)
    with pytest.raises(ConfigError, match=r"draws.high = 1e\+300: must be <= 100"):
        run(planned, "draws.high=1e300", folder=tmp_path)
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("parse_name, node, match", [
    ("draws", {"high": 1e300}, r"draws.high = 1e\+300: must be <= 100"),
    ("draws", {"count": 10**7}, r"draws.count = 10000000: must be <= 10000"),
    ("draws", {"factors": {"H1": 1e9}}, r"draws.factors.H1 = 1000000000.0: expected a factor in \(0, 100\]"),
    ("round", {"postures": 100000}, r"round.postures = 100000: must be <= 64"),
    ("round", {"posture_starts": 10**8}, r"round.posture_starts = 100000000: must be <= 1024"),
    ("round", {"sample_m": 1e-9}, r"round.sample_m = 1e-09: must be >= 0.001"),
    ("round", {"time_limit_s": 1e12}, r"round.time_limit_s = 1000000000000.0: must be <= 86400"),
    ("round", {"sweep_more_bands_m": [1e300]}, r"round.sweep_more_bands_m\[0\] = 1e\+300"),
])
def test_size_and_duration_settings_have_ranges(parse_name, node, match):
    from pipeline.events.draws import parse_draws
    from pipeline.round.settings import parse_round

    parse = {"draws": parse_draws, "round": parse_round}[parse_name]
    with pytest.raises(ConfigError, match=match):
        parse(node, parse_name)


@pytest.mark.slow
def test_the_as_drilled_log_is_where_the_true_boom_drilled(planned, tmp_path):
    """execute.true_boom_model: every hole of the executed round logged (IREDES DRPQual, documented checksum),
    its collar the true boom's forward kinematics at the joints the drill rows hold (plus the boom's base),
    within 0.01 mm, its toe the hole's length along the true drilling direction; read back by the quality stage
    it is off the plan at the field level. Without it, the log is the plan (the planning model drills it)."""
    import torch

    from pipeline.assembly.build import load_boom
    from pipeline.calibration.error_model import BoomWithErrors, ErrorLevel, draw_errors
    from pipeline.calibration.model_file import save_model
    from pipeline.plans.deviations import deviations
    from pipeline.plans.drpqual import read_quality_log

    tmp, _ = planned
    jumbo8 = load_boom("jumbo8")
    twists = draw_errors(jumbo8, ErrorLevel(angle_deg=0.2, tilt_deg=0.2, offset_mm=5.0), seed=13)
    save_model(tmp_path / "true_boom.yaml", jumbo8, twists)
    out = run(planned, "execute.draw=nominal", f"execute.true_boom_model={tmp_path / 'true_boom.yaml'}",
              "execute.monte_carlo=false", folder=tmp_path / "true")
    assert out["as_drilled"]["holes"] == 6 and out["as_drilled"]["boom"].startswith("execute.true_boom_model=")
    log = read_quality_log(tmp_path / "true" / "small_executed_quality.xml")
    assert log.checksum == "verified" and log.checksum_convention == "documented"
    traj = pd.read_csv(tmp_path / "true" / "small_executed_trajectory.csv", keep_default_na=False)
    drills = traj[traj["event"] == "drill"].drop_duplicates("hole_id").set_index("hole_id")
    q = torch.tensor(drills.loc[log.holes["hole_id"], [f"q{i}" for i in range(1, 9)]].to_numpy(float))
    p, z = BoomWithErrors(jumbo8, twists).tool_pose(q)
    base = np.array([[0.0, 0.8, 0.0] if b == "L" else [0.0, -0.8, 0.0] for b in log.holes["boom"]])
    np.testing.assert_allclose(log.holes[["collar_x", "collar_y", "collar_z"]].to_numpy(), p.numpy() + base,
                               atol=1e-5)
    plan = pd.read_csv(tmp / "small.csv", dtype={"hole_id": str}).set_index("hole_id").loc[log.holes["hole_id"]]
    length = np.linalg.norm(plan[["toe_x", "toe_y", "toe_z"]].to_numpy() - plan[["collar_x", "collar_y",
                                                                                  "collar_z"]].to_numpy(), axis=1)
    np.testing.assert_allclose(log.holes[["toe_x", "toe_y", "toe_z"]].to_numpy(),
                               p.numpy() + base + length[:, None] * z.numpy(), atol=1e-5)
    off = deviations(plan.reset_index(), log.holes)[1]
    assert off["collar_dev_m_mean"] > 0.01  # the field level: centimetres, not the plan
    nominal = run(planned, "execute.draw=nominal", "execute.monte_carlo=false", folder=tmp_path / "nominal")
    assert nominal["as_drilled"]["boom"] == "the planning model"
    same = deviations(plan.reset_index(), read_quality_log(tmp_path / "nominal" / "small_executed_quality.xml").holes)
    assert same[1]["collar_dev_m_max"] < 1e-5 and same[1]["within"] == 6


def test_the_problem_schedule_wrote_is_the_instance_a_new_reach_solve_gives(planned):
    """What execute re-plans a handed-on round on, loaded from ``<stem>_problem.npz``, against the way it was
    built before that file existed: the reach table solved again, each planned hole at its round-table joints."""
    from pipeline.assembly.rig import composed_rig
    from pipeline.core.config import as_dict
    from pipeline.core.settings import parse
    from pipeline.motion.timing import rig_motions
    from pipeline.plans.reach import solved_reach
    from pipeline.plans.read import read_plan
    from pipeline.round.from_plan import planned_joints, problem_instance, round_instance
    from pipeline.round.problem_file import load_problem
    from pipeline.round.settings import parse_round
    from pipeline.solvers.hybrid import HybridSettings
    from pipeline.solvers.network_start import first_starts, network_source

    tmp, overrides = planned
    cfg = compose(overrides)
    rig = composed_rig(cfg)
    plan = read_plan(tmp / "small.csv")
    settings, motions = parse_round(as_dict(cfg.round)), rig_motions(as_dict(cfg.motion), rig.booms)
    names = list(rig.booms[0].boom.joint_names)
    ids = plan.holes["hole_id"].astype(str).tolist()
    problem = load_problem(tmp / "small_problem.npz", rig.names, ids, names)
    loaded, _ = problem_instance(rig, plan, problem, motions, settings)

    network = cfg.schedule.network  # null here: random starts, seeded, as schedule drew them
    first = first_starts(network_source(tmp / "data", network, None), network, None, "schedule.model_uri")
    box = cfg.holes.sup.get("box")
    _, reach = solved_reach(plan, rig, first, parse(HybridSettings, cfg.solver, "solver"),
                            None if box is None else as_dict(box), "hybrid")
    table = pd.read_csv(tmp / "small_round.csv", keep_default_na=False)
    solved, _, _ = round_instance(rig, plan, reach, motions, settings, planned_joints(rig, plan, reach, table, names))
    np.testing.assert_array_equal(loaded.reach, solved.reach)
    np.testing.assert_allclose(loaded.move_s, solved.move_s, rtol=0, atol=1e-9)
    np.testing.assert_allclose(loaded.phases, solved.phases, rtol=0, atol=1e-12)
    assert loaded.reasons == solved.reasons and loaded.reach.any()


@pytest.mark.slow
def test_a_zone_is_followed_and_a_trajectory_that_does_not_follow_it_is_caught(planned, tmp_path):
    """A zone put into the planned set, its MD5 in the manifest as a planner writes it: the two booms' moves
    back to park, which run at once in the plan. The realised round follows the rule with the zone (the
    later boom waits at its last hole; the executed set carries the zone) and the independent checker,
    reading it, passes the realised set. The planned trajectory, though, still has both moves at once,
    which the zone forbids: the checker of the planned draws finds that the rule with the model durations
    does not give the planned file (a planted fault the stage itself does not look for, exit 1 there)."""
    from pipeline import execute

    d = tmp_path / "set"
    ov = _copy_set(planned, d) + [f"execute.out={tmp_path / 'out'}", "execute.draw=nominal"]
    acts = pd.read_csv(d / "small_actions.csv", keep_default_na=False)
    last = acts.loc[acts.groupby("boom")["action"].idxmax()].set_index("boom")
    assert last["t_start"].max() < last["t_end"].min(), "the plan's moves to park must overlap for this test"
    zones = "zone,boom,first_action,last_action\n" + "".join(f"park,{b},{a},{a}\n" for b, a in last["action"].items())
    (d / "small_zones.csv").write_text(zones)
    _rewrite_manifest(d, "small_zones.csv")
    out = execute.run_execute(compose(ov), ov)
    assert out["checks"]["realised"]["exit"] == 0, out["checks"]
    done = pd.read_csv(tmp_path / "out" / "small_executed_actions.csv", keep_default_na=False)
    moves = done.loc[done.groupby("boom")["action"].idxmax()]
    assert moves["t_start"].max() >= moves["t_end"].min() - 1e-9  # one after the other
    # the model durations: the boom that would have moved at once waits at its last hole, for the zone, and
    # ends that much later; the other ends as planned, and the round ends with the later of the two
    assert out["makespan_s"] > out["nominal_makespan_s"] + 1.0
    standing = out["standing_for_zones_s"]
    waited = max(standing, key=standing.get)
    end = {b: done.loc[done["boom"] == b, "t_end"].max() for b in standing}
    assert end[waited] - last.loc[waited, "t_end"] == pytest.approx(standing[waited]) and standing[waited] > 1.0
    assert all(end[b] == pytest.approx(last.loc[b, "t_end"]) for b in standing if b != waited)
    assert out["makespan_s"] == pytest.approx(max(end.values()))
    assert (tmp_path / "out" / "small_executed_zones.csv").read_text() == zones
    assert out["monte_carlo"]["deadlocks"] == 0
    planned_check = out["checks"]["planned_draws"]
    assert planned_check["exit"] == 1 and planned_check["verdict"]["execution"]["violating_draws"] == 0
    assert planned_check["verdict"]["violations"] == 2  # the makespan and the move that starts later


@pytest.mark.slow
def test_a_bad_zones_file_exits_2_naming_it_and_a_round_with_zones_is_handed_on_with_its_entry_orders(planned,
                                                                                                         tmp_path):
    """A zones file the manifest vouches for but that names an action its boom does not have: refused,
    exit 2, the file and the row named, nothing written. A good zone with execute.interrupt: the round is
    handed on with the zone's planned entry order as an interlock (pipeline.events.zones.entry_orders),
    and the independent checker passes the realised set."""
    d = tmp_path / "set"
    ov = _copy_set(planned, d) + [f"execute.out={tmp_path / 'out'}", "execute.monte_carlo=false"]
    (d / "small_zones.csv").write_text("zone,boom,first_action,last_action\nz,L,1,1\nz,R,99,99\n")
    _rewrite_manifest(d, "small_zones.csv")
    code, err = _stage(ov)
    assert code == 2 and "small_zones.csv: row 3: first_action = 99: boom 'R' has no action 99" in err, err
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())  # nothing written
    acts = pd.read_csv(d / "small_actions.csv", keep_default_na=False)
    last = acts.loc[acts.groupby("boom")["action"].idxmax()].set_index("boom")
    (d / "small_zones.csv").write_text("zone,boom,first_action,last_action\n"
                                       + "".join(f"park,{b},{a},{a}\n" for b, a in last["action"].items()))
    _rewrite_manifest(d, "small_zones.csv")
    hole = first_drill(d)["hole_id"]
    code, err = _stage([*ov, f"execute.interrupt.hole={hole}", "execute.interrupt.at_s=5"])
    assert code == 0, err
    out = json.loads(next((tmp_path / "out").glob("*_executed.json")).read_text())
    assert out["zones_fixed_for_hand_on"] == 1 and out["checks"]["realised"]["exit"] == 0, out["checks"]
    assert "Traceback" not in err
