"""Read a ``conf/boom/*.yaml`` mapping into a :class:`~pipeline.geometry.kinematics.Boom`.

Parsing is kept apart from the chain (as pytorch_kinematics keeps ``urdf.py`` apart from
``chain.py``): each section has its own reader, and every number goes through one validator, so a
bad value is reported with its place (``boom 'jumbo8': joint 'q2'.range``) and the value.
Lengths are converted to metres and angles to radians here; the chain only computes.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

from pipeline.core.errors import ConfigError
from pipeline.core.settings import unknown_keys
from pipeline.geometry.kinematics import CONVENTIONS, JOINT_PARAMS, Boom, Capsule, Joint, PointSpec

ROW_KEYS = ("alpha", "a", "theta", "d")
LENGTH_UNITS = {"m": 1.0, "cm": 1e-2, "mm": 1e-3}
ANGLE_UNITS = {"deg": math.pi / 180.0, "rad": 1.0}
BOOM_KEYS = {
    "name", "convention", "length_unit", "angle_unit", "dh", "joints", "tool",
    "preview_depth", "bodies", "self_pairs", "description",
}
JOINT_KEYS = {"name", "label", "row", "param", "range", "locked"}
BODY_KEYS = {"start", "end", "radius", "tunnel_skip_end"}
POINT_KEYS = {"frame", "along_z"}


def require(mapping: Mapping, key: str, where: str):
    if key not in mapping or mapping[key] is None:
        raise ConfigError(f"{where}: missing required field '{key}'")
    return mapping[key]


def number(value, where: str) -> float:
    """The one number validator: a finite int or float (not a bool), as float."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{where} = {value!r}: expected a number")
    if not math.isfinite(value):
        raise ConfigError(f"{where} = {value!r}: expected a finite number")
    return float(value)


def reject_unknown(mapping: Mapping, allowed: set[str], where: str) -> None:
    unknown_keys(mapping, allowed, where)  # the settings' one check: names the key and the closest known one


def _choice(value, options, where: str):
    if value not in options:
        shown = sorted(options) if isinstance(options, dict) else options
        raise ConfigError(f"{where} = {value!r}; expected one of {shown}")
    return value


def _list(value, where: str, length: int | None = None) -> Sequence:
    ok = isinstance(value, Sequence) and not isinstance(value, str) and (length is None or len(value) == length)
    if not ok:
        shape = f"a list of {length}" if length else "a list"
        raise ConfigError(f"{where} = {value!r}: expected {shape}")
    return value


def _dh_rows(dh, where: str, ls: float, as_: float) -> list[tuple[float, float, float, float]]:
    if not _list(dh, f"{where}: dh"):
        raise ConfigError(f"{where}: dh must be a non-empty list of rows, got {dh!r}")
    rows = []
    for i, row in enumerate(dh, start=1):
        rw = f"{where}: dh row {i}"
        if not isinstance(row, Mapping):
            raise ConfigError(f"{rw} = {row!r}: expected a mapping with {ROW_KEYS}")
        reject_unknown(row, set(ROW_KEYS), rw)
        v = {k: number(require(row, k, rw), f"{rw}.{k}") for k in ROW_KEYS}
        rows.append((v["alpha"] * as_, v["a"] * ls, v["theta"] * as_, v["d"] * ls))
    return rows


def _joint(jc, index: int, where: str, n_rows: int, ls: float, as_: float) -> Joint:
    jw = f"{where}: joint {index}"
    if not isinstance(jc, Mapping):
        raise ConfigError(f"{jw} = {jc!r}: expected a mapping")
    reject_unknown(jc, JOINT_KEYS, jw)
    name = str(require(jc, "name", jw))
    jw = f"{where}: joint '{name}'"
    row = require(jc, "row", jw)
    if isinstance(row, bool) or not isinstance(row, int) or not 1 <= row <= n_rows:
        raise ConfigError(f"{jw}.row = {row!r}: expected a D-H row number 1..{n_rows}")
    param = _choice(require(jc, "param", jw), JOINT_PARAMS, f"{jw}.param")
    scale = as_ if param == "theta" else ls
    rng = _list(require(jc, "range", jw), f"{jw}.range", 2)
    lo, hi = (number(v, f"{jw}.range") * scale for v in rng)
    if not lo < hi:
        raise ConfigError(f"{jw}.range = {list(rng)!r}: lower must be below upper")
    locked = jc.get("locked")
    if locked is not None:
        locked = number(locked, f"{jw}.locked") * scale
        if not lo <= locked <= hi:
            raise ConfigError(f"{jw}.locked = {jc['locked']!r} lies outside range {list(rng)!r}")
    return Joint(name, row - 1, param, lo, hi, locked, str(jc.get("label", "")))


def _joints(joints_cfg, where: str, n_rows: int, ls: float, as_: float) -> list[Joint]:
    joints = [_joint(jc, j, where, n_rows, ls, as_) for j, jc in enumerate(_list(joints_cfg, f"{where}: joints"), 1)]
    if not joints:
        raise ConfigError(f"{where}: joints must list at least one joint")
    names = [j.name for j in joints]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ConfigError(f"{where}: joint '{dup[0]}': duplicate joint name")
    return joints


def _point(pc, where: str, n_rows: int, ls: float) -> PointSpec:
    reject_unknown(pc, POINT_KEYS, where)
    frame = require(pc, "frame", where)
    if frame != "tool" and (isinstance(frame, bool) or not isinstance(frame, int) or not 0 <= frame <= n_rows):
        raise ConfigError(f"{where}.frame = {frame!r}: expected 0..{n_rows} or 'tool'")
    frame = n_rows + 1 if frame == "tool" else frame
    return PointSpec(frame, number(pc.get("along_z", 0.0), f"{where}.along_z") * ls)


def _bodies(bodies_cfg, where: str, n_rows: int, ls: float) -> list[Capsule]:
    bodies = []
    for name, bc in (bodies_cfg or {}).items():
        bw = f"{where}: bodies.{name}"
        reject_unknown(bc, BODY_KEYS, bw)
        start, end = (_point(require(bc, key, bw), f"{bw}.{key}", n_rows, ls) for key in ("start", "end"))
        radius = number(require(bc, "radius", bw), f"{bw}.radius") * ls
        skip = number(bc.get("tunnel_skip_end", 0.0), f"{bw}.tunnel_skip_end") * ls
        if radius < 0 or skip < 0:
            raise ConfigError(f"{bw}: radius and tunnel_skip_end must be >= 0")
        bodies.append(Capsule(str(name), start, end, radius, skip))
    return bodies


def _self_pairs(pairs_cfg, where: str, names: set[str]) -> list[tuple[str, str]]:
    pairs = []
    for pair in pairs_cfg or []:
        if len(pair) != 2 or not set(pair) <= names:
            raise ConfigError(f"{where}: self_pairs entry {list(pair)!r} must name two bodies of {sorted(names)}")
        pairs.append(tuple(pair))
    return pairs


def boom_from_config(cfg: Mapping) -> Boom:
    """A :class:`Boom` from a ``conf/boom/*.yaml`` mapping, validating every field."""
    if not isinstance(cfg, Mapping):
        raise ConfigError(f"boom config must be a mapping, got {type(cfg).__name__}")
    name = str(cfg.get("name", "<unnamed>"))
    where = f"boom '{name}'"
    reject_unknown(cfg, BOOM_KEYS, where)
    convention = _choice(require(cfg, "convention", where), CONVENTIONS, f"{where}: convention")
    ls = LENGTH_UNITS[_choice(cfg.get("length_unit", "m"), LENGTH_UNITS, f"{where}: length_unit")]
    as_ = ANGLE_UNITS[_choice(cfg.get("angle_unit", "deg"), ANGLE_UNITS, f"{where}: angle_unit")]
    rows = _dh_rows(require(cfg, "dh", where), where, ls, as_)
    joints = _joints(require(cfg, "joints", where), where, len(rows), ls, as_)
    tool = [number(v, f"{where}: tool") * ls for v in _list(cfg.get("tool", (0.0, 0.0, 0.0)), f"{where}: tool", 3)]
    depth = cfg.get("preview_depth")
    if depth is not None:
        depth = number(depth, f"{where}: preview_depth") * ls
        if depth <= 0:
            raise ConfigError(f"{where}: preview_depth = {cfg['preview_depth']!r}: must be > 0")
    bodies = _bodies(cfg.get("bodies"), where, len(rows), ls)
    pairs = _self_pairs(cfg.get("self_pairs"), where, {b.name for b in bodies})
    return Boom(name, convention, rows, joints, tool, depth, bodies, pairs)
