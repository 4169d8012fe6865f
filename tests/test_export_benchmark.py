"""The latency benchmark of the deployable network: every runtime timed, the tables written and logged."""

import pandas as pd
import pytest
import torch
from mlflow.tracking import MlflowClient

from pipeline import export_benchmark
from pipeline.deploy import latency


@pytest.mark.slow
def test_latency_benchmark_times_every_runtime_and_logs_to_mlflow(tmp_path, make_cfg, monkeypatch):
    cfg = make_cfg(tmp_path)  # experiment=tiny: batches [1, 20], 3 repeats, no compile, one process
    # what is timed must be the network: record each timed call's input and output, and the network
    timed_calls, networks = [], []
    real_block_times, real_measure = latency.block_times, export_benchmark.measure

    def recording_block_times(run, pose, *args):
        with torch.inference_mode():
            timed_calls.append((pose.clone(), run(pose)))
        return real_block_times(run, pose, *args)

    def recording_measure(*args):
        table, model = real_measure(*args)
        networks.append(model)
        return table, model

    monkeypatch.setattr(latency, "block_times", recording_block_times)  # the harness (pipeline/deploy/latency.py)
    monkeypatch.setattr(export_benchmark, "measure", recording_measure)
    table = export_benchmark.run(cfg)
    runtimes = ["torch eager", "torch.export (.pt2)", "torch.compile", "TorchScript (.ts)",
                "ONNX Runtime, 1 thread", "ONNX Runtime, 2 threads"]
    assert sorted(set(table["runtime"])) == sorted(runtimes) and sorted(set(table["holes"])) == [1, 20]
    assert len(table) == len(runtimes) * 2 and not table.duplicated(["runtime", "holes"]).any()
    timed = table.dropna(subset=["median_ms"])
    skipped = table[table["median_ms"].isna()]
    assert (skipped["note"].str.startswith("skipped")).all() and (timed["note"] == "").all()
    assert (timed["repeats"] >= cfg.export.benchmark.min_repeats).all() and timed["setup_s"].notna().all()
    assert timed["us_per_hole"].to_numpy() == pytest.approx(1000 * timed["median_ms"] / timed["holes"])
    assert table.loc[table.runtime == "torch.compile", "note"].str.startswith("skipped").all()
    # one block of calls per timed runtime and batch (rounds = 1), each computing the network's joints
    assert len(timed_calls) == len(timed) and sorted(len(pose) for pose, _ in timed_calls) == sorted(timed["holes"])
    (model,) = networks
    with torch.inference_mode():
        for pose, joints in timed_calls:
            torch.testing.assert_close(joints, model(pose), atol=1e-5, rtol=0)
    on_disk = pd.read_csv(tmp_path / "data" / "export" / "latency.csv")
    assert list(on_disk.columns) == export_benchmark.COLUMNS and len(on_disk) == len(table)
    assert "| torch eager | 1 |" in (tmp_path / "data" / "export" / "latency.md").read_text()
    client = MlflowClient(f"sqlite:///{tmp_path}/mlflow.db")
    run = client.search_runs([client.get_experiment_by_name("boom-ik-tiny").experiment_id])[0]
    assert run.info.run_name == "export-latency" and "latency_ms.torch_eager.holes_1" in run.data.metrics
    onnx_timed = timed["runtime"].str.startswith("ONNX").any()  # not without the [onnx] extra
    assert ("latency_ms.onnx_runtime_2_threads.holes_20" in run.data.metrics) == onnx_timed
    assert {a.path for a in client.list_artifacts(run.info.run_id, "export")} == {"export/latency.csv",
                                                                                   "export/latency.md"}
