"""Build a rig (conf/rig/<name>.yaml) in the configured tunnel with the configured safety distances, its
booms from the composed config (docs/rig.md, "Which model each boom drills with").

This is the composition root's side of a rig: the only place that reads a rig file or another boom
kind's config by name. :mod:`pipeline.geometry.rig` is handed the parsed node and one :class:`Boom` per
boom. Apart from :mod:`pipeline.assembly.build` so that the study's stages, which never place a rig, do
not depend on the rig's code (DVC code deps are import closures)."""

from __future__ import annotations

from collections.abc import Callable, Mapping

from pipeline.assembly.build import build_tunnel, load_boom, safety_settings
from pipeline.core.config import as_dict, load_group_file, project_path
from pipeline.core.errors import ConfigError
from pipeline.geometry.collision import SafetyDistances
from pipeline.geometry.kinematics import Boom
from pipeline.geometry.rig import Rig, RigSpec, parse_rig, rig_file
from pipeline.geometry.rig import build_rig as place_booms
from pipeline.geometry.tunnel import Tunnel

# (setting, model file, nominal boom of each kind) -> the calibrated Boom; errors name the setting. The
# stage passes pipeline.calibration.model_file.model_setting, which this layer may not import.
ModelLoader = Callable[[str, str, Mapping[str, Boom]], Boom]


def rig_spec(rig_cfg) -> RigSpec:
    """The ``rig`` node parsed, or a rig name (``conf/rig/<name>.yaml``, as a stage run on the composed
    params.yaml is given with ``rig=twin``)."""
    node = load_group_file("rig", rig_cfg) if isinstance(rig_cfg, str) else as_dict(rig_cfg)
    source = rig_file(node["name"]) if isinstance(node, dict) and isinstance(node.get("name"), str) else "rig"
    return parse_rig(node, source)


def rig_tunnel(name: str, default) -> dict:
    """The tunnel a rig file selects (its ``override /tunnel@_global_.tunnel: <name>`` default, as Hydra
    applies it when the rig is composed), else ``default``: for rigs loaded by name."""
    for d in load_group_file("rig", name).get("defaults", []) or []:
        if isinstance(d, dict):
            for k, v in d.items():
                if "tunnel" in k:
                    return load_group_file("tunnel", v)
    return as_dict(default)


def nominal_booms(spec: RigSpec, boom_cfg=None) -> dict[str, Boom]:
    """Boom kind -> its nominal :class:`Boom` for every kind of the rig: the composed ``boom`` node for
    its own kind (so ``boom.*`` overrides reach the rig), ``conf/boom/<kind>.yaml`` for the others."""
    composed = load_boom(boom_cfg) if boom_cfg is not None else None
    out: dict[str, Boom] = {}
    for m in spec.mounts:
        if m.boom in out:
            continue
        if composed is not None and composed.name == m.boom:
            out[m.boom] = composed
            continue
        try:
            out[m.boom] = load_boom(m.boom)
        except ConfigError as e:
            raise ConfigError(f"{spec.source}: boom '{m.name}'.boom = {m.boom!r}: {e}") from e
    return out


def boom_models_setting(value) -> dict[str, str]:
    """``boom_models``: null or a mapping rig boom name -> calibrated model file."""
    if value is None:
        return {}
    node = as_dict(value) if isinstance(value, Mapping) else value
    if not isinstance(node, dict) or not all(isinstance(k, str) and isinstance(v, str) and v for k, v in node.items()):
        raise ConfigError(f"boom_models = {value!r}: expected a mapping rig boom name -> model file "
                          "(e.g. 'boom_models={L: calib/L.yaml, R: calib/R.yaml}')")
    return node


def model_files(cfg) -> list[str]:
    """The calibrated model files a composed config names (``boom_model``, ``boom_models.*``): inputs
    that no output of a stage may overwrite."""
    one = cfg.get("boom_model")
    return [str(v) for v in ([one] if one else []) + list(boom_models_setting(cfg.get("boom_models")).values())]


def rig_booms(spec: RigSpec, boom_cfg=None, boom_model: str | None = None, boom_models=None,
              load_model: ModelLoader | None = None) -> dict[str, Boom]:
    """Rig boom name -> the :class:`Boom` it drills with, most specific first: ``boom_models.<name>`` (a
    calibrated model of that boom), ``boom_model`` (a calibrated model of one kind: every boom of that
    kind), the composed ``boom`` node (its kind), ``conf/boom/<kind>.yaml``. Every file is read here,
    before any work; a bad one is a :class:`ConfigError` naming the setting."""
    composed = load_boom(boom_cfg) if boom_cfg is not None else None
    nominal = nominal_booms(spec, composed)
    known = {composed.name: composed, **nominal} if composed is not None else nominal  # what a model may sit on
    per_boom = boom_models_setting(boom_models)
    names = [m.name for m in spec.mounts]
    unknown = sorted(set(per_boom) - set(names))
    if unknown:
        raise ConfigError(f"boom_models: no boom {unknown} in rig '{spec.name}' ({spec.source}); booms: {names}")
    if (boom_model or per_boom) and load_model is None:
        raise ConfigError("boom_model / boom_models: this command cannot load calibrated boom models")
    by_kind: dict[str, Boom] = {}
    if boom_model:
        model = load_model("boom_model", boom_model, known)
        if model.name not in nominal:
            raise ConfigError(f"boom_model = {boom_model!r}: a model of boom {model.name!r}, but rig '{spec.name}' "
                              f"({spec.source}) has booms of kind {sorted(nominal)}")
        by_kind[model.name] = model
    out = {}
    for m in spec.mounts:
        if m.name in per_boom:
            model = load_model(f"boom_models.{m.name}", per_boom[m.name], known)
            if model.name != m.boom:
                raise ConfigError(f"boom_models.{m.name} = {per_boom[m.name]!r}: a model of boom {model.name!r}, but "
                                  f"boom '{m.name}' of rig '{spec.name}' is a {m.boom!r} ({spec.source})")
            out[m.name] = model
        else:
            out[m.name] = by_kind.get(m.boom, nominal[m.boom])
    return out


def build_rig(rig_cfg, tunnel_cfg, safety_cfg, booms: Mapping[str, Boom] | None = None, boom_cfg=None) -> Rig:
    """The rig of the ``rig`` node or name (:func:`rig_spec`), each boom with its own safety model seen from
    its base (the same tunnel and distances as :func:`pipeline.assembly.build.build_safety`). ``booms`` (rig
    boom name -> :class:`Boom`, from :func:`rig_booms`) gives each boom its model; without it every boom is
    its kind's nominal boom (:func:`nominal_booms` with ``boom_cfg``). Errors name the rig file and the boom
    (:func:`pipeline.geometry.rig.build_rig`)."""
    spec = rig_cfg if isinstance(rig_cfg, RigSpec) else rig_spec(rig_cfg)
    if booms is None:
        booms = rig_booms(spec, boom_cfg)
    distances, n, exact = safety_settings(safety_cfg)
    return place_booms(spec, booms, build_tunnel(tunnel_cfg), distances, n, exact)


def composed_rig(cfg, load_model: ModelLoader | None = None) -> Rig:
    """The rig of a composed config (``rig``, ``tunnel``, ``safety``), its booms from ``boom``, ``boom_model``
    and ``boom_models`` (:func:`rig_booms`): what every stage that places a rig calls first."""
    spec = rig_spec(cfg.rig)
    booms = rig_booms(spec, cfg.boom, cfg.get("boom_model"), cfg.get("boom_models"), load_model)
    # a rig given by name (rig=trio on params.yaml) brings the drift its file selects, as composing it would
    tunnel = rig_tunnel(cfg.rig, cfg.tunnel) if isinstance(cfg.rig, str) else cfg.tunnel
    return build_rig(spec, tunnel, cfg.safety, booms)


def load_rig(name: str, tunnel: Tunnel, distances: SafetyDistances, points_per_capsule: int = 16,
             booms: Mapping[str, Boom] | None = None, exact: bool = True) -> Rig:
    """The rig ``conf/rig/<name>.yaml`` in ``tunnel`` with the given safety distances (a safety model's
    ``safety.tunnel, safety.distances, safety.points_per_capsule``, ``safety.exact``), its booms ``booms`` or their
    kinds' configs."""
    spec = rig_spec(name)
    return place_booms(spec, rig_booms(spec) if booms is None else booms, tunnel, distances, points_per_capsule, exact)


def rig_record(cfg) -> dict:
    """What a round is planned with, as plain data for its JSON (``planned_with``): the rig (name, d_boom and
    each boom's name, kind, base and park as the rig file writes them) and the tunnel (kind; a horseshoe's
    width and wall height, a profile's file and the MD5 of its content, so a file edited in place or another
    file of the same name is told apart). ``execute`` and the independent checker compare it with their own."""
    spec = rig_spec(cfg.rig)
    node = rig_tunnel(cfg.rig, cfg.tunnel) if isinstance(cfg.rig, str) else as_dict(cfg.tunnel)
    kind = node.get("kind", "horseshoe")
    if kind == "profile":
        from pipeline.core.io import file_md5

        tunnel = {"kind": "profile", "file": str(node.get("file")), "md5": file_md5(project_path(node["file"]))}
    else:
        tunnel = {"kind": str(kind), "width": float(node["width"]), "wall_height": float(node["wall_height"])}
    booms = [{"name": m.name, "boom": m.boom, "base": [float(v) for v in m.base], "park": [float(v) for v in m.park]}
             for m in spec.mounts]
    return {"rig": {"name": spec.name, "d_boom": float(spec.d_boom), "booms": booms}, "tunnel": tunnel}


def record_differences(planned: dict, now: dict) -> list[str]:
    """Where two :func:`rig_record` records differ (numbers within 1e-9; a file by its MD5, not its path), in
    words; empty when they agree."""
    import math

    out: list[str] = []

    def walk(a, b, where):
        if isinstance(a, dict) and isinstance(b, dict):
            keys = set(a) | set(b)
            if "md5" in keys:  # a file by its content: the same profile under another path is the same tunnel
                keys.discard("file")
            for k in sorted(keys, key=str):
                walk(a.get(k), b.get(k), f"{where}.{k}" if where else str(k))
        elif isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
            for i, (x, y) in enumerate(zip(a, b, strict=True)):
                walk(x, y, f"{where}[{i}]")
        elif (isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool)
              and not isinstance(b, bool)):
            if not math.isclose(a, b, rel_tol=0, abs_tol=1e-9):
                out.append(f"{where}: planned {a!r}, now {b!r}")
        elif a != b:
            out.append(f"{where}: planned {a!r}, now {b!r}")

    walk(planned, now, "")
    return out


def true_rig_booms(rig: Rig, boom_file: str | None, model_file: str | None,
                   load_model: ModelLoader | None = None) -> tuple[list[Boom], str]:
    """The boom each rig boom really is, for the as-drilled log (``execute.true_boom``: a boom config file
    like conf/boom/jumbo8.yaml, given by path; ``execute.true_boom_model``: a calibrated model file), for
    every rig boom of its kind, the others as planned; with neither, the booms the round was planned with.
    Returns them in the rig's order and what they are (for the log's JSON)."""
    planned = [m.boom for m in rig.booms]
    if boom_file and model_file:
        raise ConfigError("execute: give execute.true_boom or execute.true_boom_model, not both")
    if not boom_file and not model_file:
        return planned, "the planning model"
    if boom_file:
        import yaml

        path = project_path(boom_file)
        try:
            node = yaml.safe_load(path.read_text())
        except (OSError, yaml.YAMLError) as e:
            raise ConfigError(f"execute.true_boom = {boom_file!r}: cannot read it ({' '.join(str(e).split())})") \
                from None
        true = load_boom(node if isinstance(node, Mapping) else {})
        setting = f"execute.true_boom={boom_file}"
    else:
        if load_model is None:
            raise ConfigError("execute.true_boom_model: this command cannot load calibrated boom models")
        nominal = {m.boom.name: getattr(m.boom, "nominal", m.boom) for m in rig.booms}
        true = load_model("execute.true_boom_model", model_file, nominal)
        setting = f"execute.true_boom_model={model_file}"
    kinds = sorted({m.boom.name for m in rig.booms})
    if true.name not in kinds:
        raise ConfigError(f"{setting}: a boom {true.name!r}, but rig '{rig.name}' has booms of kind {kinds}")
    return [true if m.boom.name == true.name else m.boom for m in rig.booms], setting
