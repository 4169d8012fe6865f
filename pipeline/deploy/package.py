"""A trained network packaged for rigs: every format of :mod:`pipeline.deploy.formats`, each read back
from disk and compared with eager torch, and a manifest naming the files, their sha256, the joints and
units, the boom and the versions.

Everything is written into a private staging folder beside the destination and published (one atomic
rename per file, manifest last, under one lock) only after every read-back check passed: a refused
export leaves the files of the previous one, and its manifest, as they were.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import json
import platform
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from pipeline.assembly.build import build_safety
from pipeline.core.errors import ConfigError
from pipeline.core.io import publish, write_json
from pipeline.core.settings import MAX_THREADS, SEED_MAX, rule
from pipeline.data.hole_sets import MAX_SET
from pipeline.data.holes import HoleSampling, sample_holes
from pipeline.data.tables import POSE_COLUMNS
from pipeline.deploy import formats
from pipeline.deploy.formats import FORMATS, INPUT, MIN_OPSET, ONNX_PACKAGES, OUTPUT
from pipeline.geometry.kinematics import Boom
from pipeline.learning.models import IKNet


@dataclass(frozen=True)
class CheckSettings:
    """``export.check``: the holes every export is compared with eager torch on."""

    holes: int = field(default=1000, metadata=rule(ge=2, le=MAX_SET))
    seed: int = field(default=7, metadata=rule(ge=0, le=SEED_MAX))
    tolerance: float = field(default=1e-5, metadata=rule(gt=0))  # largest joint difference (rad or m)


@dataclass(frozen=True)
class LatencySettings:
    """``export.benchmark``: the latency harness (:mod:`pipeline.deploy.latency`)."""

    threads: int = field(default=2, metadata=rule(ge=1, le=MAX_THREADS))
    batches: list[int] = field(default_factory=lambda: [1, 1000], metadata=rule(ge=1, le=65_536, min_items=1,
                                                                                  max_items=20))
    ort_threads: list[int] = field(default_factory=lambda: [1, 2], metadata=rule(ge=1, le=MAX_THREADS, min_items=1,
                                                                                 max_items=20))
    compile: bool = True
    min_time_s: float = field(default=2.0, metadata=rule(ge=0, le=3600))
    min_repeats: int = field(default=50, metadata=rule(ge=1, le=100_000))
    rounds: int = field(default=5, metadata=rule(ge=1, le=1000))
    isolate: bool = True
    seed: int = field(default=0, metadata=rule(ge=0, le=SEED_MAX))


@dataclass(frozen=True)
class ExportSettings:
    """The ``export`` group (conf/export/default.yaml)."""

    methods: list[str] = field(default_factory=lambda: ["cuikm"], metadata=rule(min_items=1))
    onnx: Any = "auto"  # true, false or auto: decided by formats.onnx_wanted (it depends on what is installed)
    opset: int = field(default=18, metadata=rule(ge=MIN_OPSET))
    torchscript: bool = True
    check: CheckSettings = field(default_factory=CheckSettings)
    benchmark: LatencySettings = field(default_factory=LatencySettings)

    def formats(self) -> list[str]:
        """Keys of FORMATS to write, torch_export first (may log that ONNX is skipped)."""
        return ["torch_export"] + (["torchscript"] if self.torchscript else []) + (
            ["onnx"] if formats.onnx_wanted(self.onnx) else [])


def check_poses(boom_cfg, tunnel_cfg, safety_cfg, holes_cfg, n: int, seed: int) -> torch.Tensor:
    """``(n, 6)`` float32 holes drawn like the test groups, for the boom the network was trained on."""
    safety = build_safety(boom_cfg, tunnel_cfg, safety_cfg)
    sampling = HoleSampling(tuple(holes_cfg.face_x), float(holes_cfg.cone_deg), float(holes_cfg.inset))
    return sample_holes(n, safety, sampling, seed)[0].float()


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


def write_formats(model: IKNet, example: torch.Tensor, files: dict[str, Path], opset: int, meta: str) -> None:
    """Each format of ``files`` (format -> path) written from ``model``; ``meta`` embedded in each."""
    program = formats.export_program(model, example)
    formats.save_program(program, files["torch_export"], meta)
    if "torchscript" in files:
        formats.save_torchscript(model, example, files["torchscript"], meta)
    if "onnx" in files:
        formats.save_onnx(program, example, files["onnx"], opset, {"boom_ik": meta})


def export_method(method: str, checkpoint: Path, model: IKNet, boom: Boom, pose: torch.Tensor, out: Path,
                  st: ExportSettings, fmts: list[str]) -> dict:
    """Write ``method``'s files ``fmts`` and its manifest into ``out``; each file is read back and compared
    with eager torch on ``pose`` first, in a staging folder, and nothing is published unless all pass."""
    info = describe(method, model, boom)
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=f".{method}.staging-", dir=out) as tmp:
        staged = {fmt: Path(tmp) / f"{method}{FORMATS[fmt]}" for fmt in fmts}
        write_formats(model, pose[:16], staged, st.opset, json.dumps(info))
        diffs = {fmt: formats.max_abs_diff(formats.load_runner(fmt, path), model, pose) for fmt, path in staged.items()}
        worst = max(diffs, key=diffs.get)
        if diffs[worst] > st.check.tolerance:  # a file that does not compute what the network computes must not ship
            raise ConfigError(f"export.check.tolerance = {st.check.tolerance:g}: {staged[worst].name} differs from "
                              f"eager torch by {diffs[worst]:.3g} on {len(pose)} holes; nothing written for {method}")
        manifest = {
            **info,
            "onnx_opset": st.opset if "onnx" in staged else None,
            "versions": versions("onnx" in staged),
            "files": {fmt: {"file": p.name, "sha256": sha256(p), "bytes": p.stat().st_size}
                      for fmt, p in staged.items()},
            "checkpoint": {"file": checkpoint.name, "sha256": sha256(checkpoint)},
            "check": {"holes": len(pose), "seed": st.check.seed, "dtype": "float32", "tolerance": st.check.tolerance,
                      "max_abs_diff_vs_eager": diffs},
        }
        staged_manifest = Path(tmp) / f"{method}.manifest.json"
        write_json(manifest, staged_manifest)
        # the manifest moves last (dicts keep order), so it never names a file that is not yet in place
        publish({**{p: out / p.name for p in staged.values()}, staged_manifest: out / staged_manifest.name},
                out.parent / f".{out.name}.lock")  # beside the folder: the folder holds only the exports
    return manifest
