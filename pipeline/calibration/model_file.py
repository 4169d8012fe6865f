"""An identified boom model on disk: the nominal boom's name plus its error twists, as YAML a
field engineer can read (degrees and millimetres), loaded back as a :class:`BoomWithErrors` that
``solve`` and every IK solver can use (``boom_model=<file>``)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

import torch
import yaml

from pipeline.calibration.error_model import COMPONENTS, DTYPE, ROTATION, BoomWithErrors, parameter_names
from pipeline.core.config import project_path
from pipeline.core.errors import ConfigError, InputError
from pipeline.core.io import write_text
from pipeline.geometry.kinematics import Boom

FORMAT = "boom-ik/error-model/1"
ANGLE_UNIT, LENGTH_UNIT = "deg", "mm"  # what the file holds; converted to rad / m on load
_TO_FILE = [math.degrees(1.0) if c in ROTATION else 1e3 for c in range(len(COMPONENTS))]


def _row_keys(boom: Boom) -> list[str]:
    return [name.split(".")[0] for name in parameter_names(boom)[:: len(COMPONENTS)]]


def model_text(boom: Boom, twists: torch.Tensor, identified: list[str] | None = None, fit: Mapping | None = None,
               notes: list[str] | None = None) -> str:
    """The YAML text of a model: ``boom`` is the nominal boom, ``twists (n_rows, 6)`` in rad / m."""
    errors = {
        key: {c: float(twists[r, i]) * _TO_FILE[i] for i, c in enumerate(COMPONENTS)}
        for r, key in enumerate(_row_keys(boom))
    }
    doc = {
        "format": FORMAT,
        "boom": boom.name,
        "angle_unit": ANGLE_UNIT,
        "length_unit": LENGTH_UNIT,
        "components": list(COMPONENTS),
        "errors": errors,
    }
    if identified is not None:
        doc["identified"] = list(identified)
    if fit:
        doc["fit"] = {k: (float(v) if isinstance(v, float) else v) for k, v in fit.items()}
    if notes:
        doc["merged"] = list(notes)
    head = ("# Identified error model of a drilling boom (pipeline.calibration). Each row's error twist is\n"
            "# (rx, ry, rz) deg and (tx, ty, tz) mm in the joint's axis frame RotX(alpha) TransX(a) (z = the\n"
            "# joint axis), pre-multiplied onto the D-H row: see docs/calibration.md.\n")
    return head + yaml.safe_dump(doc, sort_keys=False)


def save_model(path: str | Path, boom: Boom, twists: torch.Tensor, identified: list[str] | None = None,
               fit: Mapping | None = None, notes: list[str] | None = None) -> None:
    write_text(model_text(boom, twists, identified, fit, notes), path)


def load_model(path: str | Path, boom: Boom | Mapping[str, Boom] | None = None) -> BoomWithErrors:
    """A :class:`BoomWithErrors` from a model file. The nominal boom is ``boom`` if given (then the names
    must agree), else the one of the file's kind in a mapping kind -> boom (the composition root's nominal
    booms), else ``conf/boom/<boom>.yaml`` of the name in the file."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such boom model file")
    try:
        doc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise InputError(f"{path}: not valid YAML ({exc})") from None
    if not isinstance(doc, Mapping) or doc.get("format") != FORMAT:
        got = doc.get("format") if isinstance(doc, Mapping) else type(doc).__name__
        raise InputError(f"{path}: format = {got!r}; expected {FORMAT!r}")
    for key, want in (("angle_unit", ANGLE_UNIT), ("length_unit", LENGTH_UNIT), ("components", list(COMPONENTS))):
        if doc.get(key) != want:
            raise InputError(f"{path}: {key} = {doc.get(key)!r}; expected {want!r}")
    name = doc.get("boom")
    if isinstance(boom, Mapping):
        boom = boom.get(name) if isinstance(name, str) else None
    if boom is None:
        from pipeline.assembly.build import load_boom

        try:
            boom = load_boom(str(name))
        except ConfigError as exc:
            raise InputError(f"{path}: boom = {name!r}: {exc}") from None
    elif boom.name != name:
        raise InputError(f"{path}: model of boom {name!r}, but boom {boom.name!r} was given")
    errors = doc.get("errors")
    keys = _row_keys(boom)
    if not isinstance(errors, Mapping) or set(errors) != set(keys):
        found = sorted(errors) if isinstance(errors, Mapping) else errors
        raise InputError(f"{path}: errors must list rows {keys} of boom {boom.name!r}; found {found!r}")
    twists = torch.zeros(boom.n_rows, len(COMPONENTS), dtype=DTYPE)
    for r, key in enumerate(keys):
        row = errors[key]
        if not isinstance(row, Mapping) or set(row) != set(COMPONENTS):
            raise InputError(f"{path}: errors.{key} must give {list(COMPONENTS)}; got {row!r}")
        for i, c in enumerate(COMPONENTS):
            v = row[c]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise InputError(f"{path}: errors.{key}.{c} = {v!r}: expected a finite number")
            twists[r, i] = float(v) / _TO_FILE[i]
    return BoomWithErrors(boom, twists)


def model_setting(setting: str, value, nominal: Mapping[str, Boom]) -> BoomWithErrors:
    """The calibrated model a setting names (``boom_model``, ``boom_models.L``: a file, relative to the
    project root), on the nominal boom of its kind in ``nominal``; a missing or bad file is a
    :class:`ConfigError` naming the setting."""
    if not isinstance(value, (str, Path)) or not str(value):
        raise ConfigError(f"{setting} = {value!r}: expected the path of a boom model file")
    try:
        return load_model(project_path(value), nominal)
    except (InputError, ConfigError, OSError) as exc:
        raise ConfigError(f"{setting} = {str(value)!r}: {exc}") from None
