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
from pipeline.core.errors import InputError
from pipeline.evaluation.metrics import solution_table
from pipeline.plans.csv_plan import read_csv_plan, write_csv_plan
from pipeline.plans.iredes import write_iredes_plan


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
    path = tmp / "data" / "plans" / "bad.csv"
    bad.to_csv(path, index=False)
    summary, table = solved(tmp, make_cfg, path)
    invalid = table[table["status"] == "invalid"].set_index("hole_id")["problem"]
    assert len(invalid) == 4 and summary["invalid_rows"] == 4
    assert "row 3" in invalid[good.loc[1, "hole_id"]] and "non-numeric value 'abc'" in invalid[good.loc[1, "hole_id"]]
    assert "duplicate hole id" in invalid[good.loc[3, "hole_id"]] and "row 5" in invalid[good.loc[3, "hole_id"]]
    assert "zero-length" in invalid[good.loc[4, "hole_id"]]
    assert "non-finite" in invalid[good.loc[5, "hole_id"]]
    assert (table["status"] == "ok").sum() == len(good) - 4


@pytest.mark.slow
def test_strict_mode_exits_non_zero_and_still_writes_the_solution(study, make_cfg):
    tmp = study
    plan = pd.read_csv(tmp / "data" / "plans" / "small.csv").iloc[:3].copy()
    plan.loc[0, ["collar_x", "toe_x"]] = [25.0, 28.5]  # far beyond reach
    path = tmp / "data" / "plans" / "strict.csv"
    plan.to_csv(path, index=False)
    with pytest.raises(SystemExit, match="strict: 1 of 3 holes are not ok"):
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
    tmp, _ = study
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
    (run,) = client.search_runs([exp.experiment_id], "tags.stage = 'train'")
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
           f"hydra.run.dir={tmp}/hydra", "strict=true"]
    done = subprocess.run(cmd, cwd=PROJECT_ROOT, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    table = pd.read_csv(tmp / "data" / "plans" / "demo_face_solution.csv")
    assert len(table) == 65 and set(table["status"]) == {"ok"}
    assert set(table["hole_type"]) == {"cut", "relief", "stoping", "lifter", "contour"}
