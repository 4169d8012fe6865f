"""A DRPPlan written the way vendor software writes it (Epiroc's office tools, Kirra's Epiroc export),
independently of pipeline/plans/iredes.py: for tests of the reader and of anything that reads rig plans.

``vendor_drpplan(path, holes_local, ids, tmatrix)`` writes CRLF lines, a ``DrillPosPlan`` whose
``IR:TMatrix`` holds ``tmatrix``'s columns, ``HoleName``, ``TypeOfHole Undefined``, ``DrillBitDia 0``,
``MwdOn``, ``xmlns:opt="opt"`` HoleOptions with ``ExtendedHoleStatus``, ``EquipmentData xmlns=""``, and
a ChkSum computed here with :func:`binascii.crc32` under either convention (``"empty-value"``: the
CRC of the file with the value empty, as Epiroc's software does; ``"documented"``: with the value
``0``). Numbers are written with ``repr`` by default, so they read back to the same floats.
"""

from __future__ import annotations

import binascii
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

PLACEHOLDER = {"documented": "0", "empty-value": ""}


def crc32_of(data: bytes) -> int:
    """The CRC32 (IEEE, as zlib) of the bytes, unsigned."""
    return binascii.crc32(data) & 0xFFFFFFFF


def _tmatrix_lines(M: np.ndarray, number: Callable[[float], str]) -> list[str]:
    lines = ["        <IR:TMatrix>"]
    for j in range(4):  # IREDES writes the matrix column by column
        lines.append("          <IR:Col>")
        lines += [f"            <IR:{a}>{number(M[i, j])}</IR:{a}>" for i, a in enumerate("xyzw")]
        lines.append("          </IR:Col>")
    return [*lines, "        </IR:TMatrix>"]


def vendor_drpplan(
    path: str | Path | None,
    holes_local: np.ndarray,
    ids: Sequence[str],
    tmatrix: np.ndarray | None = None,
    *,
    convention: str = "empty-value",
    line_end: str = "\r\n",
    number: Callable[[float], str] = lambda v: repr(float(v)),
    diameter: str | Sequence[str] = "0",
    type_of_hole: str | Sequence[str] = "Undefined",
    hole_names: Sequence[str] | None = None,
    mwd: str = "1",
    status: Sequence[str] | None = None,
    hole_data: Sequence[str] = (),
    plan_id: str = "R612",
    checksum_format: str = "decimal",
) -> bytes:
    """Write (``path`` None: only return) the file's bytes. ``holes_local``: ``(n, 6)`` collar then toe
    per hole, in the TMatrix's local frame, in the file's PointX/Y/Z order; ``tmatrix``: 4x4, its
    columns written as ``IR:Col`` (None: no TMatrix element). ``diameter``, ``type_of_hole``: one text for
    every hole or one per hole; ``hole_data``: more XML lines inside every hole's ``opt:HoleData``."""
    holes_local = np.asarray(holes_local, dtype=np.float64)
    assert holes_local.shape == (len(ids), 6)
    names = list(ids) if hole_names is None else list(hole_names)
    status = ["Undrilled"] * len(ids) if status is None else list(status)
    dias = [diameter] * len(ids) if isinstance(diameter, str) else list(diameter)
    kinds = [type_of_hole] * len(ids) if isinstance(type_of_hole, str) else list(type_of_hole)
    head = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        "<!-- written by tests/vendor_iredes.py as vendor drill-plan software writes it -->",
        '<DRPPlan xmlns:IR="http://www.iredes.org/xml" IRVersion="V 1.0" IRDownwCompat="V 1.0" '
        'DRPPlanDownwCompat="V 1.0" DRPPlanVersion="V 1.0" xmlns="http://www.iredes.org/xml/DrillRig">',
        "  <IR:GenHead>",
        "    <IR:FileCreateDate>2025-03-04T05:06:07</IR:FileCreateDate>",
        '    <IR:IRversion DownwCompat="V 1.0">V 1.0</IR:IRversion>',
        "  </IR:GenHead>",
        f"  <IR:PlanId>{plan_id}</IR:PlanId>",
        f"  <IR:PlanName>{plan_id}</IR:PlanName>",
        "  <IR:Comment>Notes</IR:Comment>",
        "  <IR:Project>Mine(Site)</IR:Project>",
        "  <IR:WorkOrder>Mine(WorkOrder)</IR:WorkOrder>",
        '  <DrillPosPlan IRVersion="V 1.0" IRDownwCompat="V 1.0">',
        "    <IR:GenHead>",
        "      <IR:FileCreateDate>2025-03-04T05:06:07</IR:FileCreateDate>",
        '      <IR:IRversion DownwCompat="V 1.0">V 1.0</IR:IRversion>',
        "    </IR:GenHead>",
        f"    <IR:PlanId>{plan_id}</IR:PlanId>",
        f"    <IR:PlanName>{plan_id}</IR:PlanName>",
        "    <PositionData>",
        "      <Coordsystem>",
        "        <IR:CoordSysName>local</IR:CoordSysName>",
        *([] if tmatrix is None else _tmatrix_lines(np.asarray(tmatrix, dtype=np.float64), number)),
        "        <IR:CsysType>L</IR:CsysType>",
        "      </Coordsystem>",
        "      <PlanIdRef />",
        "      <Bearing>0.000</Bearing>",
        "    </PositionData>",
        "  </DrillPosPlan>",
        "  <DrillPlan>",
        f"  <NumberOfHoles>{len(ids)}</NumberOfHoles>",
    ]
    body = []
    for hid, name, st, dia, kind, h in zip(ids, names, status, dias, kinds, holes_local, strict=True):
        body += [
            "    <Hole>",
            f"      <HoleId>{hid}</HoleId>",
            f"      <HoleName>{name}</HoleName>",
            "      <StartPoint>",
            *[f"        <IR:Point{a}>{number(v)}</IR:Point{a}>" for a, v in zip("XYZ", h[:3], strict=True)],
            "      </StartPoint>",
            "      <EndPoint>",
            *[f"        <IR:Point{a}>{number(v)}</IR:Point{a}>" for a, v in zip("XYZ", h[3:], strict=True)],
            "      </EndPoint>",
            f"      <TypeOfHole>{kind}</TypeOfHole>",
            f"      <DrillBitDia>{dia}</DrillBitDia>",
            f"      <MwdOn>{mwd}</MwdOn>",
            '      <HoleOptions xmlns:opt="opt">',
            "        <opt:HoleData>",
            f"          <ExtendedHoleStatus>{st}</ExtendedHoleStatus>",
            *[f"          {line}" for line in hole_data],
            "        </opt:HoleData>",
            "      </HoleOptions>",
            "    </Hole>",
        ]
    tail = [
        '    <EquipmentData xmlns="">',
        "      <IR:OptionData />",
        "    </EquipmentData>",
        "  </DrillPlan>",
        "  <IR:GenTrailer>",
        "    <IR:FileCloseDate>2025-03-04T05:06:07</IR:FileCloseDate>",
        f"    <IR:ChkSum>{PLACEHOLDER[convention]}</IR:ChkSum>",
        "  </IR:GenTrailer>",
        "</DRPPlan>",
    ]
    data = line_end.join(head + body + tail).encode("utf-8")
    crc = crc32_of(data)  # with the convention's placeholder in place
    value = str(crc) if checksum_format == "decimal" else f"{crc:08X}"
    placeholder = f"<IR:ChkSum>{PLACEHOLDER[convention]}</IR:ChkSum>".encode()
    assert data.count(placeholder) == 1
    data = data.replace(placeholder, f"<IR:ChkSum>{value}</IR:ChkSum>".encode())
    if path is not None:
        Path(path).write_bytes(data)
    return data


def rotation_z(deg: float) -> np.ndarray:
    t = np.radians(deg)
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def placement(deg: float, shift: Sequence[float]) -> np.ndarray:
    """4x4: a turn of ``deg`` about z, then a shift (a local plan placed in mine coordinates)."""
    M = np.eye(4)
    M[:3, :3] = rotation_z(deg)
    M[:3, 3] = shift
    return M


def text_sorted_ids(n: int) -> list[str]:
    """``n`` distinct ids that a reader taking them as numbers, or sorting them, would get wrong:
    ``"001"`` and ``"1"`` (equal as numbers), ``"9"`` before ``"10"``, ``"H001"``; the first seven
    in every list, in an order that is not the text order."""
    first = ["9", "10", "001", "1", "H001", "010", "H2"]
    rest = [v for i in range(2, 400) for v in (str(i), f"{i:03d}", f"H{i:03d}")]
    pool = list(dict.fromkeys(first + rest))  # from 100 on, str(i) is f"{i:03d}"
    assert len(pool) >= n
    return pool[:n]
