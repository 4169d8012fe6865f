"""Model files never run code: a crafted checkpoint or logged model is refused, and its payload never runs."""

from pathlib import Path

import pytest
import torch

from pipeline.core.errors import InputError
from pipeline.learning.models import build_model, load_checkpoint, save_checkpoint
from pipeline.learning.network_source import load_network
from pipeline.tracking.runs import TrackingSettings, stage_run


class Payload:
    """Unpickling this object creates ``marker``: the stand-in for an attacker's code."""

    def __init__(self, marker: Path):
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


def settings(tmp: Path) -> TrackingSettings:
    return TrackingSettings.from_config({"enabled": True, "uri": f"sqlite:///{tmp}/mlflow.db",
                                         "experiment": "safe-models", "artifact_root": str(tmp / "artifacts")})


def tiny_network(jumbo8):
    torch.manual_seed(0)
    return build_model(jumbo8, torch.zeros(6), torch.ones(6), width=8, depth=1, activation="gelu")


def test_the_payload_is_live(tmp_path):
    """The crafted file really runs its payload under torch's full unpickler, so the tests below mean something."""
    marker, path = tmp_path / "ran", tmp_path / "evil.pt"
    torch.save({"state_dict": {}, "hparams": Payload(marker)}, path)
    torch.load(path, weights_only=False)
    assert marker.exists()


def test_a_crafted_checkpoint_is_refused_and_its_payload_never_runs(tmp_path):
    marker, path = tmp_path / "ran", tmp_path / "cuikm.pt"
    torch.save({"state_dict": {}, "hparams": Payload(marker)}, path)
    with pytest.raises(InputError, match=r"cuikm\.pt: refused.*GLOBAL .*open.*would run code"):
        load_checkpoint(path)
    assert not marker.exists()


def test_a_project_checkpoint_still_loads_weights_only(tmp_path, jumbo8):
    model, path = tiny_network(jumbo8), tmp_path / "net.pt"
    save_checkpoint(path, model, {"name": "jumbo8"}, {"method": "cuikm", "history": [{"step": 0, "loss": 1.5}],
                                                      "final": {"kept_step": 0}, "config": {"a": [1, None, "x"]}})
    loaded, meta = load_checkpoint(path)
    assert meta["history"] == [{"step": 0, "loss": 1.5}] and meta["config"] == {"a": [1, None, "x"]}
    pose = torch.randn(5, 6)
    assert torch.equal(loaded(pose), model.eval()(pose))


def test_a_pickled_logged_model_is_refused_and_its_payload_never_runs(tmp_path, jumbo8):
    """A model in MLflow's pickle form, as earlier versions logged it, with a payload in its weights file."""
    import mlflow

    marker, model_dir = tmp_path / "ran", tmp_path / "model"
    (model_dir / "data").mkdir(parents=True)
    torch.save(Payload(marker), model_dir / "data" / "model.pth")
    (model_dir / "MLmodel").write_text("flavors:\n  pytorch:\n    model_data: data\n    pytorch_version: 2.13.0\n"
                                       "    serialization_format: pickle\n")
    s = settings(tmp_path)
    with stage_run(s, "crafted") as run:
        mlflow.log_artifacts(str(model_dir), "model")
    with pytest.raises(InputError, match=r"solve.model_uri = runs:/.*/model: refused.*'pickle'.*pipeline.train"):
        load_network(f"runs:/{run.run_id}/model", jumbo8, s.uri, "solve.model_uri")
    assert not marker.exists()


def test_a_logged_network_round_trips_without_pickle(tmp_path, jumbo8):
    model, ckpt = tiny_network(jumbo8), tmp_path / "cuikm.pt"
    save_checkpoint(ckpt, model, {"name": "jumbo8"}, {"method": "cuikm"})
    s = settings(tmp_path)
    with stage_run(s, "train-cuikm") as run:
        run.log_network(model.eval(), torch.zeros(2, 6).numpy(), ckpt, name="cuikm", step=7)
    loaded, meta = load_network(f"runs:/{run.run_id}/cuikm", jumbo8, s.uri)
    pose = torch.randn(4, 6)
    assert meta["method"] == "cuikm" and torch.equal(loaded(pose), model(pose))
    store = tmp_path / "artifacts"
    assert [f.name for f in store.rglob("model.pt2")] == ["model.pt2"]  # MLflow's torch.export form
    assert not list(store.rglob("*.pth"))  # no pickled module anywhere in the store
