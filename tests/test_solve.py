"""The solve stage: a drill plan in (CSV or IREDES), exact and clear joints out, a status per hole,
bad rows named and skipped, strict mode, MLflow, and the network from an MLflow model URI."""

import json
import subprocess
import sys

import pandas as pd
import pytest
import torch
from mlflow.tracking import MlflowClient

from pipeline import solve
from pipeline.core.config import PROJECT_ROOT
from pipeline.core.errors import InputError, StrictCheckFailed
from pipeline.evaluation.metrics import solution_table
from pipeline.plans.csv_plan import read_csv_plan, write_csv_plan
from pipeline.plans.iredes import write_iredes_plan
from pipeline.plans.output import read_solution_set


@pytest.fixture
def study(tiny_study):
    """A private copy of the tiny study (CUIKM trained with its MLflow model) and a small plan."""
    plans = tiny_study / "data" / "plans"
    demo = read_csv_plan(plans / "demo_face.csv")
    small = demo.holes.iloc[::6].reset_index(drop=True)  # every hole type, 11 holes
    write_csv_plan(small, plans / "small.csv")
    return tiny_study


def solved(tmp, make_cfg, plan, *extra):
    summary = solve.run(make_cfg(tmp, f"plan={plan}", *extra))
    out = plan.with_name(f"{plan.stem}_solution.csv")
    return summary, pd.read_csv(out, keep_default_na=False)


@pytest.mark.slow
def test_the_solution_table_holds_every_hole_with_joints_errors_clearances_and_status(study, make_cfg, safety):
    tmp = study
    plan = tmp / "data" / "plans" / "small.csv"
    summary, table = solved(tmp, make_cfg, plan)
    holes = pd.read_csv(plan)
    assert table["hole_id"].tolist() == holes["hole_id"].tolist()
    for col in ["q1", "q8", "start_mm", "preview_mm", "hole_mm", "direction_deg", "clearance_self_m",
                "clearance_wall_m", "clearance_ground_m", "clearance_arch_m", "status", "method", "hole_type"]:
        assert col in table.columns, col
    assert set(table["status"]) == {"ok"} and summary["ok"] == len(holes)
    # the table tells the truth: recompute errors and clearances from its joints and the plan
    q = torch.tensor(table[[f"q{i}" for i in range(1, 9)]].to_numpy(dtype=float))
    pose = read_csv_plan(plan).poses(3.3)
    check = solution_table(pose, q, safety)
    assert check["hole_mm"].max() <= 0.01 and not check["any_violation"].any()
    assert table["hole_mm"].to_numpy() == pytest.approx(check["hole_mm"].to_numpy(), abs=1e-6)
    figure, summary_file = plan.with_name("small_solution.png"), plan.with_name("small_solution.json")
    assert figure.stat().st_size > 20_000 and json.loads(summary_file.read_text())["ok"] == len(holes)
    client = MlflowClient(f"sqlite:///{tmp}/mlflow.db")
    exp = client.get_experiment_by_name("boom-ik-tiny")
    (run,) = client.search_runs([exp.experiment_id], "tags.stage = 'solve'")
    assert run.info.status == "FINISHED" and run.data.metrics["ok"] == len(holes)
    assert {"solution.json", "solution.png"} <= {a.path for a in client.list_artifacts(run.info.run_id)}


@pytest.mark.slow
def test_an_iredes_file_of_the_same_plan_gives_the_same_joints(study, make_cfg):
    tmp = study
    plans = tmp / "data" / "plans"
    write_iredes_plan(read_csv_plan(plans / "small.csv"), plans / "small_ir.xml")
    _, from_csv = solved(tmp, make_cfg, plans / "small.csv")
    _, from_xml = solved(tmp, make_cfg, plans / "small_ir.xml")
    joints = [f"q{i}" for i in range(1, 9)]
    assert from_xml["hole_id"].tolist() == from_csv["hole_id"].tolist()
    assert from_xml[joints].to_numpy(dtype=float) == pytest.approx(from_csv[joints].to_numpy(dtype=float), abs=1e-9)


@pytest.mark.slow
def test_bad_rows_are_named_and_the_good_ones_still_solved(study, make_cfg):
    tmp = study
    good = pd.read_csv(tmp / "data" / "plans" / "small.csv")
    bad = good.copy().astype({"collar_y": object, "toe_z": object})
    bad.loc[1, "collar_y"] = "abc"                                   # non-numeric
    bad.loc[2, "hole_id"] = bad.loc[3, "hole_id"]                    # duplicate id (row 5 is the second)
    bad.loc[4, ["toe_x", "toe_y", "toe_z"]] = bad.loc[4, ["collar_x", "collar_y", "collar_z"]].to_numpy()  # zero length
    bad.loc[5, "toe_z"] = "inf"                                      # non-finite
    bad = bad.astype({"collar_x": object})
    bad.loc[6, "collar_x"] = "1e154"                                 # huge but finite: a row problem, not an abort
    bad.loc[7, "hole_id"] = '=HYPERLINK("http://evil","x")'           # a spreadsheet would run it
    bad["note"] = [f"n{i}" for i in range(len(bad))]                 # the plan's own column
    path = tmp / "data" / "plans" / "bad.csv"
    bad.to_csv(path, index=False)
    summary, table = solved(tmp, make_cfg, path)
    # plan order, invalid rows where they stood, each with its own columns
    assert table["note"].tolist() == bad["note"].tolist() and len(table) == len(bad)
    assert table["hole_type"].tolist() == bad["hole_type"].tolist()
    status = table["status"].tolist()
    assert [i for i, s in enumerate(status) if s == "invalid"] == [1, 3, 4, 5, 6, 7] and summary["invalid_rows"] == 6
    problem = table["problem"]
    assert problem[1].startswith("row 3: collar_y: non-numeric value 'abc'")
    assert table["hole_id"][2] == table["hole_id"][3] == good.loc[3, "hole_id"] and status[2] == "ok"
    assert problem[3] == f"row 5: hole_id: duplicate hole id {good.loc[3, 'hole_id']!r} (first at row 4)"
    assert problem[4].startswith("row 6: toe: zero-length") and problem[5].startswith("row 7: toe_z: non-finite")
    assert problem[6].startswith("row 8: collar_x: coordinate 1e+154 m")
    assert table["hole_id"][6] == good.loc[6, "hole_id"]
    # the formula-like id: refused as a row, and written so that a spreadsheet shows it as text
    assert table["hole_id"][7] == "'" + '=HYPERLINK("http://evil","x")' and "formula" in problem[7]
    assert (table["status"] == "ok").sum() == len(good) - 6


@pytest.mark.slow
def test_strict_mode_exits_non_zero_and_still_writes_the_solution(study, make_cfg):
    tmp = study
    plan = pd.read_csv(tmp / "data" / "plans" / "small.csv").iloc[:3].copy()
    plan.loc[0, ["collar_x", "toe_x"]] = [25.0, 28.5]  # far beyond reach
    path = tmp / "data" / "plans" / "strict.csv"
    plan.to_csv(path, index=False)
    with pytest.raises(StrictCheckFailed, match="strict: 1 of 3 holes are not ok"):
        solve.run(make_cfg(tmp, f"plan={path}", "strict=true"))
    table = pd.read_csv(path.with_name("strict_solution.csv"))
    assert table["status"].tolist() == ["unreachable", "ok", "ok"]


def test_a_plan_without_a_required_column_fails_before_anything_is_written(study, make_cfg):
    tmp = study
    path = tmp / "data" / "plans" / "nocol.csv"
    pd.read_csv(tmp / "data" / "plans" / "small.csv").drop(columns=["toe_z"]).to_csv(path, index=False)
    with pytest.raises(InputError, match=r"nocol.csv: missing column\(s\) \['toe_z'\]"):
        solve.run(make_cfg(tmp, f"plan={path}"))
    assert not path.with_name("nocol_solution.csv").exists()


@pytest.mark.slow
def test_invalid_rows_counts_rows_not_bad_cells(study, make_cfg):
    """A row with three bad cells is one invalid row (before: ``invalid_rows`` counted the cells)."""
    tmp = study
    good = pd.read_csv(tmp / "data" / "plans" / "small.csv")
    bad = good.copy().astype({"collar_y": object, "toe_z": object})
    bad.loc[1, ["collar_y", "toe_z"]] = ["abc", "inf"]  # two bad cells in one row ...
    bad.loc[1, "hole_id"] = ""                            # ... and a third: an empty id
    path = tmp / "data" / "plans" / "cells.csv"
    bad.to_csv(path, index=False)
    summary, table = solved(tmp, make_cfg, path)
    assert (table["status"] == "invalid").sum() == 1
    assert summary["invalid_rows"] == 1 and json.loads(path.with_name("cells_solution.json").read_text())[
        "invalid_rows"] == 1
    assert summary["holes"] == len(good) - 1


@pytest.mark.slow
def test_the_network_can_come_from_an_mlflow_model_uri(study, make_cfg):
    tmp = study
    client = MlflowClient(f"sqlite:///{tmp}/mlflow.db")
    exp = client.get_experiment_by_name("boom-ik-tiny")
    runs = client.search_runs([exp.experiment_id], "tags.stage = 'train'")
    assert len(runs) == 2  # tiny trains two seeds: either network, as logged in its run, solves the plan
    run = runs[-1]
    plan = tmp / "data" / "plans" / "small.csv"
    summary, table = solved(tmp, make_cfg, plan, f"solve.model_uri=runs:/{run.info.run_id}/cuikm")
    assert summary["ok"] == len(table) and table["method"].iloc[0] == f"hybrid (runs:/{run.info.run_id}/cuikm)"
    with pytest.raises(InputError, match=r"solve.model_uri = runs:/nope/model: cannot load it"):
        solve.run(make_cfg(tmp, f"plan={plan}", "solve.model_uri=runs:/nope/model"))


@pytest.mark.slow
def test_the_demo_face_is_solved_with_every_hole_ok_from_the_command_line(study):
    tmp = study
    cmd = [sys.executable, "-m", "pipeline.solve", "experiment=tiny", f"paths.data={tmp}/data",
           f"tracking.uri=sqlite:///{tmp}/mlflow.db", f"tracking.artifact_root={tmp}/artifacts",
           f"hydra.run.dir={tmp}/hydra", "strict=true", "runtime.threads=1"]  # the other worker has the other core
    done = subprocess.run(cmd, cwd=PROJECT_ROOT, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    table = pd.read_csv(tmp / "data" / "plans" / "demo_face_solution.csv")
    assert len(table) == 65 and set(table["status"]) == {"ok"}
    assert set(table["hole_type"]) == {"cut", "relief", "stoping", "lifter", "contour"}


# --- hostile out= and plans ------------------------------------------------------


@pytest.fixture
def no_work(monkeypatch):
    """Fail the test if solve gets as far as loading the network."""
    def loaded(*a, **k):
        raise AssertionError("solve loaded the network before refusing out=")
    monkeypatch.setattr(solve, "load_network", loaded)


def test_out_that_is_the_plan_collides_or_is_a_folder_is_refused_before_any_work(study, make_cfg, no_work):
    tmp = study
    plans = tmp / "data" / "plans"
    plan = plans / "small.csv"
    before = plan.read_bytes()
    (plans / "link.csv").unlink(missing_ok=True)
    (plans / "link.csv").symlink_to(plan)
    (plans / "twisted.json").unlink(missing_ok=True)
    (plans / "twisted.json").symlink_to(plan)  # the summary of out=twisted.csv would land on the plan
    (plans / "adir").mkdir(exist_ok=True)
    (plans / "fig_dir.png").mkdir(exist_ok=True)
    cases = [(plan, "is the drill plan"), (plans / ".." / "plans" / "small.csv", "is the drill plan"),
             (plans / "link.csv", "is the drill plan"), (plans / "twisted.csv", "is the drill plan"),
             (plans / "x.json", "expected a .csv file name"), (plans / "x.png", "expected a .csv file name"),
             (plans / "small.xml", "expected a .csv file name"), (plans / "adir", "an existing folder"),
             (plans / "fig_dir.csv", "fig_dir.png is an existing folder")]
    for out, match in cases:
        with pytest.raises(InputError, match=rf"out = .*{match}"):
            solve.run(make_cfg(tmp, f"plan={plan}", f"out={out}"))
    assert plan.read_bytes() == before
    assert not any(p.name.startswith("x.") for p in plans.iterdir())


def test_the_summary_and_the_mlflow_run_record_the_checksum_state(study, make_cfg):
    tmp = study
    plans = tmp / "data" / "plans"
    write_iredes_plan(read_csv_plan(plans / "small.csv"), plans / "sig.xml")
    data = (plans / "sig.xml").read_bytes()
    summary = solve.run(make_cfg(tmp, f"plan={plans / 'sig.xml'}"))
    assert summary["checksum"] == "verified"
    assert json.loads((plans / "sig_solution.json").read_text())["checksum"] == "verified"
    start = data.index(b"<IR:GenTrailer>")
    (plans / "unsigned.xml").write_bytes(data[:start] + data[data.index(b"</IR:GenTrailer>") + 16:])
    with pytest.raises(InputError, match=r"unsigned.xml: the file has no ChkSum .*refused"):
        solve.run(make_cfg(tmp, f"plan={plans / 'unsigned.xml'}"))
    assert not (plans / "unsigned_solution.csv").exists()
    for mode, state in [("warn", "unverified"), ("ignore", "ignored")]:
        solve.run(make_cfg(tmp, f"plan={plans / 'unsigned.xml'}", f"solve.iredes.checksum={mode}"))
        assert json.loads((plans / "unsigned_solution.json").read_text())["checksum"] == state
    solve.run(make_cfg(tmp, f"plan={plans / 'small.csv'}", f"out={tmp / 'csv_out.csv'}"))
    assert json.loads((tmp / "csv_out.json").read_text())["checksum"] == "not applicable"
    client = MlflowClient(f"sqlite:///{tmp}/mlflow.db")
    exp = client.get_experiment_by_name("boom-ik-tiny")
    states = {r.data.params["plan_checksum"] for r in client.search_runs([exp.experiment_id], "tags.stage = 'solve'")
              if "plan_checksum" in r.data.params}
    assert {"verified", "unverified", "ignored", "not applicable"} <= states


def test_a_full_disk_leaves_the_previous_set_whole_and_chunks_solve_alike(study, make_cfg, monkeypatch, safety):
    import errno

    from pipeline.plans import output

    tmp = study
    plan = tmp / "data" / "plans" / "small.csv"
    out = tmp / "set" / "sol.csv"
    solve.run(make_cfg(tmp, f"plan={plan}", f"out={out}", "solve.chunk=4"))  # 3 chunks: 4, 4, 3 holes
    table, summary = read_solution_set(out)  # the MD5s in the summary are the files'
    assert set(summary["files"]) == {"sol.csv", "sol.png"} and summary["ok"] == len(table) == 11
    before = {p.name: p.read_bytes() for p in out.parent.iterdir()}

    def full(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr(output, "write_json", full)  # the last file of the set fails
    with pytest.raises(OSError, match="No space left"):
        solve.run(make_cfg(tmp, f"plan={plan}", f"out={out}", "solve.figure=false"))
    assert {p.name: p.read_bytes() for p in out.parent.iterdir()} == before  # whole, and no temp left
    monkeypatch.undo()
    solve.run(make_cfg(tmp, f"plan={plan}", f"out={out}"))  # one chunk
    again, _ = read_solution_set(out)
    # Chunks change a hard hole's random starts (they are drawn per batch), so its joints may be another
    # of its solutions; never its status, and every answer is exact and clear by an independent recomputation.
    joints = [f"q{i}" for i in range(1, 9)]
    assert again["status"].tolist() == table["status"].tolist()
    pose = read_csv_plan(plan).poses(3.3)
    for t in (table, again):
        check = solution_table(pose, torch.tensor(t[joints].to_numpy(dtype=float)), safety)
        assert check["hole_mm"].max() <= 0.01 and not check["any_violation"].any()
    solve.run(make_cfg(tmp, f"plan={plan}", f"out={out}", "solve.figure=false"))
    assert not out.with_suffix(".png").exists()  # a figure of another run is not left beside this set
