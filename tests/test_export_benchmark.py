"""The latency benchmark of the deployable network: every runtime timed, the tables written and logged."""

import pandas as pd
from mlflow.tracking import MlflowClient

from pipeline import export_benchmark
from pipeline.core.config import compose


def test_latency_benchmark_times_every_runtime_and_logs_to_mlflow(tmp_path):
    bench = {"batches": "[1,20]", "compile": "false", "isolate": "false", "min_time_s": 0, "min_repeats": 3,
             "rounds": 1}
    cfg = compose([f"paths.data={tmp_path}/data", f"tracking.uri=sqlite:///{tmp_path}/mlflow.db",
                   f"tracking.artifact_root={tmp_path}/art", "model.width=32", "model.depth=2",
                   *(f"export.benchmark.{k}={v}" for k, v in bench.items())])
    table = export_benchmark.run(cfg)
    runtimes = ["torch eager", "torch.export (.pt2)", "torch.compile", "TorchScript (.ts)",
                "ONNX Runtime, 1 thread", "ONNX Runtime, 2 threads"]
    assert sorted(set(table["runtime"])) == sorted(runtimes) and sorted(set(table["holes"])) == [1, 20]
    timed = table.dropna(subset=["median_ms"])
    assert (timed["median_ms"] > 0).all() and (timed["repeats"] >= 3).all()
    assert table.loc[table.runtime == "torch.compile", "note"].str.startswith("skipped").all()
    on_disk = pd.read_csv(tmp_path / "data" / "export" / "latency.csv")
    assert list(on_disk.columns) == export_benchmark.COLUMNS and len(on_disk) == len(table)
    assert "| torch eager | 1 |" in (tmp_path / "data" / "export" / "latency.md").read_text()
    client = MlflowClient(f"sqlite:///{tmp_path}/mlflow.db")
    run = client.search_runs([client.get_experiment_by_name("boom-ik").experiment_id])[0]
    assert run.info.run_name == "export-latency" and "latency_ms.torch_eager.holes_1" in run.data.metrics
    onnx_timed = timed["runtime"].str.startswith("ONNX").any()  # not without the [onnx] extra
    assert ("latency_ms.onnx_runtime_2_threads.holes_20" in run.data.metrics) == onnx_timed
    assert {a.path for a in client.list_artifacts(run.info.run_id, "export")} == {"export/latency.csv",
                                                                                   "export/latency.md"}
