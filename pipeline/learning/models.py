"""The IK network of paper 000 sect. 3 and its stand-alone checkpoint.

An MLP maps a normalised 6-D hole pose to joint values squashed into their ranges
(``lo + (hi - lo) * sigmoid(z)``), so joint limits hold for every input. The
normalisation and the limits are buffers of the module: a saved network needs
nothing else to run.
"""

from __future__ import annotations

import pickle
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import torch
from torch import nn

from pipeline.core.errors import ConfigError, InputError
from pipeline.core.io import atomic_write
from pipeline.core.settings import parse, rule
from pipeline.geometry.kinematics import Boom

ACTIVATIONS = {"gelu": nn.GELU, "relu": nn.ReLU, "silu": nn.SiLU, "tanh": nn.Tanh}
CHECKPOINT_KEYS = ("state_dict", "hparams")
MAX_WIDTH, MAX_DEPTH = 4096, 16  # conf/model/mlp.yaml (as distill's student)


@dataclass(frozen=True)
class ModelSettings:
    """The ``model`` config group."""

    width: int = field(metadata=rule(ge=1, le=MAX_WIDTH))  # the paper's 512; 4096 is 64x its weights a layer
    depth: int = field(metadata=rule(ge=1, le=MAX_DEPTH))
    activation: str = field(default="gelu", metadata=rule(choices=sorted(ACTIVATIONS)))

    @classmethod
    def from_config(cls, node) -> ModelSettings:
        return parse(cls, node, "model")


class IKNet(nn.Module):
    def __init__(
        self,
        lower: torch.Tensor,
        upper: torch.Tensor,
        in_mean: torch.Tensor,
        in_std: torch.Tensor,
        width: int = 512,
        depth: int = 4,
        activation: str = "gelu",
    ):
        super().__init__()
        if activation not in ACTIVATIONS:
            raise ConfigError(f"model.activation = {activation!r}; expected one of {sorted(ACTIVATIONS)}")
        if width < 1 or depth < 1:
            raise ConfigError(f"model.width = {width!r}, model.depth = {depth!r}: both must be >= 1")
        self.n_in, self.n_out = int(in_mean.numel()), int(lower.numel())
        self.hparams = {"width": width, "depth": depth, "activation": activation}
        layers, n = [], self.n_in
        for _ in range(depth):
            layers += [nn.Linear(n, width), ACTIVATIONS[activation]()]
            n = width
        layers.append(nn.Linear(n, self.n_out))
        self.net = nn.Sequential(*layers)
        f32 = torch.float32
        self.register_buffer("lower", lower.detach().to(f32).clone())
        self.register_buffer("span", (upper - lower).detach().to(f32).clone())
        self.register_buffer("in_mean", in_mean.detach().to(f32).clone())
        self.register_buffer("in_std", in_std.detach().to(f32).clamp_min(1e-6).clone())

    def unit_joints(self, pose: torch.Tensor, hidden_dtype: torch.dtype | None = None) -> torch.Tensor:
        """Joints as fractions of their ranges, in (0, 1).

        ``hidden_dtype`` (training only, ``train.precision``): the products between hidden layers in that
        dtype (bfloat16: about twice as fast on a CPU with AVX-512 BF16), the input and output layers in
        float32, so that neither the pose nor the joints lose float32's resolution (bfloat16 resolves
        about 1 part in 256: 2 cm of a 5 m face)."""
        if pose.shape[-1] != self.n_in:
            raise InputError(f"network input: expected {self.n_in} pose values per hole, got shape {tuple(pose.shape)}")
        x = (pose.to(self.in_mean.dtype) - self.in_mean) / self.in_std
        if hidden_dtype is None or hidden_dtype == self.in_mean.dtype or len(self.net) < 5:
            return torch.sigmoid(self.net(x))
        h = self.net[:2](x)  # input layer and its activation, float32
        with torch.autocast(x.device.type, dtype=hidden_dtype):
            h = self.net[2:-1](h)
        return torch.sigmoid(self.net[-1](h.to(x.dtype)))

    def forward(self, pose: torch.Tensor) -> torch.Tensor:
        return self.lower + self.span * self.unit_joints(pose)


def build_model(boom: Boom, in_mean, in_std, width: int, depth: int, activation: str) -> IKNet:
    """A fresh network for ``boom`` whose inputs are standardised by ``in_mean`` / ``in_std``."""
    lo, hi = boom.limits(torch.float32)
    return IKNet(lo, hi, torch.as_tensor(in_mean), torch.as_tensor(in_std), width, depth, activation)


def save_checkpoint(path: Path, model: IKNet, boom_cfg: dict, extra: dict) -> None:
    """Everything needed to load the network alone: weights, shape, boom, training facts."""
    payload = {
        "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()},
        "hparams": model.hparams,
        "n_in": model.n_in,
        "n_out": model.n_out,
        "boom": boom_cfg,
        **extra,
    }
    atomic_write(path, lambda tmp: torch.save(payload, tmp))


def _rebuild_hint(path: Path) -> str:
    return f"rebuild it with `python -m pipeline.train method={path.stem}` (or `dvc repro train@{path.stem}`)"


def _unsafe_global(exc: Exception) -> str:
    """The global torch's weights-only unpickler refused (``GLOBAL io.open``), without its advice to trust the file."""
    for line in str(exc).splitlines():
        if "GLOBAL " in line:
            return "GLOBAL " + line.split("GLOBAL ", 1)[1].split(" ", 1)[0]
    return type(exc).__name__


def load_checkpoint(path: str | Path, map_location="cpu") -> tuple[IKNet, dict]:
    """The network (eval mode) and the checkpoint's metadata (boom config, method, ...).

    A missing, truncated or foreign file is an :class:`InputError` naming the file and how to
    rebuild it, not a bare ``EOFError`` / ``KeyError`` from deep inside torch."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such model checkpoint; {_rebuild_hint(path)}")
    try:  # weights only: a checkpoint is data, and torch's full unpickler would run code from the file
        payload = torch.load(path, map_location=map_location, weights_only=True)
    except pickle.UnpicklingError as exc:
        raise InputError(f"{path}: refused, the file holds objects beyond weights and plain values "
                         f"({_unsafe_global(exc)}) and loading them would run code from it; "
                         f"{_rebuild_hint(path)}") from None
    except (EOFError, OSError, RuntimeError, zipfile.BadZipFile, ValueError) as exc:
        raise InputError(f"{path}: not a readable checkpoint ({type(exc).__name__}: {exc}); "
                         f"{_rebuild_hint(path)}") from None
    missing = [k for k in CHECKPOINT_KEYS if not isinstance(payload, dict) or k not in payload]
    if missing:
        raise InputError(f"{path}: not an IK network checkpoint (missing {missing}); {_rebuild_hint(path)}")
    sd = payload["state_dict"]
    try:
        model = IKNet(sd["lower"], sd["lower"] + sd["span"], sd["in_mean"], sd["in_std"], **payload["hparams"])
        model.load_state_dict(sd)
    except (KeyError, RuntimeError, TypeError) as exc:
        raise InputError(f"{path}: weights do not fit the network they describe ({exc}); "
                         f"{_rebuild_hint(path)}") from None
    model.eval()
    return model, {k: v for k, v in payload.items() if k != "state_dict"}


def check_network_fits(model: IKNet, boom: Boom, source: str) -> IKNet:
    """The one joint-count check between a network and a boom."""
    if model.n_out != boom.n_joints:
        raise InputError(f"{source}: the network outputs {model.n_out} joints; boom '{boom.name}' has "
                         f"{boom.n_joints} {boom.joint_names}")
    return model
