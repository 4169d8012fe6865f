"""The rig, tunnel, navigation, safety distances and motion from the same composed config as the stage's.

Hydra's compose API on the project's ``conf/`` with the stage's own command-line overrides
(``rig=twin motion.joint_speeds.q1=7.5 ...``): Hydra is the settings reader, nothing of ``pipeline``
is imported. A rig boom whose ``boom:`` equals the composed ``boom.name`` uses the composed ``boom``
node (so ``boom.*`` overrides reach it); any other reads ``conf/boom/<name>.yaml``. A calibrated model
goes on top as the stage puts it: ``boom_models.<name>`` (that boom), else ``boom_model`` (every boom of
its kind), each a file relative to the project root (:meth:`BoomModel.calibrated`).

The tunnel by its ``kind``: ``horseshoe`` (``width``, ``wall_height``; a node with ``width`` and no kind is
one), or ``profile`` (``tunnel.file``, a CSV relative to the project root, read and validated by
:mod:`.profile`). The navigation node gives the plan frame's transform (:mod:`.navigation`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .boom import BoomModel
from .distance import Horseshoe
from .errors import InputError
from .navigation import Navigation, read_navigation
from .paths import CONF_DIR, base_dir, project_path
from .profile import Profile, read_profile


@dataclass
class RigBoom:
    name: str
    model: BoomModel
    base: np.ndarray  # (3,) rig frame, no rotation (docs/reference.md, section 7)
    park: np.ndarray  # rad / m
    speed: np.ndarray  # rad/s / m/s, per joint


@dataclass
class Settings:
    rig: str
    d_boom: float
    booms: list[RigBoom]
    half_width: float | None  # the horseshoe's (None for a profile)
    wall_height: float | None
    safety: dict[str, float]  # self, wall, ground, arch (m)
    collaring_s: float
    rate_m_per_s: float  # penetration
    retract_m_per_s: float
    tunnel: Horseshoe | Profile | None = None  # what the sweep measures against (None: the horseshoe above)
    navigation: Navigation | None = None  # the plan frame's transform (None: the rig frame)
    record: dict | None = None  # the rig and tunnel composed, as a round JSON's `planned_with` has them (record())

    def __post_init__(self):
        if self.tunnel is None:
            self.tunnel = Horseshoe(self.half_width, self.wall_height)
        if self.navigation is None:
            self.navigation = Navigation()

    def drill_times(self, length: np.ndarray) -> np.ndarray:
        """``(n, 3)``: collaring, drilling and retraction seconds of holes of ``length`` (reference, section 7)."""
        length = np.asarray(length, float)
        return np.stack([np.full(length.shape, self.collaring_s), length / self.rate_m_per_s,
                         length / self.retract_m_per_s], -1)


def compose(overrides: list[str]):
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir
    from omegaconf import OmegaConf

    try:
        with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
            cfg = hydra_compose(config_name="config", overrides=list(overrides))
        return OmegaConf.to_container(cfg, resolve=True)
    except Exception as e:  # Hydra's own errors name the override; keep them, on one line
        raise InputError(f"settings {list(overrides)}: {' '.join(str(e).split())}") from None


def _number(node: dict, key: str, where: str, positive: bool = True) -> float:
    v = node.get(key) if isinstance(node, dict) else None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or (positive and v <= 0):
        raise InputError(f"settings: {where}.{key} = {v!r}: expected a {'positive ' if positive else ''}number")
    return float(v)


def _tunnel(node) -> Horseshoe | Profile:
    """The composed tunnel node by its kind."""
    if not isinstance(node, dict):
        raise InputError(f"settings: tunnel = {node!r}: expected a tunnel node (tunnel=horseshoe | profile ...)")
    kind = node.get("kind", "horseshoe" if "width" in node else None)
    if kind == "horseshoe":
        return Horseshoe(0.5 * _number(node, "width", "tunnel"), _number(node, "wall_height", "tunnel"))
    if kind == "profile":
        return read_profile(node.get("file"), node.get("max_vertices", 2000), base_dir())
    raise InputError(f"settings: tunnel.kind = {kind!r}: expected horseshoe (width, wall_height) or profile "
                     "(tunnel.file)")


def _boom_node(name: str, composed: dict) -> tuple[dict, str]:
    if composed.get("name") == name:
        return composed, "the composed boom node"
    path = CONF_DIR / "boom" / f"{name}.yaml"
    if not path.is_file():
        raise InputError(f"settings: rig boom type {name!r}: no {path}")
    from omegaconf import OmegaConf

    return OmegaConf.to_container(OmegaConf.load(path), resolve=True), str(path)


def _model_file(setting: str, value) -> dict:
    """The YAML of a calibrated model file a setting names (relative paths: the project root, as the stage reads
    them), read as plain data."""
    import yaml

    if not isinstance(value, str) or not value:
        raise InputError(f"settings: {setting} = {value!r}: expected the path of a boom model file")
    path = project_path(value)
    try:
        return yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as e:
        raise InputError(f"settings: {setting} = {value!r}: cannot read it ({' '.join(str(e).split())})") from None


def _calibrated(cfg: dict, rig: dict) -> tuple[dict[str, tuple[str, dict]], tuple[str, dict] | None]:
    """The calibrated model files, read as the stage reads them: per rig boom name ``(setting, YAML)`` from
    ``boom_models.<name>``, and ``("boom_model", YAML)`` for every boom of the file's kind (or None)."""
    one = cfg.get("boom_model")
    by_kind = ("boom_model", _model_file("boom_model", one)) if one else None
    per = cfg.get("boom_models") or {}
    if not isinstance(per, dict):
        raise InputError(f"settings: boom_models = {per!r}: expected a mapping rig boom name -> model file")
    names = [str(b.get("name")) for b in rig.get("booms") or []]
    unknown = sorted(set(per) - set(names))
    if unknown:
        raise InputError(f"settings: boom_models: no boom {unknown} in rig {rig.get('name')!r}; booms: {names}")
    return {name: (f"boom_models.{name}", _model_file(f"boom_models.{name}", v)) for name, v in per.items()}, by_kind


def record(rig: dict, tunnel: dict) -> dict:
    """The composed rig and tunnel as the stage records them in the round JSON (``planned_with``): the rig's
    name, d_boom and each boom's name, kind, base and park as its file writes them; the tunnel's kind and a
    horseshoe's width and wall height, or a profile's file and the MD5 of its content (read here)."""
    import hashlib

    kind = tunnel.get("kind", "horseshoe" if "width" in tunnel else None)
    if kind == "profile":
        file = str(tunnel.get("file"))
        path = project_path(file)
        t = {"kind": "profile", "file": file, "md5": hashlib.md5(path.read_bytes()).hexdigest()}
    else:
        t = {"kind": str(kind), "width": float(tunnel["width"]), "wall_height": float(tunnel["wall_height"])}
    booms = [{"name": str(b.get("name")), "boom": str(b.get("boom")), "base": [float(v) for v in b.get("base")],
              "park": [float(v) for v in b.get("park")]} for b in rig.get("booms") or []]
    return {"rig": {"name": str(rig.get("name")), "d_boom": float(rig.get("d_boom")), "booms": booms}, "tunnel": t}


def differences(planned, now, where: str = "") -> list[str]:
    """Where a round's ``planned_with`` and :func:`record` of the composed settings differ (numbers within
    1e-9; a profile by its content's MD5, not its path), in words."""
    if isinstance(planned, dict) and isinstance(now, dict):
        keys = set(planned) | set(now)
        if "md5" in keys:
            keys.discard("file")
        return [d for k in sorted(keys, key=str)
                for d in differences(planned.get(k), now.get(k), f"{where}.{k}" if where else str(k))]
    if isinstance(planned, list) and isinstance(now, list) and len(planned) == len(now):
        return [d for i, (a, b) in enumerate(zip(planned, now, strict=True))
                for d in differences(a, b, f"{where}[{i}]")]
    numbers = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in (planned, now))
    if numbers and abs(planned - now) <= 1e-9:
        return []
    return [] if (not numbers and planned == now) else [f"{where}: planned {planned!r}, composed {now!r}"]


def settings(overrides: list[str]) -> Settings:
    cfg = compose(overrides)
    rig, motion, safety, tunnel = cfg["rig"], cfg["motion"], cfg["safety"], cfg["tunnel"]
    per_boom, by_kind = _calibrated(cfg, rig)
    kinds = {str(b.get("boom")) for b in rig.get("booms") or []}
    model_kind = str(by_kind[1].get("boom")) if by_kind and isinstance(by_kind[1], dict) else None
    if by_kind and model_kind not in kinds:
        raise InputError(f"settings: boom_model: a model of boom {model_kind!r}, but rig {rig.get('name')!r} has booms "
                         f"of kind {sorted(kinds)}")
    speeds = motion.get("joint_speeds") or {}
    drilling = motion.get("drilling") or {}
    booms, models = [], {}
    for i, b in enumerate(rig.get("booms") or []):
        where = f"rig.booms[{i}]"
        kind = str(b.get("boom"))
        if kind not in models:
            node, src = _boom_node(kind, cfg["boom"])
            models[kind] = BoomModel(node, src)
        m = models[kind]
        # most specific first: boom_models.<name>, then boom_model on every boom of its kind
        setting, doc = per_boom.get(str(b.get("name")), by_kind if model_kind == kind else (None, None))
        if setting is not None:
            m = m.calibrated(doc, f"settings: {setting}")
        base, park = np.asarray(b.get("base", []), float), np.asarray(b.get("park", []), float)
        finite = np.isfinite(base).all() and np.isfinite(park).all()
        if base.shape != (3,) or park.shape != (len(m.joint_names),) or not finite:
            raise InputError(f"settings: {where} ({b.get('name')}): base needs 3 numbers, park {len(m.joint_names)}")
        missing = [j for j in m.joint_names if j not in speeds]
        if missing:
            raise InputError(f"settings: motion.joint_speeds has no {missing} for boom {b.get('name')} ({kind})")
        unit = np.where(m.revolute, math.pi / 180.0, 1.0)  # rig parks and speeds: deg (revolute), m (prismatic)
        speed = np.array([_number(speeds, j, "motion.joint_speeds") for j in m.joint_names]) * unit
        booms.append(RigBoom(str(b.get("name")), m, base, park * unit, speed))
    names = [b.name for b in booms]
    if not booms or len(set(names)) != len(names):
        raise InputError(f"settings: rig {rig.get('name')!r}: booms {names}: expected one or more, each named once")
    shape = _tunnel(tunnel)
    horseshoe = isinstance(shape, Horseshoe)
    return Settings(
        rig=str(rig.get("name")), d_boom=_number(rig, "d_boom", "rig", positive=False), booms=booms,
        half_width=shape.half_width if horseshoe else None, wall_height=shape.wall_height if horseshoe else None,
        tunnel=shape, navigation=read_navigation(cfg.get("navigation"), base_dir()), record=record(rig, tunnel),
        safety={k: _number(safety, k, "safety", positive=False) for k in ("self", "wall", "ground", "arch")},
        collaring_s=_number(drilling, "collaring_s", "motion.drilling", positive=False),
        rate_m_per_s=_number(drilling, "rate_m_per_min", "motion.drilling") / 60.0,
        retract_m_per_s=_number(drilling, "retract_m_per_s", "motion.drilling"),
    )
