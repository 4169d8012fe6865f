"""IREDES quality logs (``DRPQual``): what a rig drilled, hole by hole, read back against its plan.

A rig reports what it drilled in a quality log (docs/reference.md, "The as-drilled log")::

    <DRPQual xmlns="http://www.iredes.org/xml/DrillRig" xmlns:IR="http://www.iredes.org/xml" ...>
      <IR:GenHead>...</IR:GenHead>
      <IR:PlanIdRef>demo_face</IR:PlanIdRef> <IR:PlanNameRef>...</IR:PlanNameRef>
      <HoleQualityData>
        <Hole>
          <HoleId>C01</HoleId> <HoleName>C01</HoleName>
          <StartPoint><IR:PointX>..</IR:PointX>...</StartPoint>  <EndPoint>...</EndPoint>   (plan frame, m)
          <StartHoleTime>2026-01-01T07:00:10</StartHoleTime> <EndHoleTime>...</EndHoleTime>
          <Hstatus>Drilled</Hstatus> <EqpType>L</EqpType>
        </Hole>
      </HoleQualityData>
      ...
      <IR:GenTrailer><IR:FileCloseDate>...</IR:FileCloseDate><IR:ChkSum>...</IR:ChkSum></IR:GenTrailer>
    </DRPQual>

The writer writes one ``HoleQualityData`` per hole the round started and the documented checksum (the CRC32
with the value ``0``). The reader takes what vendors write: either checksum convention (and a copy whose only
change is its line ends), a missing ``HoleName`` (some write ``HoleId`` only), points local to an
``IR:TMatrix``, ``Hole`` elements wherever they are nested; it streams the file with the drill plan's parser
(:mod:`pipeline.plans.iredes`: no DTD, no entity, no text node over ``max_text``). A hole with no id or an
unreadable point is a row problem naming its line; a hole logged twice keeps its last entry (a re-drilled
hole: the rock holds the last one) and says so.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np
import pandas as pd

from pipeline.core.errors import InputError
from pipeline.core.io import atomic_write
from pipeline.plans.iredes import DR_NS, IR_NS, LABELS, MAX_TEXT, add_element, add_point, new_document, read_iredes_file
from pipeline.plans.iredes_checksum import crc32_text, file_crc32
from pipeline.plans.iredes_frames import TMATRIX_TOL, apply_local_to_plan, axis_map
from pipeline.plans.model import COORDS, RowProblem

STATUSES = ("Drilled", "Interrupted")  # Hstatus as the execute stage writes it; readers keep any other word
LOG_COLUMNS = ["hole_id", "hole_name", "boom", "status", *COORDS, "start_time", "end_time"]


@dataclass
class QualityLog:
    """The holes of a quality log (``LOG_COLUMNS``; points in the plan frame, m), where it came from and what
    could not be read."""

    holes: pd.DataFrame
    plan_id: str = ""
    plan_name: str = ""
    source: str = ""
    problems: list[RowProblem] = field(default_factory=list)
    lines: np.ndarray | None = None
    checksum: str = "not applicable"
    checksum_detail: str = ""
    checksum_convention: str | None = None
    checksum_line_ends: str | None = None
    local_to_plan: np.ndarray | None = None

    def provenance(self) -> dict:
        M = self.local_to_plan
        return {"log": self.source, "log_plan_id": self.plan_id, "log_checksum": self.checksum,
                "log_checksum_detail": self.checksum_detail, "log_checksum_convention": self.checksum_convention,
                "log_checksum_line_ends": self.checksum_line_ends,
                "log_local_to_plan": None if M is None else np.asarray(M, dtype=float).tolist()}


def read_quality_log(path: str | Path, *, axes: str = "xyz", unit: str = "m", origin: Sequence[float] = (0, 0, 0),
                     checksum: str = "refuse", max_text: int = MAX_TEXT, tmatrix_tol: float = TMATRIX_TOL,
                     max_mb: float = 256.0) -> QualityLog:
    """Read a ``DRPQual`` (module docstring); ``axes``, ``unit``, ``origin``, ``checksum``, ``max_text`` and
    ``tmatrix_tol`` as for a drill plan (``solve.iredes``), so a log and its plan are read alike."""
    path = Path(path)
    if path.is_file() and path.stat().st_size > max_mb * 1e6:
        raise InputError(f"{path}: {path.stat().st_size / 1e6:.1f} MB, over {max_mb:g} MB for a quality log")
    scan, verdict, M = read_iredes_file(path, "DRPQual", "quality log", checksum, max_text, tmatrix_tol)
    amap = axis_map(axes, unit, origin)
    ids = [f[0].strip() for f in scan.holes]
    text = pd.DataFrame([f[1] for f in scan.holes], columns=LABELS, dtype=object)
    values = text.apply(lambda c: pd.to_numeric(c.str.strip(), errors="coerce")).to_numpy(dtype=np.float64)
    extra = pd.DataFrame([f[2] for f in scan.holes], dtype=object)
    lines = np.asarray(scan.lines)
    problems, keep = [], np.isfinite(values).all(axis=1) & np.array([bool(i) for i in ids])
    for i in np.flatnonzero(~keep):
        bad = [LABELS[j] for j in np.flatnonzero(~np.isfinite(values[i]))] or ["HoleId"]
        problems.append(RowProblem(int(lines[i]), ids[i], bad[0], "missing or unreadable" + (
            f" {', '.join(bad)}" if ids[i] else " HoleId")))
    seen: dict[str, int] = {}
    for i in np.flatnonzero(keep):
        if ids[i] in seen:  # a re-drilled hole: the later entry is what the rock holds
            j = seen[ids[i]]
            keep[j] = False
            problems.append(RowProblem(int(lines[j]), ids[i], "HoleId", f"logged again at line {lines[i]}; the "
                                       "later entry is kept"))
        seen[ids[i]] = i
    if not keep.any():
        raise InputError(f"{path}: no readable hole: " + "; ".join(p.describe() for p in problems[:10]))

    def column(name: str) -> pd.Series:
        return extra[name].fillna("").astype(str).str.strip() if name in extra else pd.Series([""] * len(ids))

    names = column("HoleName")
    holes = pd.DataFrame({"hole_id": ids, "hole_name": names.where(names != "", pd.Series(ids)),
                          "boom": column("EqpType"), "status": column("Hstatus")})
    holes[COORDS] = amap.to_base(apply_local_to_plan(M, values))
    holes["start_time"], holes["end_time"] = column("StartHoleTime"), column("EndHoleTime")
    log = QualityLog(holes[keep].reset_index(drop=True)[LOG_COLUMNS], scan.top.get("PlanIdRef", ""),
                     scan.top.get("PlanNameRef", ""), str(path), sorted(problems, key=lambda p: p.row), lines[keep])
    log.checksum, log.checksum_detail = verdict.state, verdict.detail
    log.checksum_convention, log.checksum_line_ends = verdict.convention, verdict.line_ends
    log.local_to_plan = M
    return log


def quality_log_bytes(holes: pd.DataFrame, *, plan_id: str, plan_name: str, created: datetime | str) -> bytes:
    """The ``DRPQual`` of ``holes`` (``LOG_COLUMNS``; plan frame, m; times as ISO 8601 text), UTF-8, with the
    documented checksum."""
    missing = [c for c in LOG_COLUMNS if c not in holes.columns]
    if missing:
        raise InputError(f"quality log: missing column(s) {missing}")
    stamp = created.isoformat() if isinstance(created, datetime) else str(created)
    root = new_document("DRPQual", stamp)
    add_element(root, IR_NS, "PlanIdRef", plan_id)
    add_element(root, IR_NS, "PlanNameRef", plan_name)
    points = holes[COORDS].to_numpy(dtype=np.float64)
    for row, pts in zip(holes.to_dict("records"), points, strict=True):
        hole = add_element(add_element(root, DR_NS, "HoleQualityData"), DR_NS, "Hole")
        add_element(hole, DR_NS, "HoleId", str(row["hole_id"]))
        add_element(hole, DR_NS, "HoleName", str(row["hole_name"]))
        add_point(hole, "StartPoint", pts[:3])
        add_point(hole, "EndPoint", pts[3:])
        add_element(hole, DR_NS, "StartHoleTime", str(row["start_time"]))
        add_element(hole, DR_NS, "EndHoleTime", str(row["end_time"]))
        add_element(hole, DR_NS, "Hstatus", str(row["status"]))
        add_element(hole, DR_NS, "EqpType", str(row["boom"]))
    trailer = add_element(root, IR_NS, "GenTrailer")
    add_element(trailer, IR_NS, "FileCloseDate", stamp)
    add_element(trailer, IR_NS, "ChkSum", "0")  # the placeholder the CRC is taken over (the documented convention)
    ET.register_namespace("IR", IR_NS)
    ET.indent(root, space="  ")
    data = ('<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n").encode("utf-8")
    crc, _ = file_crc32(data)
    return data.replace(b"<IR:ChkSum>0</IR:ChkSum>", f"<IR:ChkSum>{crc32_text(crc)}</IR:ChkSum>".encode())


def write_quality_log(holes: pd.DataFrame, path: str | Path, **kw) -> None:
    """Write a quality log atomically; ``kw`` as :func:`quality_log_bytes`."""
    data = quality_log_bytes(holes, **kw)
    atomic_write(path, lambda tmp: Path(tmp).write_bytes(data))

