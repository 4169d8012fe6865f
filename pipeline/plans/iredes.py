"""IREDES drill plans (``DRPPlan`` XML), the format drill rigs exchange: read and written.

What real files look like (IREDES Drill Rig profile V 1.0; sources below): the root
``DRPPlan`` is in the Drill Rig namespace ``http://www.iredes.org/xml/DrillRig`` (the default
namespace of the file) and the shared IREDES elements carry the prefix ``IR:`` for
``http://www.iredes.org/xml``::

    <DRPPlan xmlns="http://www.iredes.org/xml/DrillRig" xmlns:IR="http://www.iredes.org/xml"
             IRVersion="V 1.0" IRDownwCompat="V 1.0" DRPPlanVersion="V 1.0" DRPPlanDownwCompat="V 1.0">
      <IR:GenHead><IR:FileCreateDate>...</IR:FileCreateDate><IR:IRversion ...>V 1.0</IR:IRversion></IR:GenHead>
      <IR:PlanId>...</IR:PlanId> <IR:PlanName>...</IR:PlanName> <IR:Comment>...</IR:Comment>
      <IR:Project>...</IR:Project> <IR:WorkOrder>...</IR:WorkOrder>
      <DrillPosPlan IRVersion="V 1.0" IRDownwCompat="V 1.0"> <IR:GenHead>...</IR:GenHead> ...
        <PositionData>
          <Coordsystem><IR:CoordSysName>local</IR:CoordSysName>
            <IR:TMatrix><IR:Col><IR:x>1</IR:x><IR:y>0</IR:y><IR:z>0</IR:z><IR:w>0</IR:w></IR:Col> (x4)</IR:TMatrix>
            <IR:CsysType>L</IR:CsysType></Coordsystem>
          <PlanIdRef /> <Bearing>0.000</Bearing>
        </PositionData>
      </DrillPosPlan>
      <DrillPlan>
        <NumberOfHoles>2</NumberOfHoles>
        <Hole>
          <HoleId>C01</HoleId> <HoleName>C01</HoleName>
          <StartPoint><IR:PointX>..</IR:PointX><IR:PointY>..</IR:PointY><IR:PointZ>..</IR:PointZ></StartPoint>
          <EndPoint>...</EndPoint>
          <TypeOfHole>Undefined</TypeOfHole> <DrillBitDia>48</DrillBitDia> <MwdOn>1</MwdOn>
          <HoleOptions xmlns:opt="opt"><opt:HoleData><ExtendedHoleStatus>Undrilled</ExtendedHoleStatus>
          </opt:HoleData></HoleOptions>
        </Hole>
        <EquipmentData xmlns=""><IR:OptionData /></EquipmentData>
      </DrillPlan>
      <IR:GenTrailer><IR:FileCloseDate>...</IR:FileCloseDate><IR:ChkSum>1723439548</IR:ChkSum></IR:GenTrailer>
    </DRPPlan>

What the reader takes from it:

- ``Hole`` elements wherever they sit, element names matched with or without a namespace.
  Collar = ``StartPoint``, toe = ``EndPoint``. ``HoleId`` stays text exactly as written (``001``,
  ``10`` and ``9`` are three ids, ``1`` and ``001`` two), and the holes keep the file's order.
- ``TypeOfHole`` -> ``hole_type``: ``Undefined`` (or empty) means no type, ``""``; anything else
  (a name, or the numbers 1-15 some software writes) is kept as text. ``DrillBitDia`` ->
  ``diameter_mm``: ``0`` means "not given" in real files, so it reads as blank (NaN), never as a
  0 mm bit.
- Extra columns, by local name: single-value ``Hole`` children (``HoleName``, ``MwdOn``, ...), the
  columns this writer stores in ``HoleOptions`` (namespace :data:`BIK_NS`), and every other
  single value inside ``HoleOptions`` in whatever namespace (``opt:HoleData/ExtendedHoleStatus``
  -> ``ExtendedHoleStatus``). A vendor field never overwrites a known column or an earlier field:
  a taken name is tried as ``Hole.<name>`` / ``HoleOptions.<name>``, and left out if that is taken too.
- ``DrillPosPlan/.../IR:TMatrix``: the file's local frame, applied before the axis map
  (:mod:`pipeline.plans.iredes_frames`: file point -> TMatrix -> :class:`AxisMap` -> base frame);
  the matrix applied is ``DrillPlan.local_to_plan``. A ``TMatrix`` inside a ``Hole`` is refused
  (a per-hole frame is not read, and must not be dropped silently).
- Everything else (``IR:Project``, ``IR:WorkOrder``, ``PlanIdRef``, ``Bearing``, ``NumberOfHoles``,
  ``EquipmentData`` with ``xmlns=""`` and ``IR:OptionData``) is passed over.

Checksum (``IR:GenTrailer/IR:ChkSum``): a CRC32 of the whole file, verified under either
convention rig software uses (the schema's: the value written as ``0`` while the CRC is taken;
Epiroc's: the value empty), and over the file with its line ends converted when a copy only changed
those (:mod:`pipeline.plans.iredes_checksum`). The plan carries the state, the convention and the
line ends (``DrillPlan.checksum``, ``checksum_convention``, ``checksum_line_ends``); a file that
cannot be verified is refused, read as unverified or not looked at (``checksum="refuse"``, ``"warn"``,
``"ignore"``). The writer uses the schema's convention and writes the value in decimal, as rig
software does (``checksum="hex"``: 8 upper-case hex digits).

Axes: IREDES has no fixed axis convention. Surface-mine files put northing in ``PointX`` and
easting in ``PointY``; the boom base frame is x toward the face, y across, z up. The mapping
is :class:`AxisMap` (``axes``, ``unit``, ``origin``): by default ``PointX -> x``, ``PointY -> y``,
``PointZ -> z`` in metres with the base frame at the file's origin, which is what this writer
writes (no TMatrix), so its files round-trip.

Sources: iredes.org/irdocs/chksum.html and gentrailertype.html (ChkSum and GenTrailer,
IRtypes.xsd); iredes.org/irdocs/planidref2.html and plantorock.html (Drill Rig namespace,
metres); the IREDES import/export of the Kirra blast design app (github.com/brentbuffham/
Kirra2D: ``src/dialog/popups/generic/ExportDialogs.js``, ``src/fileIO/EpirocIO/IREDESParser.js``,
``IREDESWriter.js`` and its notes, which show the element nesting above with CRLF line ends, the
``DrillPosPlan`` with its ``TMatrix`` of four ``Col``, the ``opt`` HoleOptions, the northing-in-PointX
convention and the decimal "Epiroc" vs hexBinary "XSD spec" checksum options); and a stand-alone
C# ``IredesChecksum`` checker that parses the stored value as a decimal ``uint`` and computes the
CRC32 of the UTF-8 file with the value replaced by ``0``.

XML is read with :mod:`xml.parsers.expat` (standard library; it gives the line of every
``<Hole>``, which row-level problems name) in one streaming pass: each ``<Hole>`` (and each
``TMatrix``) becomes a small :mod:`xml.etree.ElementTree` tree, is read and dropped, so memory
follows the holes' values, not a tree of the file; a text node over ``max_text`` characters is
refused. A ``<!DOCTYPE`` is refused at its line: an IREDES file has none, and refusing it means no
entity is ever declared or expanded (the "billion laughs" blow-up) and no external entity or DTD is
read. Written with ElementTree. No third-party XML library is needed: the structure is flat, and
lxml would add a compiled dependency for no gain here.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from xml.etree import ElementTree as ET
from xml.parsers import expat

import numpy as np
import pandas as pd

from pipeline.core.errors import ConfigError, InputError
from pipeline.core.io import atomic_write
from pipeline.plans.iredes_checksum import crc32_text, file_crc32, verify_checksum
from pipeline.plans.iredes_frames import TMATRIX_TOL, AxisMap, apply_local_to_plan, axis_map, local_to_plan
from pipeline.plans.model import (
    COORDS,
    MIN_LENGTH,
    REQUIRED,
    DrillPlan,
    checked_plan,
    infer_column_types,
    plan_frame,
)

# AxisMap and file_crc32 live beside this module; callers and tests import them from here too
__all__ = ["AxisMap", "file_crc32", "iredes_bytes", "read_iredes_plan", "write_iredes_plan"]

log = logging.getLogger(__name__)

IR_NS = "http://www.iredes.org/xml"
DR_NS = "http://www.iredes.org/xml/DrillRig"
BIK_NS = "urn:boom-ik:drill-plan"  # our extra columns, inside HoleOptions
VERSION = "V 1.0"
CHECKSUM_FORMATS = ("decimal", "hex", None)
POINTS = ("StartPoint", "EndPoint")
AXES = ("PointX", "PointY", "PointZ")
LABELS = [f"{p}/{a}" for p in POINTS for a in AXES]
KNOWN = {"HoleId", "TypeOfHole", "DrillBitDia", "HoleOptions", *POINTS}
NO_TYPE = {"", "undefined"}  # TypeOfHole values that mean "no type" (case-insensitive)
NO_DIAMETER = 0.0  # DrillBitDia 0: not given (real files write it so), never a 0 mm bit


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
# Reading

MAX_TEXT = 65_536  # characters in one text node: a coordinate needs 30, a 300 MB node is an attack or a fault
_FEED = 1 << 20  # bytes handed to expat at a time
_TREES = ("Hole", "TMatrix")  # elements built as small trees while streaming


@dataclass
class IredesScan:
    root: str | None = None
    holes: list[tuple[str, list[str], dict[str, str]]] = field(default_factory=list)
    lines: list[int] = field(default_factory=list)
    top: dict[str, str] = field(default_factory=dict)  # PlanId, PlanName (children of the root)
    chksum: list[tuple[int, str]] = field(default_factory=list)
    tmatrix: list[tuple[int, ET.Element]] = field(default_factory=list)


def scan_iredes(data: bytes, source: str, max_text: int) -> IredesScan:
    """One pass of expat over the file: each ``<Hole>`` is built as a small tree, read into its
    fields and dropped, so memory follows the holes' values, not a tree of the whole file; every
    text node longer than ``max_text`` characters is refused with its line, and so is a DOCTYPE."""
    parser = expat.ParserCreate(namespace_separator=" ")
    out = IredesScan()
    stack: list[str] = []
    state = {"builder": None, "kind": None, "depth": 0, "size": 0, "line": 0}
    text: list[str] = []

    def qname(name: str) -> str:
        uri, _, local = name.rpartition(" ")
        return f"{{{uri}}}{local}" if uri else local

    def doctype(name, *_):
        raise InputError(f"{source}: line {parser.CurrentLineNumber}: a <!DOCTYPE {name}> declaration; an IREDES file "
                         "has none, and its entities could expand to gigabytes or read other files: refused")

    def start(name, attrs):
        local = name.rpartition(" ")[2]
        if not stack:
            out.root = local
        stack.append(local)
        state["size"] = 0
        builder = state["builder"]
        if builder is not None and local == "TMatrix":
            raise InputError(f"{source}: line {parser.CurrentLineNumber}: a TMatrix inside a {state['kind']}; only "
                             "the plan's own TMatrix (DrillPosPlan/PositionData/Coordsystem) is read")
        if builder is None and local in _TREES:
            builder = state["builder"] = ET.TreeBuilder()
            state["depth"], state["kind"] = len(stack), local
            state["line"] = parser.CurrentLineNumber
            if local == "Hole":
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
                tree = builder.close()
                if state["kind"] == "Hole":
                    out.holes.append(_hole_fields(tree))
                else:
                    out.tmatrix.append((state["line"], tree))
                state["builder"] = None
        elif local == "ChkSum":
            out.chksum.append((state["line"], "".join(text).strip()))
        elif local in ("PlanId", "PlanName", "PlanIdRef", "PlanNameRef") and len(stack) == 1:  # plan; log
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

    parser.StartDoctypeDeclHandler = doctype
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


def _carry(extra: dict[str, str], name: str, value: str, prefix: str) -> None:
    """Put a vendor field under its name, or ``prefix.name`` when that is taken; never over a known column."""
    for key in (name, f"{prefix}.{name}"):
        if key not in extra and key not in REQUIRED:
            extra[key] = value
            return


def _hole_fields(hole: ET.Element) -> tuple[str, list[str], dict[str, str]]:
    """Id, the six coordinate texts (StartPoint then EndPoint), and every other value."""
    coords = [_text(_child(_child(hole, p), a)) for p in POINTS for a in AXES]
    kind = _text(_child(hole, "TypeOfHole"))
    extra = {"hole_type": "" if kind.lower() in NO_TYPE else kind}
    if _child(hole, "DrillBitDia") is not None:
        dia = _text(_child(hole, "DrillBitDia"))
        extra["diameter_mm"] = "" if _is_number(dia, NO_DIAMETER) else dia
    for c in hole:  # single-value children we do not interpret (HoleName, MwdOn, ...)
        if _local(c.tag) not in KNOWN and len(c) == 0:
            _carry(extra, _local(c.tag), _text(c), "Hole")
    options = _child(hole, "HoleOptions")
    if options is not None:
        ours = [c for c in options if c.tag == f"{{{BIK_NS}}}Column" and c.get("name")]
        for c in ours:  # this writer's columns, under their own names
            _carry(extra, c.get("name"), _text(c), "HoleOptions")
        for c in options.iter():  # other software's single values, in any namespace (opt:HoleData/...)
            if c is not options and len(c) == 0 and c.tag != f"{{{BIK_NS}}}Column":
                _carry(extra, _local(c.tag), _text(c), "HoleOptions")
    return _text(_child(hole, "HoleId")), coords, extra


def _is_number(text: str, value: float) -> bool:
    try:
        return float(text) == value
    except ValueError:
        return False


def read_iredes_file(path: Path, root: str, what: str, checksum: str, max_text: int, tmatrix_tol: float):
    """An IREDES file's holes as streamed (:func:`scan_iredes`), its checksum's verdict and its TMatrix (None
    without one), every check a drill plan and a quality log share: the file there and not empty, the root
    ``root``, the checksum by ``checksum``'s policy, a rigid TMatrix, at least one ``Hole``."""
    if not path.is_file():
        raise InputError(f"{path}: no such {what}")
    data = path.read_bytes()
    if not data.strip():
        raise InputError(f"{path}: empty file; expected an IREDES {root}")
    scan = scan_iredes(data, str(path), max_text)
    if scan.root != root:
        raise InputError(f"{path}: root element is {scan.root!r}, expected {root!r} (an IREDES {what})")
    verdict = verify_checksum(data, str(path), checksum, scan.chksum)
    del data
    M = local_to_plan(scan.tmatrix, str(path), tmatrix_tol)
    if not scan.holes:
        raise InputError(f"{path}: no Hole elements in the {root}")
    return scan, verdict, M


def read_iredes_plan(
    path: str | Path,
    *,
    axes: str | AxisMap = "xyz",
    unit: str = "m",
    origin: Sequence[float] = (0.0, 0.0, 0.0),
    checksum: str = "refuse",
    max_text: int = MAX_TEXT,
    tmatrix_tol: float = TMATRIX_TOL,
    min_length: float = MIN_LENGTH,
) -> DrillPlan:
    """Read an IREDES ``DRPPlan`` into a :class:`DrillPlan` (base frame, metres).

    Row problems (a missing or unreadable point coordinate, an empty or duplicate ``HoleId``,
    ``EndPoint`` equal to ``StartPoint``) are collected with the line of the hole's ``<Hole>``
    tag, as the CSV reader does. ``checksum``: ``"refuse"`` (a file that cannot be verified
    raises), ``"warn"`` (logs it, reads on, the plan says ``checksum = "unverified"``) or
    ``"ignore"``; see :func:`~pipeline.plans.iredes_checksum.verify_checksum`. The file's
    ``TMatrix`` (checked against ``tmatrix_tol``), then axes, unit, origin (:class:`AxisMap`),
    take its points to the base frame (:mod:`pipeline.plans.iredes_frames`).
    """
    path = Path(path)
    amap = axis_map(axes, unit, origin)
    scan, verdict, M = read_iredes_file(path, "DRPPlan", "drill plan", checksum, max_text, tmatrix_tol)
    fields = scan.holes
    coord_text = pd.DataFrame([f[1] for f in fields], columns=LABELS, dtype=object)
    extras = pd.DataFrame([f[2] for f in fields], dtype=object).fillna("")
    extras = pd.concat([extras[["hole_type"]], infer_column_types(extras.drop(columns="hole_type"))], axis=1)
    if "diameter_mm" in extras and extras["diameter_mm"].eq("").all():  # every DrillBitDia 0 or empty: unknown
        extras["diameter_mm"] = np.nan
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
        to_base=lambda points: amap.to_base(apply_local_to_plan(M, points)),
        id_label="HoleId",
        length_label="EndPoint",
        min_length=min_length,
    )
    plan.checksum, plan.checksum_detail = verdict.state, verdict.detail
    plan.checksum_convention, plan.checksum_line_ends = verdict.convention, verdict.line_ends
    plan.local_to_plan = M
    return plan


# ---------------------------------------------------------------------------------------------
# Writing


def _num(value: float) -> str:
    """Shortest text that reads back to the same float, without an exponent (rig software)."""
    return np.format_float_positional(float(value) + 0.0, unique=True, trim="-")


def add_element(parent: ET.Element, ns: str, tag: str, text: str | None = None, **attrib) -> ET.Element:
    # Drill Rig elements go unqualified under the root's default namespace, as in real files
    # (ElementTree's default_namespace option refuses the unqualified attributes they carry).
    el = ET.SubElement(parent, tag if ns == DR_NS else f"{{{ns}}}{tag}", attrib)
    if text is not None:
        el.text = text
    return el


def new_document(kind: str, stamp: str) -> ET.Element:
    """The root of an IREDES Drill Rig document ``kind`` (``DRPPlan``, ``DRPQual``) with its versions and
    ``GenHead`` (created ``stamp``), as plans and quality logs both begin."""
    versions = ("IRVersion", "IRDownwCompat", f"{kind}Version", f"{kind}DownwCompat")
    root = ET.Element(kind, {"xmlns": DR_NS, **dict.fromkeys(versions, VERSION)})
    head = add_element(root, IR_NS, "GenHead")
    add_element(head, IR_NS, "FileCreateDate", stamp)
    add_element(head, IR_NS, "IRversion", VERSION, DownwCompat=VERSION)
    return root


def add_point(parent: ET.Element, name: str, xyz: np.ndarray) -> None:
    pt = add_element(parent, DR_NS, name)
    for axis, v in zip(AXES, xyz, strict=True):
        add_element(pt, IR_NS, axis, _num(v))


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
    amap = axis_map(axes, unit, origin)
    holes = plan_frame(plan)
    meta = plan if isinstance(plan, DrillPlan) else None
    plan_id = plan_id or (meta.plan_id if meta else "") or "plan"
    plan_name = plan_name or (meta.name if meta else "") or plan_id
    stamp = created or datetime.now(UTC).replace(tzinfo=None, microsecond=0)
    stamp = stamp.isoformat() if isinstance(stamp, datetime) else str(stamp)

    root = new_document("DRPPlan", stamp)
    add_element(root, IR_NS, "PlanId", plan_id)
    add_element(root, IR_NS, "PlanName", plan_name)
    add_element(root, IR_NS, "Comment",
                f"boom-ik drill plan; axes={amap.axes} unit={amap.unit} origin={list(amap.origin)}")
    body = add_element(root, DR_NS, "DrillPlan")
    add_element(body, DR_NS, "NumberOfHoles", str(len(holes)))
    points = amap.from_base(holes[COORDS].to_numpy(dtype=np.float64))
    extra_cols = [c for c in holes.columns if c not in (*REQUIRED, "hole_type", "diameter_mm")]
    records = holes.to_dict("records")
    for row, pts in zip(records, points, strict=True):
        hole = add_element(body, DR_NS, "Hole")
        add_element(hole, DR_NS, "HoleId", str(row["hole_id"]))
        add_point(hole, "StartPoint", pts[:3])
        add_point(hole, "EndPoint", pts[3:])
        kind = row.get("hole_type")
        add_element(hole, DR_NS, "TypeOfHole", "Undefined" if _is_blank(kind) or kind == "" else str(kind))
        if not _is_blank(row.get("diameter_mm")):
            add_element(hole, DR_NS, "DrillBitDia", str(row["diameter_mm"]))
        values = [(c, row[c]) for c in extra_cols if not _is_blank(row[c])]
        if values:
            options = add_element(hole, DR_NS, "HoleOptions")
            for c, v in values:
                add_element(options, BIK_NS, "Column", _num(v) if isinstance(v, float) else str(v), name=str(c))
    if checksum is not None:
        trailer = add_element(root, IR_NS, "GenTrailer")
        add_element(trailer, IR_NS, "FileCloseDate", stamp)
        add_element(trailer, IR_NS, "ChkSum", "0")  # the placeholder the CRC is taken over
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
