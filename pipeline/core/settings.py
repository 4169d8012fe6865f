"""Typed, range-checked settings read from config nodes, before any work starts.

A settings class is a frozen dataclass whose fields carry their rules (``field(metadata=rule(gt=0))``);
:func:`parse` reads a config node into it and names the setting and the value of the first problem:
``train.lr = 'abc': expected a number``. A key the class does not know is refused with the closest
known one (``solver.deep_start: unknown setting; did you mean 'deep_starts'?``), and a field whose type
is another settings class is parsed as a nested node. Stages parse every group they use first thing, so a
bad value fails before data is loaded, files are written or an MLflow run is created.

Every size, count, duration and iteration budget has an upper bound as well as a lower one (a huge
value must be refused by name, not end in an allocation traceback after minutes of work); each group's conf
file states its bounds and why. Seeds are bounded by :data:`SEED_MAX`.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import typing
from collections.abc import Mapping, Sequence
from typing import Any

from pipeline.core.errors import ConfigError

# the largest seed every consumer takes: numpy's legacy seeding stops at 2**32 - 1, torch's overflows above 2**64 - 1
SEED_MAX = 2**32 - 1
# the most threads a thread setting takes: a thread pool beyond it is a typo (the reference machine has 2 cores)
MAX_THREADS = 256


def rule(*, gt: float | None = None, ge: float | None = None, le: float | None = None,
         choices: Sequence | None = None, min_items: int | None = None, max_items: int | None = None) -> dict:
    """Field metadata: bounds (``gt``, ``ge``, ``le``), allowed ``choices`` (of a value or of each item
    of a list), and for a list its least and largest lengths ``min_items`` and ``max_items``."""
    return {"rule": {"gt": gt, "ge": ge, "le": le, "choices": tuple(choices) if choices else None,
                     "min_items": min_items, "max_items": max_items}}


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


def check_rule(value: Any, where: str, gt=None, ge=None, le=None, choices=None, min_items=None,
               max_items=None) -> None:
    values = value if isinstance(value, (list, tuple)) else [value]
    if min_items is not None and len(values) < min_items:
        raise ConfigError(f"{where} = {list(values)!r}: expected at least {min_items} item(s)")
    if max_items is not None and len(values) > max_items:
        raise ConfigError(f"{where}: {len(values)} items, at most {max_items} allowed")
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


def unknown_keys(node: Mapping, known, where: str, note: str = "") -> None:
    """ConfigError for the first key of ``node`` not in ``known``, with the closest known one (and ``note``)."""
    for key in node:
        if key not in known:
            close = difflib.get_close_matches(str(key), list(known), n=1, cutoff=0.6)
            hint = f"did you mean '{close[0]}'? " if close else ""
            raise ConfigError(f"{where}.{key}: unknown setting; {hint}known: {sorted(known)}{note}")


def parse(cls: type[T], node: Mapping | None, where: str) -> T:
    """Read the config node ``where`` into the settings dataclass ``cls``, checking each field and
    refusing keys ``cls`` does not have."""
    if node is None or not isinstance(node, Mapping):
        raise ConfigError(f"{where}: expected a config group (a mapping), got {node!r}")
    fields = dataclasses.fields(cls)
    unknown_keys(node, {f.name for f in fields}, where)
    try:
        hints = typing.get_type_hints(cls)
    except (NameError, TypeError):  # an annotation only a type checker resolves: no nested classes
        hints = {}
    values = {}
    for f in fields:
        name = f"{where}.{f.name}"
        if f.name not in node:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise ConfigError(f"{where}: missing required setting '{f.name}'")
            continue
        value = node[f.name]
        nested = _settings_class(hints.get(f.name))
        if nested is not None and value is not None:
            values[f.name] = parse(nested, value, name)
            continue
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


def _settings_class(hint) -> type | None:
    """The dataclass of a field typed ``SomeSettings`` or ``SomeSettings | None``, else None."""
    if dataclasses.is_dataclass(hint):
        return hint
    args = [a for a in typing.get_args(hint) if a is not type(None)]
    return args[0] if len(args) == 1 and dataclasses.is_dataclass(args[0]) else None


@dataclasses.dataclass(frozen=True)
class RuntimeSettings:
    """The ``runtime`` group: how stages run here, never what they compute (conf/runtime/default.yaml)."""

    # benchmark, solve, paper_baselines, ...
    threads: int | None = dataclasses.field(default=2, metadata=rule(ge=1, le=MAX_THREADS))
    train_threads: int | None = dataclasses.field(default=None, metadata=rule(ge=1, le=MAX_THREADS))
    calibrate_threads: int | None = dataclasses.field(default=1, metadata=rule(ge=1, le=MAX_THREADS))
    progress: bool = True  # train's tqdm bar
    log_model: bool = True  # train: the network logged as an MLflow model
    # train: steps between resume states
    checkpoint_every: int = dataclasses.field(default=1000, metadata=rule(ge=0, le=10_000_000))
    resume: bool = True  # train: continue an interrupted training of the same settings, data and code (same weights)

    @classmethod
    def from_config(cls, cfg: Mapping) -> RuntimeSettings:
        """The ``runtime`` node of a composed config (its defaults where a config has none)."""
        return parse(cls, cfg.get("runtime") or {}, "runtime")
