"""Build the shared objects (boom, tunnel, safety model) from config sections."""

from __future__ import annotations

from pipeline.core.config import as_dict, load_group_file
from pipeline.core.errors import ConfigError
from pipeline.geometry.collision import SafetyDistances, SafetyModel
from pipeline.geometry.kinematics import Boom
from pipeline.geometry.tunnel import Horseshoe


def load_boom(boom) -> Boom:
    """A :class:`Boom` from a name (``conf/boom/<name>.yaml``) or a config mapping."""
    if isinstance(boom, Boom):
        return boom
    cfg = load_group_file("boom", boom) if isinstance(boom, str) else as_dict(boom)
    return Boom.from_config(cfg)


def build_safety(boom, tunnel_cfg, safety_cfg) -> SafetyModel:
    """The safety model of a boom in a tunnel with the configured safety distances."""
    safety = as_dict(safety_cfg)
    n = safety.get("points_per_capsule", 16)
    if isinstance(n, bool) or not isinstance(n, int):
        raise ConfigError(f"safety.points_per_capsule = {n!r}: expected an integer")
    distances = SafetyDistances.from_config({k: v for k, v in safety.items() if k != "points_per_capsule"})
    return SafetyModel(load_boom(boom), Horseshoe.from_config(as_dict(tunnel_cfg)), distances, n)
