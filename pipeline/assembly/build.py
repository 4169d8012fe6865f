"""Build the shared objects (boom, tunnel, safety model) from config sections."""

from __future__ import annotations

from pipeline.core.config import as_dict, load_group_file, project_path
from pipeline.core.errors import ConfigError
from pipeline.core.settings import coerce
from pipeline.data.holes import HoleSampling
from pipeline.geometry.boom_config import boom_from_config
from pipeline.geometry.collision import SafetyDistances, SafetyModel, capsule_settings
from pipeline.geometry.kinematics import Boom
from pipeline.geometry.profile import MAX_VERTICES, Profile
from pipeline.geometry.tunnel import Horseshoe, Tunnel


def load_boom(boom) -> Boom:
    """A :class:`Boom` from a name (``conf/boom/<name>.yaml``) or a config mapping."""
    if isinstance(boom, Boom):
        return boom
    cfg = load_group_file("boom", boom) if isinstance(boom, str) else as_dict(boom)
    return boom_from_config(cfg)


def build_safety(boom, tunnel_cfg, safety_cfg) -> SafetyModel:
    """The safety model of a boom in a tunnel with the configured safety distances."""
    distances, points, exact = safety_settings(safety_cfg)
    return SafetyModel(load_boom(boom), build_tunnel(tunnel_cfg), distances, points, exact)


TUNNEL_KINDS = ("horseshoe", "profile")


def build_tunnel(tunnel_cfg) -> Tunnel:
    """The drift of a ``tunnel`` node: ``kind: horseshoe`` (``width``, ``wall_height``; a node without
    ``kind`` is one) or ``kind: profile`` (``file``: a profile CSV, relative paths from the project root;
    ``max_vertices``)."""
    cfg = as_dict(tunnel_cfg)
    kind = cfg.get("kind", "horseshoe")
    if kind == "horseshoe":
        return Horseshoe.from_config(cfg)
    if kind != "profile":
        raise ConfigError(f"tunnel.kind = {kind!r}: expected one of {list(TUNNEL_KINDS)}")
    unknown = sorted(set(cfg) - {"kind", "file", "max_vertices"})
    if unknown:
        raise ConfigError(f"tunnel: unknown field(s) {unknown} for kind profile; allowed: ['file', 'max_vertices']")
    file = cfg.get("file")
    if not isinstance(file, str) or not file:
        raise ConfigError(f"tunnel.file = {file!r}: tunnel=profile needs the profile CSV (columns y, z, surface): "
                          "tunnel.file=<path>")
    limit = cfg.get("max_vertices", MAX_VERTICES)
    if isinstance(limit, bool) or not isinstance(limit, int) or not 3 <= limit <= 10 * MAX_VERTICES:
        raise ConfigError(f"tunnel.max_vertices = {limit!r}: expected a whole number in [3, {10 * MAX_VERTICES}]")
    return Profile.from_file(project_path(file), limit)


_CAPSULE_KEYS = ("points_per_capsule", "exact_capsules")


def safety_settings(safety_cfg) -> tuple[SafetyDistances, int, bool]:
    """The ``safety`` node's distances, ``points_per_capsule`` (16 when not given) and ``exact_capsules``
    (true when not given)."""
    safety = as_dict(safety_cfg)
    points, exact = capsule_settings(safety.get("points_per_capsule", 16), safety.get("exact_capsules", True))
    return SafetyDistances.from_config({k: v for k, v in safety.items() if k not in _CAPSULE_KEYS}), points, exact


def hole_sampling(holes_cfg) -> HoleSampling:
    """How holes are drawn (``holes.face_x``, ``holes.cone_deg``, ``holes.inset``), validated."""
    face_x = coerce(holes_cfg.get("face_x"), "list[float]", "holes.face_x")
    if len(face_x) != 2:
        raise ConfigError(f"holes.face_x = {face_x!r}: expected [lower, upper]")
    return HoleSampling(tuple(face_x), coerce(holes_cfg.get("cone_deg"), "float", "holes.cone_deg"),
                        coerce(holes_cfg.get("inset"), "float", "holes.inset"))
