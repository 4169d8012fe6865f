"""Stage ``export``: the trained networks in the formats a rig controller loads.

    python -m pipeline.export                               # export.methods (default: cuikm)
    python -m pipeline.export 'export.methods=[cuikm,uikm]' export.onnx=true

Writes under ``paths.data/export/``, for each method (docs/export.md):

* ``<method>.onnx``: ONNX at opset ``export.opset``, for ONNX Runtime (Python, C++, C#, ...). It
  needs the optional extra ``pip install -c constraints.txt -e ".[onnx]"``; without it the stage
  skips ONNX with one log line (``export.onnx=auto``) or refuses to run (``export.onnx=true``);
* ``<method>.pt2``: a ``torch.export`` program, ``torch.export.load(path).module()``;
* ``<method>.ts``: TorchScript, for libtorch (C++) rigs; deprecated in torch, ``export.torchscript``;
* ``<method>.manifest.json``: input and output names and shapes, joints and their units, the boom,
  versions, the sha256 of each file and the largest difference to eager torch, measured on
  ``export.check.holes`` holes by running each file as written.

Every format takes any number of holes per call (a dynamic batch dimension), float32.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.metadata
import importlib.util
import json
import logging
import platform
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import hydra
import torch
from omegaconf import DictConfig

from pipeline.assembly.build import build_safety, load_boom
from pipeline.core.config import project_path
from pipeline.core.errors import ConfigError
from pipeline.core.io import atomic_write, write_json
from pipeline.data.holes import HoleSampling, sample_holes
from pipeline.data.tables import POSE_COLUMNS
from pipeline.geometry.kinematics import Boom
from pipeline.learning.models import IKNet, check_network_fits, load_checkpoint
from pipeline.tracking.runs import TrackingSettings, stage_run

log = logging.getLogger(__name__)

INPUT, OUTPUT = "pose", "joints"  # graph input and output names; INPUT is also IKNet.forward's argument
FORMATS = {"onnx": ".onnx", "torch_export": ".pt2", "torchscript": ".ts"}
ONNX_PACKAGES = ("onnx", "onnxscript", "onnxruntime")  # torch's ONNX exporter (dynamo=True) needs onnxscript
ONNX_HINT = 'pip install -c constraints.txt -e ".[onnx]"'
MIN_OPSET = 18  # torch's exporter translates at opset 18; lower ones need a down-conversion that can fail
META_FILE = "boom_ik.json"  # the manifest's description, embedded in the .pt2 and .ts archives


# --- settings -------------------------------------------------------------------------------------------------

def missing_onnx_packages() -> list[str]:
    return [name for name in ONNX_PACKAGES if importlib.util.find_spec(name) is None]


def onnx_wanted(setting) -> bool:
    """``export.onnx``: true (required), false, or auto (exported when the extra is installed)."""
    if not (isinstance(setting, bool) or setting == "auto"):  # not `in (True, False)`: 1 == True
        raise ConfigError(f"export.onnx = {setting!r}: expected true, false or auto")
    if setting is False:
        return False
    missing = missing_onnx_packages()
    if not missing:
        return True
    if setting is True:
        raise ConfigError(f"export.onnx = true, but {', '.join(missing)} not installed: install the [onnx] extra "
                          f"with {ONNX_HINT}, or set export.onnx=auto to export the torch formats only")
    log.warning("ONNX export skipped: %s not installed; for .onnx files install the [onnx] extra: %s",
                ", ".join(missing), ONNX_HINT)
    return False


@dataclass(frozen=True)
class Settings:
    methods: list[str]
    formats: list[str]  # keys of FORMATS, torch_export first
    opset: int
    holes: int  # check holes
    seed: int
    tolerance: float


def settings(ecfg: DictConfig) -> Settings:
    """``export.*`` validated; decides whether ONNX is written (which may log that it is skipped)."""
    methods = list(ecfg.methods)
    if not methods or not all(isinstance(m, str) and m for m in methods):
        raise ConfigError(f"export.methods = {methods!r}: expected a non-empty list of method names")
    values = {"opset": ecfg.opset, "check.holes": ecfg.check.holes, "check.seed": ecfg.check.seed}
    for key, value in values.items():
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"export.{key} = {value!r}: expected an integer")
    if ecfg.opset < MIN_OPSET:
        raise ConfigError(f"export.opset = {ecfg.opset}: expected >= {MIN_OPSET}, the opset torch's exporter "
                          "translates to natively")
    if ecfg.check.holes < 2:
        raise ConfigError(f"export.check.holes = {ecfg.check.holes}: expected at least 2 holes")
    tol = float(ecfg.check.tolerance)
    if not tol > 0:
        raise ConfigError(f"export.check.tolerance = {ecfg.check.tolerance!r}: expected a positive number")
    if not isinstance(ecfg.torchscript, bool):
        raise ConfigError(f"export.torchscript = {ecfg.torchscript!r}: expected true or false")
    formats = ["torch_export"] + (["torchscript"] if ecfg.torchscript else []) + (
        ["onnx"] if onnx_wanted(ecfg.onnx) else [])
    return Settings(methods, formats, ecfg.opset, ecfg.check.holes, ecfg.check.seed, tol)


# --- checkpoints and holes ------------------------------------------------------------------------------------

def load_network(models_dir: Path, method: str) -> tuple[IKNet, dict]:
    """The trained network of ``method`` (frozen, eval mode) and its checkpoint metadata; a missing or
    unreadable checkpoint is named with how to rebuild it (:func:`load_checkpoint`)."""
    path = models_dir / f"{method}.pt"
    model, meta = load_checkpoint(path)
    check_network_fits(model, load_boom(meta["boom"]), str(path))
    return model.requires_grad_(False), meta


def check_poses(cfg: DictConfig, boom_cfg, n: int, seed: int) -> torch.Tensor:
    """``(n, 6)`` float32 holes drawn like the test groups, for the boom the network was trained on."""
    holes = cfg.holes
    safety = build_safety(boom_cfg, cfg.tunnel, cfg.safety)
    sampling = HoleSampling(tuple(holes.face_x), float(holes.cone_deg), float(holes.inset))
    return sample_holes(n, safety, sampling, seed)[0].float()


# --- writing each format ----------------------------------------------------------------------------------------

# torch 2.13's ONNX exporter probes torchvision's ops (this project has none) and onnxscript's optimiser logs
# each pass at INFO, which Hydra's root logger would print: neither is ours to act on.
EXPORTER_LOGGERS = {"torch.onnx._internal.exporter._registration": logging.ERROR, "onnx_ir": logging.WARNING,
                    "onnxscript": logging.WARNING}


@contextlib.contextmanager
def quiet_onnx_exporter():
    """The exporter's chatter muted (see EXPORTER_LOGGERS), and torch's own pytree deprecation, which the
    exporter trips over."""
    loggers = {logging.getLogger(name): level for name, level in EXPORTER_LOGGERS.items()}
    before = {lg: lg.level for lg in loggers}
    for lg, level in loggers.items():
        lg.setLevel(level)
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=r"`isinstance\(treespec, LeafSpec\)`", category=FutureWarning)
            yield
    finally:
        for lg, level in before.items():
            lg.setLevel(level)


@contextlib.contextmanager
def quiet_torchscript():
    """torch 2.13 deprecates torch.jit (the stage says so once, in its log). The trace also warns that it
    freezes IKNet's input-width check: harmless, 6 pose values per hole is fixed by the first layer."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r"`torch\.jit\.\w+` is deprecated", category=DeprecationWarning)
        warnings.filterwarnings("ignore", message="Converting a tensor to a Python boolean",
                                category=torch.jit.TracerWarning)
        yield


def export_program(model: IKNet, example: torch.Tensor) -> torch.export.ExportedProgram:
    """The network as a ``torch.export`` graph whose batch dimension is free (``example`` needs >= 2 rows:
    torch.export would specialise a batch of 1)."""
    return torch.export.export(model, (example,), dynamic_shapes={INPUT: {0: torch.export.Dim("batch")}})


def save_program(program: torch.export.ExportedProgram, path: Path, meta: str) -> None:
    def write(tmp: str) -> None:
        with open(tmp, "wb") as f:  # a file object: torch.export.save warns on names not ending in .pt2
            torch.export.save(program, f, extra_files={META_FILE: meta})

    atomic_write(path, write)


def save_torchscript(model: IKNet, example: torch.Tensor, path: Path, meta: str) -> None:
    # trace, not script: torch.jit.script cannot compile IKNet's error message (an f-string of a shape)
    with quiet_torchscript(), torch.no_grad():
        traced = torch.jit.trace(model, example)
        atomic_write(path, lambda tmp: torch.jit.save(traced, tmp, _extra_files={META_FILE: meta}))


def save_onnx(program: torch.export.ExportedProgram, example: torch.Tensor, path: Path, opset: int,
              props: dict[str, str]) -> None:
    """ONNX by torch's current exporter (``dynamo=True``, via onnxscript) from the same program as the .pt2,
    so it keeps its dynamic batch; one self-contained file with ``props`` as model metadata."""
    import onnx

    def write(tmp: str) -> None:
        with quiet_onnx_exporter():
            torch.onnx.export(program, (example,), tmp, dynamo=True, opset_version=opset, input_names=[INPUT],
                              output_names=[OUTPUT], external_data=False, verbose=False)
        proto = onnx.load(tmp)
        onnx.helper.set_model_props(proto, props)
        onnx.checker.check_model(proto, full_check=True)
        onnx.save(proto, tmp)

    atomic_write(path, write)


# --- reading each format back -------------------------------------------------------------------------------

Runner = Callable[[torch.Tensor], torch.Tensor]


def onnx_session(path: Path, threads: int | None = None):
    import onnxruntime as ort

    opts = ort.SessionOptions()
    if threads:
        opts.intra_op_num_threads = threads
        opts.inter_op_num_threads = 1  # one node at a time: an MLP has no parallel branches
    return ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])


def load_runner(fmt: str, path: Path, threads: int | None = None) -> Runner:
    """A function from float32 poses ``(n, 6)`` to joints ``(n, n_joints)`` that runs the file at ``path``."""
    if fmt == "torch_export":
        return torch.export.load(path).module()
    if fmt == "torchscript":
        with quiet_torchscript():
            return torch.jit.load(path)
    if fmt == "onnx":
        session = onnx_session(path, threads)
        return lambda pose: torch.from_numpy(session.run([OUTPUT], {INPUT: pose.numpy()})[0])
    raise ConfigError(f"export format {fmt!r}: expected one of {sorted(FORMATS)}")


def max_abs_diff(run: Runner, model: IKNet, pose: torch.Tensor) -> float:
    with torch.inference_mode():
        return float((run(pose) - model(pose)).abs().max())


# --- the manifest ---------------------------------------------------------------------------------------------

def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def versions(with_onnx: bool) -> dict[str, str]:
    out = {"python": platform.python_version(), "torch": torch.__version__}
    for name in ONNX_PACKAGES if with_onnx else ():
        out[name] = importlib.metadata.version(name)
    return out


def describe(method: str, model: IKNet, boom: Boom) -> dict:
    """What a rig needs to call the network: names, shapes, dtypes and units of the input and output."""
    return {
        "method": method,
        "boom": boom.name,
        "input": {"name": INPUT, "shape": ["batch", model.n_in], "dtype": "float32", "columns": POSE_COLUMNS,
                  "unit": "m", "frame": "boom base",
                  "meaning": f"collar, then the preview point {boom.preview_depth} m along the hole from it"},
        "output": {"name": OUTPUT, "shape": ["batch", model.n_out], "dtype": "float32"},
        "joints": [{"name": j.name, "label": j.label, "unit": "rad" if j.revolute else "m",
                    "lower": j.lower, "upper": j.upper, **({"locked": j.locked} if j.locked is not None else {})}
                   for j in boom.joints],
        "network": dict(model.hparams),
    }


def export_method(method: str, checkpoint: Path, model: IKNet, meta: dict, pose: torch.Tensor, out: Path,
                  st: Settings) -> dict:
    """Write ``method``'s files and its manifest; each file is read back and compared with eager torch."""
    boom = load_boom(meta["boom"])
    info = describe(method, model, boom)
    info_json = json.dumps(info)
    files = {fmt: out / f"{method}{FORMATS[fmt]}" for fmt in st.formats}
    example = pose[:16]
    program = export_program(model, example)
    save_program(program, files["torch_export"], info_json)
    if "torchscript" in files:
        save_torchscript(model, example, files["torchscript"], info_json)
    if "onnx" in files:
        save_onnx(program, example, files["onnx"], st.opset, {"boom_ik": info_json})
    diffs = {fmt: max_abs_diff(load_runner(fmt, path), model, pose) for fmt, path in files.items()}
    worst = max(diffs, key=diffs.get)
    if diffs[worst] > st.tolerance:
        for path in files.values():  # a file that does not compute what the network computes must not ship
            path.unlink(missing_ok=True)
        raise ConfigError(f"export.check.tolerance = {st.tolerance:g}: {files[worst].name} differs from eager "
                          f"torch by {diffs[worst]:.3g} on {len(pose)} holes; nothing written for {method}")
    manifest = {
        **info,
        "onnx_opset": st.opset if "onnx" in files else None,
        "versions": versions("onnx" in files),
        "files": {fmt: {"file": p.name, "sha256": sha256(p), "bytes": p.stat().st_size} for fmt, p in files.items()},
        "checkpoint": {"file": checkpoint.name, "sha256": sha256(checkpoint)},
        "check": {"holes": len(pose), "seed": st.seed, "dtype": "float32", "tolerance": st.tolerance,
                  "max_abs_diff_vs_eager": diffs},
    }
    write_json(manifest, out / f"{method}.manifest.json")
    return manifest


def run(cfg: DictConfig) -> dict[str, dict]:
    """Export every network of ``export.methods``; returns the manifests by method."""
    st, tracking = settings(cfg.export), TrackingSettings.from_config(cfg.tracking)
    models = project_path(cfg.paths.data) / "models"
    networks = {m: load_network(models, m) for m in st.methods}  # every checkpoint read before writing
    if "torchscript" in st.formats:
        log.info("TorchScript (.ts) is deprecated in torch %s; written for libtorch rigs (export.torchscript=false "
                 "skips it)", torch.__version__)
    out = project_path(cfg.paths.data) / "export"
    manifests = {}
    with stage_run(tracking, "export", {"stage": "export"}) as mlrun:
        mlrun.log_params({"export": {"methods": st.methods, "formats": st.formats, "opset": st.opset}})
        for method, (model, meta) in networks.items():
            pose = check_poses(cfg, meta["boom"], st.holes, st.seed)
            manifests[method] = m = export_method(method, models / f"{method}.pt", model, meta, pose, out, st)
            mlrun.log_metrics(m["check"]["max_abs_diff_vs_eager"], prefix=f"{method}.max_abs_diff.")
            mlrun.log_artifact(out / f"{method}.manifest.json", "export")
            log.info("%s: %s written to %s; largest difference to eager torch on %d holes: %s", method,
                     ", ".join(f["file"] for f in m["files"].values()), out, st.holes,
                     ", ".join(f"{k} {v:.1e}" for k, v in m["check"]["max_abs_diff_vs_eager"].items()))
    return manifests


@hydra.main(version_base="1.3", config_path="../conf", config_name="config")
def main(cfg: DictConfig) -> None:
    run(cfg)


if __name__ == "__main__":
    main()
