"""One way to get a trained network for a boom: a checkpoint file or an MLflow model URI, with the
joint-count check (:func:`~pipeline.learning.models.check_network_fits`) every caller needs."""

from __future__ import annotations

from pathlib import Path

from pipeline.assembly.build import load_boom
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
    URI (``runs:/<id>/<method>``, ``models:/<name>@<alias>``, from ``tracking_uri``: the checkpoint it carries).
    ``boom=None`` checks a checkpoint against the boom it was trained on (its ``boom`` metadata).
    ``setting`` names the config key a URI came from, for the error when MLflow cannot load it."""
    if is_model_uri(source):
        model, meta = _load_logged(str(source), tracking_uri, setting)
    else:
        model, meta = load_checkpoint(source)
    if boom is None:
        if "boom" not in meta:
            raise InputError(f"{source}: no boom to check the network against")
        boom = load_boom(meta["boom"])
    return check_network_fits(model, boom, str(source)), meta


def _load_logged(uri: str, tracking_uri: str | None, setting: str) -> tuple[IKNet, dict]:
    """A network logged by ``train`` (``runs:/<id>/<method>``, ``models:/<name>@<alias>``) and its
    checkpoint's metadata.

    Only the files are downloaded; the network is read from the weights-only checkpoint the model
    carries (:func:`~pipeline.learning.models.load_checkpoint`). MLflow's own loader is never called:
    a model logged in pickle form (by earlier versions) would run code from the store, so it is
    refused with how to log it again."""
    import mlflow  # lazily: only a URI needs MLflow
    import yaml
    from mlflow.exceptions import MlflowException

    if tracking_uri:
        mlflow.set_tracking_uri(tracking_uri)
    try:
        local = Path(mlflow.artifacts.download_artifacts(artifact_uri=uri))
    except (MlflowException, OSError) as exc:
        raise InputError(f"{setting} = {uri}: cannot load it from {tracking_uri or mlflow.get_tracking_uri()} "
                         f"({exc})") from None
    spec = local / "MLmodel"
    if not spec.is_file():
        raise InputError(f"{setting} = {uri}: not an MLflow model (no MLmodel file in {local})")
    try:
        flavor = (yaml.safe_load(spec.read_text()) or {}).get("flavors", {}).get("pytorch", {})
    except yaml.YAMLError as exc:
        raise InputError(f"{setting} = {uri}: its MLmodel file is not readable YAML ({exc})") from None
    entries = [e["path"] for e in flavor.get("extra_files", []) if isinstance(e, dict) and "path" in e]
    extra = [(local / e).resolve() for e in entries]
    checkpoints = [f for f in extra if f.suffix == ".pt" and f.is_file() and local.resolve() in f.parents]
    if len(checkpoints) != 1:
        fmt = flavor.get("serialization_format", "unknown")
        raise InputError(f"{setting} = {uri}: refused, this model carries no weights-only checkpoint (format "
                         f"{fmt!r}); a pickled model would run code from the store when loaded. Log the network "
                         "again with `python -m pipeline.train method=<method>` and use the new run's model")
    try:
        return load_checkpoint(checkpoints[0])
    except InputError as exc:
        raise InputError(f"{setting} = {uri}: {exc}") from None
