"""MLflow: one store (an absolute SQLite file by default), one experiment, flat params."""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Mapping
from pathlib import Path

import mlflow
from mlflow.tracking import MlflowClient

from pipeline.core.config import main_root

log = logging.getLogger(__name__)


def flatten(params: Mapping, prefix: str = "") -> dict[str, str]:
    """``{"a": {"b": 1}}`` -> ``{"a.b": "1"}``; lists become JSON text."""
    out: dict[str, str] = {}
    for key, value in params.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out.update(flatten(value, f"{name}."))
        elif isinstance(value, (list, tuple)):
            out[name] = json.dumps(value)
        else:
            out[name] = str(value)
    return out


def resolve_uri(uri: str | None) -> str:
    """The absolute tracking URI: ``uri``, else ``$MLFLOW_TRACKING_URI``, else the SQLite file
    ``mlflow.db`` in the main checkout. A relative SQLite path is taken from the main checkout."""
    uri = uri or os.environ.get("MLFLOW_TRACKING_URI") or "sqlite:///mlflow.db"
    if uri.startswith("sqlite:///"):
        path = Path(uri.removeprefix("sqlite:///"))
        if not path.is_absolute():
            path = main_root() / path
        return f"sqlite:///{path}"
    return uri


def resolve_artifact_root(artifact_root: str | None) -> Path:
    root = Path(artifact_root) if artifact_root else Path("mlartifacts")
    return root if root.is_absolute() else main_root() / root


def setup(uri: str | None, experiment: str, artifact_root: str | None = None) -> str:
    """Point MLflow at the store and make sure ``experiment`` exists; returns its id.

    Creating the store and the experiment here, before any job logs, is what keeps
    parallel sweep jobs from racing on a fresh SQLite file. Artifacts go under an
    absolute ``artifact_root``, so Hydra job folders and DVC temp copies share them.
    """
    uri = resolve_uri(uri)
    if uri.startswith("sqlite:///"):
        Path(uri.removeprefix("sqlite:///")).parent.mkdir(parents=True, exist_ok=True)
    mlflow.set_tracking_uri(uri)
    client = MlflowClient(uri)
    exp = client.get_experiment_by_name(experiment)
    if exp is None:
        location = resolve_artifact_root(artifact_root).as_uri()
        try:
            exp_id = client.create_experiment(experiment, artifact_location=location)
        except mlflow.exceptions.MlflowException:  # another job created it first
            exp_id = client.get_experiment_by_name(experiment).experiment_id
    else:
        exp_id = exp.experiment_id
    mlflow.set_experiment(experiment_id=exp_id)
    return exp_id


def log_history(history: list[dict[str, float]]) -> None:
    """Per-step metrics, batched into few calls."""
    import time

    from mlflow.entities import Metric

    now = int(time.time() * 1000)
    metrics = [
        Metric(k, float(v), now, int(rec["step"])) for rec in history for k, v in rec.items() if k != "step"
    ]
    client = MlflowClient()
    run_id = mlflow.active_run().info.run_id
    for i in range(0, len(metrics), 900):
        client.log_batch(run_id, metrics=metrics[i : i + 900])


def start(**kwargs):
    """``mlflow.start_run(**kwargs)``: the run of one stage or sweep job."""
    return mlflow.start_run(**kwargs)


def log_params(params: Mapping[str, str]) -> None:
    items = list(params.items())
    for i in range(0, len(items), 100):  # MLflow takes at most 100 params a batch
        mlflow.log_params(dict(items[i : i + 100]))


def log_metrics(metrics: Mapping[str, float], prefix: str = "") -> None:
    mlflow.log_metrics({f"{prefix}{k}": float(v) for k, v in metrics.items() if isinstance(v, (int, float))})


def log_artifact(path: str | Path, folder: str | None = None) -> None:
    mlflow.log_artifact(str(path), artifact_path=folder)


def log_training_figure(history, method: str) -> None:
    import matplotlib.pyplot as plt

    from pipeline.evaluation.plots import training_curves

    fig = training_curves({method: history})
    mlflow.log_figure(fig, f"figures/training_{method}.png")
    plt.close(fig)


def log_network(model, input_example) -> None:
    """The trained network as an MLflow model, with an input example (MLflow 3 needs one)."""
    import mlflow.pytorch

    mlflow.pytorch.log_model(model, name="model", input_example=input_example, pip_requirements=["torch"])
