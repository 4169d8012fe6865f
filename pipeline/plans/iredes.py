"""IREDES drill plans (``DRPPlan`` XML), the format drill rigs exchange.

What real files look like (IREDES Drill Rig profile V 1.0; sources below): the root
``DRPPlan`` is in the Drill Rig namespace ``http://www.iredes.org/xml/DrillRig`` (the default
namespace of the file) and the shared IREDES elements carry the prefix ``IR:`` for
``http://www.iredes.org/xml``::

    <DRPPlan xmlns="http://www.iredes.org/xml/DrillRig" xmlns:IR="http://www.iredes.org/xml"
             IRVersion="V 1.0" IRDownwCompat="V 1.0" DRPPlanVersion="V 1.0" DRPPlanDownwCompat="V 1.0">
      <IR:GenHead><IR:FileCreateDate>...</IR:FileCreateDate><IR:IRversion ...>V 1.0</IR:IRversion></IR:GenHead>
      <IR:PlanId>...</IR:PlanId> <IR:PlanName>...</IR:PlanName> <IR:Comment>...</IR:Comment>
      <DrillPlan>
        <NumberOfHoles>2</NumberOfHoles>
        <Hole>
          <HoleId>C01</HoleId>
          <StartPoint><IR:PointX>..</IR:PointX><IR:PointY>..</IR:PointY><IR:PointZ>..</IR:PointZ></StartPoint>
          <EndPoint>...</EndPoint>
          <TypeOfHole>Undefined</TypeOfHole> <DrillBitDia>48</DrillBitDia>
          <HoleOptions>...</HoleOptions>
        </Hole>
      </DrillPlan>
      <IR:GenTrailer><IR:FileCloseDate>...</IR:FileCloseDate><IR:ChkSum>1723439548</IR:ChkSum></IR:GenTrailer>
    </DRPPlan>

Real files may also hold a ``DrillPosPlan`` (position and coordinate system) and per-hole
``HoleName``, ``MwdOn``, ``HoleOptions``. The reader finds ``Hole`` elements wherever they sit,
matches element names with or without a namespace, keeps unknown single-value ``Hole``
children as extra columns, and reads back the extra columns this writer stores in
``HoleOptions`` (namespace :data:`BIK_NS`). Collar = ``StartPoint``, toe = ``EndPoint``,
``TypeOfHole`` -> ``hole_type``, ``DrillBitDia`` -> ``diameter_mm``.

Checksum (``IR:GenTrailer/IR:ChkSum``, optional here): the IREDES schema (IRtypes.xsd) says
it is a CRC32 "calculated over the ENTIRE XML file ready to send using the value string "0"
as ChkSum value", and types it ``xsd:hexBinary``; in practice Epiroc's rig software and the
tools that talk to it write it as an unsigned *decimal* integer. So: the CRC32 (zlib/IEEE
802.3, as both tools use) is taken over the file's bytes with the element's text replaced
by ``0``; the writer writes decimal by default (``checksum="hex"``: 8 upper-case hex digits);
the reader accepts either spelling. A file whose checksum cannot be verified (no trailer, an
empty or ``0`` value, UTF-16/32 bytes, a ``ChkSum`` only inside a comment) is *unverified*:
refused under ``checksum="refuse"``, read and marked ``unverified`` under ``"warn"``
(:func:`verify_checksum`); the plan carries the state (``DrillPlan.checksum``).

Axes: IREDES has no fixed axis convention. Surface-mine files put northing in ``PointX`` and
easting in ``PointY``; the boom base frame is x toward the face, y across, z up. The mapping
is :class:`AxisMap` (``axes``, ``unit``, ``origin``): by default ``PointX -> x``, ``PointY -> y``,
``PointZ -> z`` in metres with the base frame at the file's origin, which is what this writer
writes, so its files round-trip.

Sources: iredes.org/irdocs/chksum.html and gentrailertype.html (ChkSum and GenTrailer,
IRtypes.xsd); iredes.org/irdocs/planidref2.html and plantorock.html (Drill Rig namespace,
metres); the IREDES import/export of the Kirra blast design app (github.com/brentbuffham/
Kirra2D: ``src/dialog/popups/generic/ExportDialogs.js``, ``src/fileIO/EpirocIO/IREDESParser.js``
and its notes, which show the element nesting above, the northing-in-PointX convention and
the decimal "Epiroc" vs hexBinary "XSD spec" checksum options); and a stand-alone C#
``IredesChecksum`` checker that parses the stored value as a decimal ``uint`` and computes
the CRC32 of the UTF-8 file with the value replaced by ``0``.

XML is read with :mod:`xml.parsers.expat` (standard library; it gives the line of every
``<Hole>``, which row-level problems name) in one streaming pass: each ``<Hole>`` becomes a small
:mod:`xml.etree.ElementTree` tree, is read and dropped, so memory follows the holes' values, not a
tree of the file; a text node over ``max_text`` characters is refused. Written with ElementTree.
No third-party XML library is needed: the structure is flat, and lxml would add a compiled
dependency for no gain here.
"""

from __future__ import annotations

import logging
import math
import re
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from xml.etree import ElementTree as ET
from xml.parsers import expat

import numpy as np
import pandas as pd

from pipeline.core.errors import ConfigError, InputError
from pipeline.core.io import atomic_write
from pipeline.plans.model import (
    COORDS,
    MIN_LENGTH,
    REQUIRED,
    DrillPlan,
    checked_plan,
    infer_column_types,
    plan_frame,
)

log = logging.getLogger(__name__)

IR_NS = "http://www.iredes.org/xml"
DR_NS = "http://www.iredes.org/xml/DrillRig"
BIK_NS = "urn:boom-ik:drill-plan"  # our extra columns, inside HoleOptions
VERSION = "V 1.0"
UNITS = {"m": 1.0, "mm": 1e-3}
CHECKSUM_POLICIES = ("refuse", "warn", "ignore")
CHECKSUM_FORMATS = ("decimal", "hex", None)
POINTS = ("StartPoint", "EndPoint")
AXES = ("PointX", "PointY", "PointZ")
LABELS = [f"{p}/{a}" for p in POINTS for a in AXES]
KNOWN = {"HoleId", "TypeOfHole", "DrillBitDia", "HoleOptions", *POINTS}
_CHKSUM = re.compile(rb"(<(?:[A-Za-z_][\w.-]*:)?ChkSum(?:\s[^>]*)?>)([^<]*)(</(?:[A-Za-z_][\w.-]*:)?ChkSum\s*>)")


def _local(tag: str) -> str:
    return tag.rpartition("}")[2]


def _child(el: ET.Element | None, name: str) -> ET.Element | None:
    """First child with this local name, in any namespace."""
    if el is None:
        return None
    return next((c for c in el if _local(c.tag) == name), None)


def _text(el: ET.Element | None) -> str:
    return "" if el is None or el.text is None else el.text.strip()


# ---------------------------------------------------------------------------------------------
# Axes


@dataclass(frozen=True)
class AxisMap:
    """IREDES points to the boom base frame: ``base = R @ (scale * (point - origin))``.

    ``axes``: for PointX, PointY, PointZ in turn, the base axis it becomes, optionally signed:
    ``"xyz"`` (default) keeps them, ``"yxz"`` swaps the first two (a surface-mine file with
    northing in PointX, read with y along the northing), ``"x-yz"`` flips y. ``unit``: the
    file's length unit, ``"m"`` or ``"mm"``. ``origin``: the base frame's origin as an IREDES
    point, in the file's unit and axes.
    """

    axes: str = "xyz"
    unit: str = "m"
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    R: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        spec = str(self.axes).replace(" ", "").lower()
        tokens = re.findall(r"([+-]?)([xyz])", spec)
        if "".join(s + a for s, a in tokens) != spec or sorted(a for _, a in tokens) != ["x", "y", "z"]:
            raise ConfigError(
                f"iredes.axes = {self.axes!r}: expected the base axes of PointX, PointY, PointZ, each of x, y, z "
                f"once with an optional sign, e.g. 'xyz', 'yxz', 'x-yz'"
            )
        if self.unit not in UNITS:
            raise ConfigError(f"iredes.unit = {self.unit!r}: expected one of {list(UNITS)}")
        origin = tuple(self.origin)
        if len(origin) != 3 or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in origin):
            raise ConfigError(f"iredes.origin = {self.origin!r}: expected three finite numbers (file units)")
        R = np.zeros((3, 3))
        for i, (sign, axis) in enumerate(tokens):
            R["xyz".index(axis), i] = -1.0 if sign == "-" else 1.0
        object.__setattr__(self, "origin", tuple(float(v) for v in origin))
        object.__setattr__(self, "R", R)

    @classmethod
    def from_config(cls, cfg: Mapping | None) -> AxisMap:
        """From a mapping with any of ``axes``, ``unit``, ``origin`` (e.g. a Hydra node)."""
        cfg = dict(cfg or {})
        unknown = sorted(set(cfg) - {"axes", "unit", "origin"})
        if unknown:
            raise ConfigError(f"iredes: unknown field(s) {unknown}; allowed: ['axes', 'unit', 'origin']")
        return cls(**cfg)

    @property
    def scale(self) -> float:
        return UNITS[self.unit]

    def to_base(self, points: np.ndarray) -> np.ndarray:
        """``(..., 3k)`` file points (x, y, z repeated) to base-frame metres."""
        p = np.asarray(points, dtype=np.float64)
        xyz = p.reshape(*p.shape[:-1], -1, 3)
        return (self.scale * (xyz - np.asarray(self.origin)) @ self.R.T).reshape(p.shape)

    def from_base(self, points: np.ndarray) -> np.ndarray:
        p = np.asarray(points, dtype=np.float64)
        xyz = p.reshape(*p.shape[:-1], -1, 3)
        return ((xyz @ self.R) / self.scale + np.asarray(self.origin)).reshape(p.shape)


def _axis_map(axes: str | AxisMap, unit: str, origin) -> AxisMap:
    return axes if isinstance(axes, AxisMap) else AxisMap(axes, unit, tuple(origin))


# ---------------------------------------------------------------------------------------------
# Checksum


def crc32_text(value: int, fmt: str = "decimal") -> str:
    """The ChkSum spelling of a CRC32: unsigned decimal, or 8 upper-case hex digits."""
    if fmt not in ("decimal", "hex"):
        raise ConfigError(f"iredes checksum format = {fmt!r}: expected 'decimal' or 'hex'")
    return str(value) if fmt == "decimal" else f"{value:08X}"


_HIDDEN = re.compile(rb"<!--.*?-->|<!\[CDATA\[.*?\]\]>|<\?.*?\?>", re.DOTALL)  # no element can stand in these
_WIDE_BOMS = (b"\xff\xfe", b"\xfe\xff", b"\x00\x00\xfe\xff")


def _chksum_matches(data: bytes) -> list[re.Match]:
    """``ChkSum`` elements in the bytes, leaving out look-alikes inside comments, CDATA and
    processing instructions (a checksum there checks nothing)."""
    hidden = [m.span() for m in _HIDDEN.finditer(data)]
    return [m for m in _CHKSUM.finditer(data) if not any(a <= m.start() < b for a, b in hidden)]


def file_crc32(data: bytes, source: str = "IREDES file") -> tuple[int, str | None]:
    """CRC32 of the file with the ChkSum text replaced by ``0``, and the stored text
    (``None`` when the file has no ChkSum element)."""
    found = _chksum_matches(data)
    if not found:
        return zlib.crc32(data), None
    if len(found) > 1:
        lines = [data.count(b"\n", 0, m.start()) + 1 for m in found]
        raise InputError(f"{source}: {len(found)} ChkSum elements (lines {lines}); an IREDES file has one")
    m = found[0]
    zeroed = data[: m.start(2)] + b"0" + data[m.end(2) :]
    return zlib.crc32(zeroed), m.group(2).decode("utf-8", "replace").strip()


def _matches(stored: str, crc: int) -> bool:
    """Stored text equals the CRC read as decimal (Epiroc practice) or as hex (the XSD's hexBinary)."""
    s = stored.strip()
    as_dec = s.isdigit() and int(s) == crc
    as_hex = re.fullmatch(r"(0[xX])?[0-9A-Fa-f]{1,8}", s) is not None and int(s, 16) == crc
    return as_dec or as_hex


def verify_checksum(data: bytes, source: str, policy: str = "refuse",
                    elements: Sequence[tuple[int, str]] | None = None) -> tuple[str, str]:
    """The file's ChkSum state: ``("verified", ...)``, ``("unverified", why)`` or ``("ignored", ...)``.

    Unverified: no ChkSum element (no trailer), a ChkSum of ``0`` or empty (not computed), an encoding
    whose bytes the CRC cannot be taken over as rig software does (UTF-16/32), a ChkSum that is not a
    real element (only in a comment), or a mismatch. ``policy="refuse"`` raises :class:`InputError`
    for every unverified file, ``"warn"`` logs it and reads on, ``"ignore"`` does not look.
    ``elements``: the (line, text) of the real ``ChkSum`` elements, as the parser found them."""
    if policy not in CHECKSUM_POLICIES:
        raise ConfigError(f"iredes checksum policy = {policy!r}: expected one of {list(CHECKSUM_POLICIES)}")
    if policy == "ignore":
        return "ignored", "solve.iredes.checksum=ignore"
    if elements is None:
        elements = _scan(data, source, MAX_TEXT).chksum
    if len(elements) > 1:
        raise InputError(f"{source}: {len(elements)} ChkSum elements (lines {[e[0] for e in elements]}); "
                         "an IREDES file has one")
    why = None
    if data.startswith(_WIDE_BOMS) or b"\x00" in data[:4096]:
        why = "the file is UTF-16 or UTF-32; the checksum is a CRC32 over the UTF-8 bytes rig software writes"
    elif not elements:
        found = _CHKSUM.search(data)
        why = ("a ChkSum stands only inside a comment, which checks nothing" if found else
               "the file has no ChkSum (no IR:GenTrailer)")
    elif elements[0][1] in ("", "0"):
        why = f"ChkSum is {elements[0][1]!r} (not computed)"
    else:
        crc, stored = file_crc32(data, source)
        if stored is None or stored != elements[0][1]:
            why = "the ChkSum element cannot be located in the file's bytes"
        elif _matches(stored, crc):
            return "verified", f"ChkSum {stored}"
        else:
            why = (f"IREDES checksum mismatch: ChkSum in the file is {stored!r}, the CRC32 of the file with "
                   f"ChkSum 0 is {crc} (hex {crc:08X}); the file changed after it was written")
    if policy == "refuse":
        raise InputError(f"{source}: {why}; refused (solve.iredes.checksum=refuse): pass checksum='warn' "
                         "(solve.iredes.checksum=warn) to solve it as unverified")
    log.warning("%s: %s; reading it anyway, as unverified (checksum=warn)", source, why)
    return "unverified", why


# ---------------------------------------------------------------------------------------------
# Reading

MAX_TEXT = 65_536  # characters in one text node: a coordinate needs 30, a 300 MB node is an attack or a fault
_FEED = 1 << 20  # bytes handed to expat at a time


@dataclass
class _Scan:
    root: str | None = None
    holes: list[tuple[str, list[str], dict[str, str]]] = field(default_factory=list)
    lines: list[int] = field(default_factory=list)
    top: dict[str, str] = field(default_factory=dict)  # PlanId, PlanName (children of the root)
    chksum: list[tuple[int, str]] = field(default_factory=list)


def _scan(data: bytes, source: str, max_text: int) -> _Scan:
    """One pass of expat over the file: each ``<Hole>`` is built as a small tree, read into its
    fields and dropped, so memory follows the holes' values, not a tree of the whole file; every
    text node longer than ``max_text`` characters is refused with its line."""
    parser = expat.ParserCreate(namespace_separator=" ")
    out = _Scan()
    stack: list[str] = []
    state = {"builder": None, "depth": 0, "size": 0, "line": 0}
    text: list[str] = []

    def qname(name: str) -> str:
        uri, _, local = name.rpartition(" ")
        return f"{{{uri}}}{local}" if uri else local

    def start(name, attrs):
        local = name.rpartition(" ")[2]
        if not stack:
            out.root = local
        stack.append(local)
        state["size"] = 0
        builder = state["builder"]
        if builder is None and local == "Hole":
            builder = state["builder"] = ET.TreeBuilder()
            state["depth"] = len(stack)
            out.lines.append(parser.CurrentLineNumber)
        if builder is not None:
            builder.start(qname(name), {qname(k): v for k, v in attrs.items()})
        else:
            text.clear()
            state["line"] = parser.CurrentLineNumber

    def end(name):
        local = stack.pop()
        state["size"] = 0
        builder = state["builder"]
        if builder is not None:
            builder.end(qname(name))
            if len(stack) + 1 == state["depth"]:
                out.holes.append(_hole_fields(builder.close()))
                state["builder"] = None
        elif local == "ChkSum":
            out.chksum.append((state["line"], "".join(text).strip()))
        elif local in ("PlanId", "PlanName") and len(stack) == 1:
            out.top[local] = "".join(text).strip()

    def chars(piece):
        state["size"] += len(piece)
        if state["size"] > max_text:
            raise InputError(f"{source}: line {parser.CurrentLineNumber}: a text node in <{stack[-1]}> is longer "
                             f"than {max_text} characters; not a drill plan value (solve.iredes.max_text)")
        if state["builder"] is not None:
            state["builder"].data(piece)
        else:
            text.append(piece)

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.CharacterDataHandler = chars
    try:
        for i in range(0, len(data), _FEED):
            parser.Parse(data[i : i + _FEED], False)
        parser.Parse(b"", True)
    except expat.ExpatError as e:
        raise InputError(
            f"{source}: malformed XML at line {e.lineno}, column {e.offset + 1}: {expat.ErrorString(e.code)}"
        ) from None
    return out


def _hole_fields(hole: ET.Element) -> tuple[str, list[str], dict[str, str]]:
    """Id, the six coordinate texts (StartPoint then EndPoint), and every other value."""
    coords = [_text(_child(_child(hole, p), a)) for p in POINTS for a in AXES]
    extra = {"hole_type": _text(_child(hole, "TypeOfHole"))}
    if _child(hole, "DrillBitDia") is not None:
        extra["diameter_mm"] = _text(_child(hole, "DrillBitDia"))
    for c in hole:  # single-value children we do not interpret (HoleName, MwdOn, ...)
        if _local(c.tag) not in KNOWN and len(c) == 0:
            extra[_local(c.tag)] = _text(c)
    options = _child(hole, "HoleOptions")
    for c in options if options is not None else ():
        if c.tag == f"{{{BIK_NS}}}Column" and c.get("name"):
            extra[c.get("name")] = _text(c)
    return _text(_child(hole, "HoleId")), coords, extra


def read_iredes_plan(
    path: str | Path,
    *,
    axes: str | AxisMap = "xyz",
    unit: str = "m",
    origin: Sequence[float] = (0.0, 0.0, 0.0),
    checksum: str = "refuse",
    max_text: int = MAX_TEXT,
    min_length: float = MIN_LENGTH,
) -> DrillPlan:
    """Read an IREDES ``DRPPlan`` into a :class:`DrillPlan` (base frame, metres).

    Row problems (a missing or unreadable point coordinate, an empty or duplicate ``HoleId``,
    ``EndPoint`` equal to ``StartPoint``) are collected with the line of the hole's ``<Hole>``
    tag, as the CSV reader does. ``checksum``: ``"refuse"`` (a file that cannot be verified
    raises), ``"warn"`` (logs it, reads on, the plan says ``checksum = "unverified"``) or
    ``"ignore"``; see :func:`verify_checksum`. Axes, unit, origin: :class:`AxisMap`.
    """
    path = Path(path)
    amap = _axis_map(axes, unit, origin)
    if not path.is_file():
        raise InputError(f"{path}: no such drill plan")
    data = path.read_bytes()
    if not data.strip():
        raise InputError(f"{path}: empty file; expected an IREDES DRPPlan")
    scan = _scan(data, str(path), max_text)
    if scan.root != "DRPPlan":
        raise InputError(f"{path}: root element is {scan.root!r}, expected 'DRPPlan' (an IREDES drill plan)")
    state, detail = verify_checksum(data, str(path), checksum, scan.chksum)
    del data
    if not scan.holes:
        raise InputError(f"{path}: no Hole elements in the DRPPlan")
    fields = scan.holes
    coord_text = pd.DataFrame([f[1] for f in fields], columns=LABELS, dtype=object)
    extras = pd.DataFrame([f[2] for f in fields], dtype=object).fillna("")
    extras = pd.concat([extras[["hole_type"]], infer_column_types(extras.drop(columns="hole_type"))], axis=1)
    plan_id = scan.top.get("PlanId") or path.stem
    plan = checked_plan(
        [f[0] for f in fields],
        coord_text,
        extras,
        np.array(scan.lines),
        source=str(path),
        fmt="iredes",
        plan_id=plan_id,
        name=scan.top.get("PlanName") or plan_id,
        labels=LABELS,
        to_base=amap.to_base,
        id_label="HoleId",
        length_label="EndPoint",
        min_length=min_length,
    )
    plan.checksum, plan.checksum_detail = state, detail
    return plan


# ---------------------------------------------------------------------------------------------
# Writing


def _num(value: float) -> str:
    """Shortest text that reads back to the same float, without an exponent (rig software)."""
    return np.format_float_positional(float(value) + 0.0, unique=True, trim="-")


def _sub(parent: ET.Element, ns: str, tag: str, text: str | None = None, **attrib) -> ET.Element:
    # Drill Rig elements go unqualified under the root's default namespace, as in real files
    # (ElementTree's default_namespace option refuses the unqualified attributes they carry).
    el = ET.SubElement(parent, tag if ns == DR_NS else f"{{{ns}}}{tag}", attrib)
    if text is not None:
        el.text = text
    return el


def _point(parent: ET.Element, name: str, xyz: np.ndarray) -> None:
    pt = _sub(parent, DR_NS, name)
    for axis, v in zip(AXES, xyz, strict=True):
        _sub(pt, IR_NS, axis, _num(v))


def _is_blank(value) -> bool:
    return value is None or (isinstance(value, float) and math.isnan(value)) or value is pd.NA


def iredes_bytes(
    plan: DrillPlan | pd.DataFrame,
    *,
    axes: str | AxisMap = "xyz",
    unit: str = "m",
    origin: Sequence[float] = (0.0, 0.0, 0.0),
    checksum: str | None = "decimal",
    plan_id: str | None = None,
    plan_name: str | None = None,
    created: datetime | str | None = None,
) -> bytes:
    """The IREDES file of a plan (UTF-8), with its ChkSum when ``checksum`` is given."""
    if checksum not in CHECKSUM_FORMATS:
        raise ConfigError(f"iredes checksum format = {checksum!r}: expected one of {list(CHECKSUM_FORMATS)}")
    amap = _axis_map(axes, unit, origin)
    holes = plan_frame(plan)
    meta = plan if isinstance(plan, DrillPlan) else None
    plan_id = plan_id or (meta.plan_id if meta else "") or "plan"
    plan_name = plan_name or (meta.name if meta else "") or plan_id
    stamp = created or datetime.now(UTC).replace(tzinfo=None, microsecond=0)
    stamp = stamp.isoformat() if isinstance(stamp, datetime) else str(stamp)

    versions = ("IRVersion", "IRDownwCompat", "DRPPlanVersion", "DRPPlanDownwCompat")
    root = ET.Element("DRPPlan", {"xmlns": DR_NS, **dict.fromkeys(versions, VERSION)})
    head = _sub(root, IR_NS, "GenHead")
    _sub(head, IR_NS, "FileCreateDate", stamp)
    _sub(head, IR_NS, "IRversion", VERSION, DownwCompat=VERSION)
    _sub(root, IR_NS, "PlanId", plan_id)
    _sub(root, IR_NS, "PlanName", plan_name)
    _sub(root, IR_NS, "Comment", f"boom-ik drill plan; axes={amap.axes} unit={amap.unit} origin={list(amap.origin)}")
    body = _sub(root, DR_NS, "DrillPlan")
    _sub(body, DR_NS, "NumberOfHoles", str(len(holes)))
    points = amap.from_base(holes[COORDS].to_numpy(dtype=np.float64))
    extra_cols = [c for c in holes.columns if c not in (*REQUIRED, "hole_type", "diameter_mm")]
    records = holes.to_dict("records")
    for row, pts in zip(records, points, strict=True):
        hole = _sub(body, DR_NS, "Hole")
        _sub(hole, DR_NS, "HoleId", str(row["hole_id"]))
        _point(hole, "StartPoint", pts[:3])
        _point(hole, "EndPoint", pts[3:])
        kind = row.get("hole_type")
        _sub(hole, DR_NS, "TypeOfHole", "Undefined" if _is_blank(kind) or kind == "" else str(kind))
        if not _is_blank(row.get("diameter_mm")):
            _sub(hole, DR_NS, "DrillBitDia", str(row["diameter_mm"]))
        values = [(c, row[c]) for c in extra_cols if not _is_blank(row[c])]
        if values:
            options = _sub(hole, DR_NS, "HoleOptions")
            for c, v in values:
                _sub(options, BIK_NS, "Column", _num(v) if isinstance(v, float) else str(v), name=str(c))
    if checksum is not None:
        trailer = _sub(root, IR_NS, "GenTrailer")
        _sub(trailer, IR_NS, "FileCloseDate", stamp)
        _sub(trailer, IR_NS, "ChkSum", "0")  # the placeholder the CRC is taken over
    ET.register_namespace("IR", IR_NS)
    ET.register_namespace("bik", BIK_NS)
    ET.indent(root, space="  ")
    text = ET.tostring(root, encoding="unicode")
    data = ('<?xml version="1.0" encoding="UTF-8"?>\n' + text + "\n").encode("utf-8")
    if checksum is None:
        return data
    crc, _ = file_crc32(data)
    return data.replace(b"<IR:ChkSum>0</IR:ChkSum>", f"<IR:ChkSum>{crc32_text(crc, checksum)}</IR:ChkSum>".encode())


def write_iredes_plan(plan: DrillPlan | pd.DataFrame, path: str | Path, **kw) -> None:
    """Write a plan as IREDES XML, atomically; ``kw`` as :func:`iredes_bytes`."""
    data = iredes_bytes(plan, **kw)
    atomic_write(path, lambda tmp: Path(tmp).write_bytes(data))
