"""Deployment export: each exported file computes the joints eager torch computes, for 1 hole and 1 000."""

import hashlib
import json
import logging

import pytest
import torch

from pipeline import export
from pipeline.assembly.build import load_boom
from pipeline.core.config import compose, load_group_file
from pipeline.core.errors import ConfigError, InputError
from pipeline.data.holes import HoleSampling, sample_holes
from pipeline.deploy import formats
from pipeline.learning.models import build_model, save_checkpoint

TORCH_FORMATS = ["torch_export", "torchscript"]


def cfg_for(tmp, *extra):
    return compose([f"paths.data={tmp}/data", "tracking.enabled=false", *extra])


@pytest.fixture(scope="module")
def holes(safety):
    """Holes drawn like the test groups, with a seed the export's own check does not use."""
    return sample_holes(1000, safety, HoleSampling(), 4242)[0].float()


def save_tiny_network(data, holes, method="cuikm"):
    """A small network with random weights: equality of the exports needs no training."""
    torch.manual_seed(0)
    boom_cfg = load_group_file("boom", "jumbo8")
    model = build_model(load_boom(boom_cfg), holes.mean(0), holes.std(0), 32, 2, "gelu")
    save_checkpoint(data / "models" / f"{method}.pt", model, boom_cfg, {"method": method})
    return model.eval().requires_grad_(False)


@pytest.fixture(scope="module")
def exported(tmp_path_factory, holes):
    tmp = tmp_path_factory.mktemp("export")
    model = save_tiny_network(tmp / "data", holes)
    manifests = export.run(cfg_for(tmp))
    return tmp / "data" / "export", model, manifests["cuikm"]


def assert_same_joints(run, model, pose):
    with torch.inference_mode():
        got, want = run(pose), model(pose)
    assert got.shape == (len(pose), 8) and got.dtype == torch.float32
    torch.testing.assert_close(got, want, atol=1e-5, rtol=0)


@pytest.mark.slow
@pytest.mark.parametrize("batch", [1, 1000])
@pytest.mark.parametrize("fmt", TORCH_FORMATS)
def test_torch_exports_give_the_joints_of_eager_torch(exported, holes, fmt, batch):
    out, model, _ = exported
    assert_same_joints(formats.load_runner(fmt, out / f"cuikm{formats.FORMATS[fmt]}"), model, holes[:batch])


@pytest.mark.slow
@pytest.mark.parametrize("batch", [1, 1000])
def test_onnx_gives_the_joints_of_eager_torch(exported, holes, batch):
    pytest.importorskip("onnxruntime")
    out, model, _ = exported
    assert_same_joints(formats.load_runner("onnx", out / "cuikm.onnx"), model, holes[:batch])


@pytest.mark.slow
def test_onnx_file_is_named_and_described(exported):
    onnx = pytest.importorskip("onnx")
    out, _, manifest = exported
    proto = onnx.load(out / "cuikm.onnx")
    assert [i.name for i in proto.graph.input] == ["pose"] and [o.name for o in proto.graph.output] == ["joints"]
    assert proto.graph.input[0].type.tensor_type.shape.dim[0].dim_param  # symbolic: any batch size
    assert {o.domain: o.version for o in proto.opset_import}[""] == 18
    props = {p.key: p.value for p in proto.metadata_props}
    assert json.loads(props["boom_ik"])["joints"] == manifest["joints"]


@pytest.mark.slow
def test_manifest_describes_the_files(exported):
    out, _, manifest = exported
    assert manifest == json.loads((out / "cuikm.manifest.json").read_text())
    assert manifest["method"] == "cuikm" and manifest["boom"] == "jumbo8"
    assert manifest["input"]["name"] == "pose" and manifest["input"]["shape"] == ["batch", 6]
    assert manifest["output"]["name"] == "joints" and manifest["output"]["shape"] == ["batch", 8]
    joints = manifest["joints"]
    assert [j["name"] for j in joints] == [f"q{i}" for i in range(1, 9)]
    assert [j["unit"] for j in joints] == ["rad", "rad", "m", "rad", "rad", "rad", "rad", "m"]  # q3, q8 prismatic
    assert "torch" in manifest["versions"]
    for entry in manifest["files"].values():
        assert hashlib.sha256((out / entry["file"]).read_bytes()).hexdigest() == entry["sha256"]
    assert set(manifest["check"]["max_abs_diff_vs_eager"]) == set(manifest["files"])
    assert manifest["check"]["holes"] == 1000
    assert max(manifest["check"]["max_abs_diff_vs_eager"].values()) <= 1e-5
    # the .pt2 carries the same description, for a rig that gets the file alone
    extra = {formats.META_FILE: ""}
    torch.export.load(out / "cuikm.pt2", extra_files=extra)
    assert json.loads(extra[formats.META_FILE])["joints"] == joints


def test_missing_or_corrupt_model_names_the_file_and_how_to_rebuild_it(tmp_path):
    named = r"cuikm\.pt.*python -m pipeline\.train method=cuikm.*dvc repro train@cuikm"
    for content in (None, b"not a checkpoint"):
        if content is not None:
            (tmp_path / "data" / "models").mkdir(parents=True)
            (tmp_path / "data" / "models" / "cuikm.pt").write_bytes(content)
        with pytest.raises(InputError, match=named):
            export.run(cfg_for(tmp_path, "export.onnx=false"))
    assert not (tmp_path / "data" / "export").exists()


def test_onnx_required_without_the_extra_is_a_config_error(tmp_path, monkeypatch):
    monkeypatch.setattr(formats, "missing_onnx_packages", lambda: ["onnxscript"])
    with pytest.raises(ConfigError, match=r"export\.onnx = true.*onnxscript.*\[onnx\]"):
        export.run(cfg_for(tmp_path, "export.onnx=true"))
    with pytest.raises(ConfigError, match=r"export\.onnx = 'maybe'"):
        export.run(cfg_for(tmp_path, "export.onnx=maybe"))


@pytest.mark.slow
def test_without_the_extra_onnx_is_skipped_with_one_log_line(tmp_path, holes, monkeypatch, caplog):
    monkeypatch.setattr(formats, "missing_onnx_packages", lambda: ["onnx", "onnxruntime"])
    save_tiny_network(tmp_path / "data", holes)
    with caplog.at_level(logging.INFO, logger="pipeline.deploy"):
        manifests = export.run(cfg_for(tmp_path, "export.torchscript=false", "export.check.holes=50"))
    skipped = [r for r in caplog.records if "ONNX export skipped" in r.getMessage()]
    assert len(skipped) == 1 and 'pip install -c constraints.txt -e ".[onnx]"' in skipped[0].getMessage()
    assert sorted(p.name for p in (tmp_path / "data" / "export").iterdir()) == ["cuikm.manifest.json", "cuikm.pt2"]
    assert manifests["cuikm"]["onnx_opset"] is None and "onnx" not in manifests["cuikm"]["versions"]


@pytest.mark.slow
def test_an_export_that_differs_from_torch_is_refused_and_removed(tmp_path, holes, monkeypatch):
    save_tiny_network(tmp_path / "data", holes)
    monkeypatch.setattr(formats, "max_abs_diff", lambda run, model, pose: 1e-3)
    with pytest.raises(ConfigError, match=r"export\.check\.tolerance = 1e-05: cuikm\.pt2 differs .* by 0\.001"):
        export.run(cfg_for(tmp_path, "export.onnx=false", "export.torchscript=false", "export.check.holes=50"))
    assert list((tmp_path / "data" / "export").iterdir()) == []


def test_a_refused_export_leaves_the_previous_one_whole(tmp_path, holes, monkeypatch):
    """Files are staged and checked before any is published: a failed check must not delete the files the
    previous manifest names (before: they were written in place, then unlinked, the old manifest kept)."""
    save_tiny_network(tmp_path / "data", holes)
    cfg = cfg_for(tmp_path, "export.onnx=false", "export.check.holes=50")
    export.run(cfg)
    out = tmp_path / "data" / "export"
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    monkeypatch.setattr(formats, "max_abs_diff", lambda run, model, pose: 1e-3)
    with pytest.raises(ConfigError, match=r"export\.check\.tolerance"):
        export.run(cfg)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # nothing staged is left behind either
    manifest = json.loads((out / "cuikm.manifest.json").read_text())
    for entry in manifest["files"].values():
        assert hashlib.sha256((out / entry["file"]).read_bytes()).hexdigest() == entry["sha256"]


@pytest.mark.parametrize(("override", "pattern"), [
    ("export.opset=17", r"export\.opset = 17: must be >= 18"),
    ("export.check.holes=1", r"export\.check\.holes = 1: must be >= 2"),
    ("export.check.tolerance=0", r"export\.check\.tolerance = 0\.0: must be > 0"),
    ("export.methods=[]", r"export\.methods = \[\]: expected at least 1"),
    ("+export.check.tolerence=1", r"export\.check\.tolerence: unknown setting; did you mean 'tolerance'"),
    ("export.benchmark.rounds=0", r"export\.benchmark\.rounds = 0: must be >= 1"),
])
def test_bad_export_settings_are_named_before_any_work(tmp_path, override, pattern):
    with pytest.raises(ConfigError, match=pattern):
        export.run(cfg_for(tmp_path, override))
