"""scripts/study_timing.py: each stage timed from DVC's own start lines, on a scripted clock."""

import importlib.util
import json

import pytest

from pipeline.core.config import PROJECT_ROOT

_spec = importlib.util.spec_from_file_location("study_timing", PROJECT_ROOT / "scripts" / "study_timing.py")
study_timing = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(study_timing)


def test_each_stage_runs_from_its_start_line_to_the_next_and_the_last_to_the_end(capsys):
    lines = ["Verifying data sources\n", "Running stage 'generate':\n", "> python -m pipeline.generate\n",
             "Running stage 'train@cuikm':\n", "log line\n", "Updating lock file 'dvc.lock'\n"]
    ticks = iter([0.0, 5.0, 65.0, 100.0])  # start, generate, train@cuikm, end
    rows, total = study_timing.stage_times(iter(lines), clock=lambda: next(ticks))
    assert rows == [{"stage": "generate", "seconds": 60.0}, {"stage": "train@cuikm", "seconds": 35.0}]
    assert total == 100.0
    assert capsys.readouterr().out == "".join(lines)  # DVC's output is echoed as it comes


def test_an_earlier_timing_is_never_overwritten(tmp_path):
    out = tmp_path / "t.json"
    out.write_text(json.dumps({"total_s": 1}))
    with pytest.raises(SystemExit):
        study_timing.main(["--out", str(out)])
    assert json.loads(out.read_text()) == {"total_s": 1}
