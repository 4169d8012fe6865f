"""Typed, range-checked settings read from config nodes, before any work starts.

A settings class is a frozen dataclass whose fields carry their rules (``field(metadata=rule(gt=0))``);
:func:`parse` reads a config node into it and names the setting and the value of the first problem:
``train.lr = 'abc': expected a number``. Stages parse every group they use first thing, so a bad
value fails before data is loaded, files are written or an MLflow run is created.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from collections.abc import Mapping, Sequence
from typing import Any

from pipeline.core.errors import ConfigError


def rule(*, gt: float | None = None, ge: float | None = None, le: float | None = None,
         choices: Sequence | None = None) -> dict:
    """Field metadata: bounds (``gt``, ``ge``, ``le``) or allowed ``choices``."""
    return {"rule": {"gt": gt, "ge": ge, "le": le, "choices": tuple(choices) if choices else None}}


def _kind(annotation: str) -> tuple[str, bool]:
    """``"float | None"`` -> ``("float", True)``."""
    parts = [p.strip() for p in annotation.split("|")]
    optional = "None" in parts
    base = [p for p in parts if p != "None"]
    return (base[0] if base else "None"), optional


def coerce(value: Any, kind: str, where: str) -> Any:
    """``value`` as ``kind`` (int, float, bool, str, list[...]); ConfigError naming ``where`` otherwise."""
    if kind == "bool":
        if not isinstance(value, bool):
            raise ConfigError(f"{where} = {value!r}: expected true or false")
        return value
    if kind == "int":
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and math.isfinite(value) and value.is_integer():
                return int(value)
            raise ConfigError(f"{where} = {value!r}: expected an integer")
        return value
    if kind == "float":
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where} = {value!r}: expected a number")
        if not math.isfinite(value):
            raise ConfigError(f"{where} = {value!r}: expected a finite number")
        return float(value)
    if kind == "str":
        if not isinstance(value, str) or not value:
            raise ConfigError(f"{where} = {value!r}: expected a non-empty text")
        return value
    if kind.startswith(("list[", "tuple[")):
        if isinstance(value, (str, bytes)) or not isinstance(value, Sequence):
            raise ConfigError(f"{where} = {value!r}: expected a list")
        inner = kind[kind.index("[") + 1 : -1].split(",")[0].strip()
        items = [coerce(v, inner, f"{where}[{i}]") for i, v in enumerate(value)]
        return tuple(items) if kind.startswith("tuple[") else items
    return value  # anything else is checked by its own class


def check_rule(value: Any, where: str, gt=None, ge=None, le=None, choices=None) -> None:
    values = value if isinstance(value, (list, tuple)) else [value]
    for v in values:
        if choices is not None and v not in choices:
            raise ConfigError(f"{where} = {v!r}: expected one of {list(choices)}")
        if gt is not None and not v > gt:
            raise ConfigError(f"{where} = {v!r}: must be > {gt}")
        if ge is not None and not v >= ge:
            raise ConfigError(f"{where} = {v!r}: must be >= {ge}")
        if le is not None and not v <= le:
            raise ConfigError(f"{where} = {v!r}: must be <= {le}")


T = typing.TypeVar("T")


def parse(cls: type[T], node: Mapping | None, where: str) -> T:
    """Read the config node ``where`` into the settings dataclass ``cls``, checking each field."""
    if node is None or not isinstance(node, Mapping):
        raise ConfigError(f"{where}: expected a config group (a mapping), got {node!r}")
    values = {}
    for f in dataclasses.fields(cls):
        name = f"{where}.{f.name}"
        if f.name not in node:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise ConfigError(f"{where}: missing required setting '{f.name}'")
            continue
        value = node[f.name]
        kind, optional = _kind(f.type if isinstance(f.type, str) else f.type.__name__)
        if value is None:
            if not optional:
                raise ConfigError(f"{name} = null: a value is required")
            values[f.name] = None
            continue
        value = coerce(value, kind, name)
        check_rule(value, name, **f.metadata.get("rule", {}))
        values[f.name] = value
    return cls(**values)
