"""Build a rig (conf/rig/<name>.yaml) in the configured tunnel with the configured safety distances.

Apart from :mod:`pipeline.assembly.build` so that the study's stages, which never place a rig, do not
depend on the rig's code (DVC code deps are import closures)."""

from __future__ import annotations

from pipeline.core.config import as_dict, load_group_file
from pipeline.core.errors import ConfigError
from pipeline.geometry.collision import SafetyDistances
from pipeline.geometry.rig import Rig, parse_rig, rig_file
from pipeline.geometry.rig import build_rig as place_booms
from pipeline.geometry.tunnel import Horseshoe


def build_rig(rig_cfg, tunnel_cfg, safety_cfg) -> Rig:
    """The rig of the ``rig`` node (or a rig name: ``conf/rig/<name>.yaml``, as a stage run on the composed
    params.yaml is given with ``rig=twin``), each boom with its own safety model seen from its base (the same
    tunnel and distances as :func:`pipeline.assembly.build.build_safety`); errors name the rig file and
    the boom (:func:`pipeline.geometry.rig.build_rig`)."""
    node = load_group_file("rig", rig_cfg) if isinstance(rig_cfg, str) else as_dict(rig_cfg)
    source = rig_file(node["name"]) if isinstance(node, dict) and isinstance(node.get("name"), str) else "rig"
    safety = as_dict(safety_cfg)
    n = safety.get("points_per_capsule", 16)
    if isinstance(n, bool) or not isinstance(n, int):
        raise ConfigError(f"safety.points_per_capsule = {n!r}: expected an integer")
    distances = SafetyDistances.from_config({k: v for k, v in safety.items() if k != "points_per_capsule"})
    return place_booms(parse_rig(node, source), Horseshoe.from_config(as_dict(tunnel_cfg)), distances, n)
