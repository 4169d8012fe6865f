"""The deployable network's file formats: each written from a network and read back as a runner.

* ONNX at a chosen opset, for ONNX Runtime (Python, C++, C#, ...), from the optional extra
  ``pip install -c constraints.txt -e ".[onnx]"``;
* a ``torch.export`` program (``.pt2``), ``torch.export.load(path).module()``;
* TorchScript (``.ts``), for libtorch (C++) rigs; deprecated in torch.

Every format takes any number of holes per call (a dynamic batch dimension), float32. Used by the
export package (:mod:`pipeline.deploy.package`) and the latency harness (:mod:`pipeline.deploy.latency`).
"""

from __future__ import annotations

import contextlib
import importlib.util
import logging
import warnings
from collections.abc import Callable
from pathlib import Path

import torch

from pipeline.core.errors import ConfigError
from pipeline.core.io import atomic_write
from pipeline.learning.models import IKNet

log = logging.getLogger(__name__)

INPUT, OUTPUT = "pose", "joints"  # graph input and output names; INPUT is also IKNet.forward's argument
FORMATS = {"onnx": ".onnx", "torch_export": ".pt2", "torchscript": ".ts"}
ONNX_PACKAGES = ("onnx", "onnxscript", "onnxruntime")  # torch's ONNX exporter (dynamo=True) needs onnxscript
ONNX_HINT = 'pip install -c constraints.txt -e ".[onnx]"'
MIN_OPSET = 18  # torch's exporter translates at opset 18; lower ones need a down-conversion that can fail
META_FILE = "boom_ik.json"  # the manifest's description, embedded in the .pt2 and .ts archives


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
