"""The as-drilled loop on a small face, end to end (docs/calibration.md, "The loop: plan, drill, log, calibrate"):
a rig whose boom is not its nominal model drills a round planned on the nominal model, its log is off the plan
by the field level; 60 poses measured by a simulated total station calibrate it; the round planned again with
the calibrated model and drilled by the same boom is on the plan to within a millimetre."""

import json

import pandas as pd
import pytest
from conftest import CHECK_STAGE

from pipeline.core.config import compose

STAGE = [s for s in CHECK_STAGE if s not in ("schedule.interlocks=false", "round.postures=1")] + [
    "draws.count=20", "execute.replay=false", "execute.figures=false", "execute.monte_carlo=false"]


@pytest.mark.slow
def test_calibration_brings_the_drilled_round_onto_the_plan(tmp_path):
    from pipeline import calibrate, demo_face, execute, field_boom, quality, schedule

    base = ["experiment=tiny", f"paths.data={tmp_path}/data", f"tracking.uri=sqlite:///{tmp_path}/mlflow.db",
            f"tracking.artifact_root={tmp_path}/artifacts"]
    demo_face.run(compose(base))
    plan = tmp_path / "small.csv"
    pd.read_csv(tmp_path / "data" / "plans" / "demo_face.csv").iloc[::11].to_csv(plan, index=False)
    made = field_boom.run(compose([*base, f"field_boom.folder={tmp_path}/loop"]))
    true = f"execute.true_boom_model={made['true_boom']}"

    def drilled(name: str, *model: str) -> dict:
        """Plan (with ``model``), drill with the true boom, read the log back: the quality summary."""
        folder = tmp_path / name
        round_csv = folder / "small_round.csv"
        schedule.run(compose([*base, *STAGE, f"plan={plan}", f"out={round_csv}", *model]))
        ov = [*base, *STAGE, f"plan={plan}", f"execute.round={round_csv}", f"execute.out={folder}", true, *model]
        out = execute.run_execute(compose(ov), ov)
        assert out["checks"]["realised"]["exit"] == 0 and out["as_drilled"]["holes"] == 6
        return quality.run(compose([*base, f"plan={plan}", f"log={folder / 'small_executed_quality.xml'}",
                                    f"out={folder / 'small_quality.csv'}"]))

    before = drilled("before")
    assert before["collar_dev_m_mean"] > 0.02  # the field level: centimetres off the plan
    model = tmp_path / "loop" / "boom_model.yaml"
    calibrate.run(compose([*base, f"measurements={made['measurements']}", f"calibration.model_file={model}"]))
    after = drilled("after", f"boom_model={model}")
    assert after["collar_dev_m_mean"] <= 0.001 and after["within"] == 6, after
    assert after["collar_dev_m_mean"] < before["collar_dev_m_mean"] / 20
    record = json.loads((tmp_path / "after" / "small_quality.json").read_text())
    assert record["log_checksum"] == "verified" and record["missing_from_log"] == []
    from pipeline.report import loop_lines  # the study's report renders the two summaries as its loop table

    table = "\n".join(loop_lines({"before": before, "after": after}))
    assert f"| before | {before['within']} of 6 |" in table
    assert f"{1000 * after['collar_dev_m_mean']:.2f} / " in table
