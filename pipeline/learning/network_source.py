"""One way to get a trained network for a boom: a checkpoint file or an MLflow model URI, with the
joint-count check (:func:`~pipeline.learning.models.check_network_fits`) every caller needs."""

from __future__ import annotations

from pathlib import Path

from pipeline.core.build import load_boom
from pipeline.core.errors import InputError
from pipeline.geometry.kinematics import Boom
from pipeline.learning.models import IKNet, check_network_fits, load_checkpoint

URI_SCHEMES = ("models:/", "runs:/", "mlflow-artifacts:/", "s3://", "gs://", "file://")


def is_model_uri(source: str | Path) -> bool:
    return isinstance(source, str) and source.startswith(URI_SCHEMES)


def load_network(source: str | Path, boom: Boom | None, tracking_uri: str | None = None,
                 setting: str = "model") -> tuple[IKNet, dict]:
    """The network at ``source`` (eval mode, CPU) and its metadata, checked against ``boom``.

    ``source`` is a checkpoint path (``load_checkpoint``: its metadata come with it) or an MLflow model
    URI (``runs:/<id>/model``, ``models:/<name>@<alias>``, loaded from ``tracking_uri``; no metadata).
    ``boom=None`` checks a checkpoint against the boom it was trained on (its ``boom`` metadata).
    ``setting`` names the config key a URI came from, for the error when MLflow cannot load it."""
    if is_model_uri(source):
        model, meta = _load_logged(str(source), tracking_uri, setting), {}
    else:
        model, meta = load_checkpoint(source)
    if boom is None:
        if "boom" not in meta:
            raise InputError(f"{source}: no boom to check the network against")
        boom = load_boom(meta["boom"])
    return check_network_fits(model, boom, str(source)), meta


def _load_logged(uri: str, tracking_uri: str | None, setting: str) -> IKNet:
    import mlflow  # lazily: only a URI needs MLflow
    import mlflow.pytorch
    from mlflow.exceptions import MlflowException

    if tracking_uri:
        mlflow.set_tracking_uri(tracking_uri)
    try:
        model = mlflow.pytorch.load_model(uri, map_location="cpu")
    except (MlflowException, OSError) as exc:
        raise InputError(f"{setting} = {uri}: cannot load it from {tracking_uri or mlflow.get_tracking_uri()} "
                         f"({exc})") from None
    if not isinstance(model, IKNet):
        raise InputError(f"{setting} = {uri}: not an IK network ({type(model).__name__})")
    return model.eval()
