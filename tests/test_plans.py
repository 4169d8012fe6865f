"""Drill plans: CSV and IREDES readers, row-level problems, checksums, the demo face, hole poses."""

import logging
import math
import re
import zlib

import numpy as np
import pandas as pd
import pytest
import torch

from pipeline.core.errors import ConfigError, InputError
from pipeline.plans.csv_plan import read_csv_plan, write_csv_plan
from pipeline.plans.demo_face import demo_face, plan_clearances
from pipeline.plans.iredes import AxisMap, file_crc32, iredes_bytes, read_iredes_plan, write_iredes_plan
from pipeline.plans.model import COLLAR, COORDS, HOLE_TYPES, TOE, DrillPlan, hole_poses
from pipeline.plans.read import read_plan

HEADER = "hole_id,collar_x,collar_y,collar_z,toe_x,toe_y,toe_z,hole_type"
STAMP = "2025-01-01T00:00:00"


@pytest.fixture(scope="module")
def demo(safety):
    return demo_face(safety=safety)


def _same_holes(a: pd.DataFrame, b: pd.DataFrame, tol: float = 1e-9):
    assert a["hole_id"].tolist() == b["hole_id"].tolist()
    np.testing.assert_allclose(b[COORDS].to_numpy(), a[COORDS].to_numpy(), rtol=0, atol=tol)
    assert a["hole_type"].tolist() == b["hole_type"].tolist()


# --- CSV and IREDES give the same holes --------------------------------------------------------


def test_csv_and_iredes_readers_give_the_same_holes(demo, tmp_path):
    write_csv_plan(demo, tmp_path / "face.csv")
    write_iredes_plan(demo, tmp_path / "face.xml", created=STAMP)
    csv, xml = read_plan(tmp_path / "face.csv"), read_plan(tmp_path / "face.xml")
    assert (csv.format, xml.format) == ("csv", "iredes") and not csv.problems and not xml.problems
    _same_holes(csv.holes, xml.holes, tol=0.0)
    assert xml.holes["diameter_mm"].tolist() == csv.holes["diameter_mm"].tolist()
    assert xml.plan_id == "demo_face" and xml.name == demo.name


@pytest.mark.parametrize("axes, unit, origin", [("xyz", "m", (0, 0, 0)), ("yxz", "mm", (1000.0, 500_000.0, 250.0))])
def test_round_trip_csv_iredes_csv(demo, tmp_path, axes, unit, origin):
    df = demo.holes.assign(note=[f"n{k}" for k in range(len(demo))], burden=0.7)
    write_csv_plan(df, tmp_path / "a.csv")
    a = read_csv_plan(tmp_path / "a.csv")
    write_iredes_plan(a, tmp_path / "a.xml", axes=axes, unit=unit, origin=origin, created=STAMP)
    b = read_iredes_plan(tmp_path / "a.xml", axes=axes, unit=unit, origin=origin)
    _same_holes(a.holes, b.holes)
    assert b.holes["note"].tolist() == a.holes["note"].tolist() and (b.holes["burden"] == 0.7).all()
    write_csv_plan(b, tmp_path / "b.csv")
    _same_holes(a.holes, read_csv_plan(tmp_path / "b.csv").holes)


def test_axis_convention_puts_northing_in_point_x(tmp_path):
    plan = pd.DataFrame([["N1", 6.5, 1.25, 1.5, 10.0, 1.5, 1.75]], columns=["hole_id", *COORDS])
    text = iredes_bytes(plan, axes="yxz", unit="mm", created=STAMP).decode()
    start = re.search(r"<StartPoint>(.*?)</StartPoint>", text, re.S).group(1)
    assert re.findall(r"<IR:Point[XYZ]>([^<]+)<", start) == ["1250", "6500", "1500"]  # y, x, z in mm
    assert np.allclose(AxisMap("x-yz").to_base(np.array([1.0, 2.0, 3.0])), [1.0, -2.0, 3.0])
    with pytest.raises(ConfigError, match=r"iredes.axes = 'xxz'"):
        AxisMap("xxz")
    with pytest.raises(ConfigError, match=r"iredes.unit = 'ft'"):
        AxisMap(unit="ft")


# --- checksum ---------------------------------------------------------------------------------


def test_checksum_is_the_crc32_of_the_file_with_chksum_zero(demo, tmp_path):
    path = tmp_path / "face.xml"
    write_iredes_plan(demo, path, created=STAMP)
    data = path.read_bytes()
    stored = re.search(rb"<IR:ChkSum>(\d+)</IR:ChkSum>", data).group(1)
    assert int(stored) == zlib.crc32(data.replace(b"<IR:ChkSum>" + stored + b"<", b"<IR:ChkSum>0<"))
    assert file_crc32(data) == (int(stored), stored.decode())
    assert len(read_iredes_plan(path)) == len(demo)
    write_iredes_plan(demo, path, created=STAMP, checksum="hex")  # the XSD's hexBinary spelling
    assert re.search(rb"<IR:ChkSum>[0-9A-F]{8}</IR:ChkSum>", path.read_bytes())
    assert len(read_iredes_plan(path)) == len(demo)


def _tamper(path):
    """Change one digit of the first hole's StartPoint/PointY; keep the old checksum."""
    data = path.read_bytes()
    m = re.search(rb"<IR:PointY>(-?\d+\.\d*?)([0-8])", data)
    return data[: m.start(2)] + bytes([m.group(2)[0] + 1]) + data[m.end(2) :]


def test_tampered_file_fails_the_checksum(demo, tmp_path, caplog):
    path = tmp_path / "face.xml"
    write_iredes_plan(demo, path, created=STAMP)
    stored = re.search(rb"<IR:ChkSum>(\d+)<", path.read_bytes()).group(1).decode()
    path.write_bytes(_tamper(path))
    crc, _ = file_crc32(path.read_bytes())
    with pytest.raises(InputError, match=rf"face.xml: IREDES checksum mismatch: .*'{stored}'.* {crc} "):
        read_iredes_plan(path)
    with caplog.at_level(logging.WARNING, logger="pipeline.plans.iredes"):
        plan = read_iredes_plan(path, checksum="warn")
    assert "checksum mismatch" in caplog.text and len(plan) == len(demo)
    assert plan.holes["collar_y"].iloc[0] != demo.holes["collar_y"].iloc[0]  # the tampered value is read


# --- bad files and bad rows -------------------------------------------------------------------


def test_missing_column_names_file_missing_and_found(tmp_path):
    path = tmp_path / "p.csv"
    path.write_text("hole_id,collar_x,collar_y,collar_z,toe_x,toe_y\nA,6.5,0,1.5,10,0\n")
    with pytest.raises(InputError, match=r"p.csv: missing column\(s\) \['toe_z'\]; found \['hole_id', .*'toe_y'\]"):
        read_csv_plan(path)


@pytest.mark.parametrize("text, match", [("", "empty file"), (HEADER + "\n", "no holes"),
                                         (HEADER + "\nA,6.5,x,1,10,0,1,cut\n", "no usable hole.*'x'")])
def test_empty_or_all_bad_file_is_an_input_error(tmp_path, text, match):
    (tmp_path / "p.csv").write_text(text)
    with pytest.raises(InputError, match=rf"p.csv: {match}"):
        read_csv_plan(tmp_path / "p.csv")


def test_csv_row_problems_are_named_and_good_rows_kept(tmp_path):
    rows = [
        "A1,6.5,0.1,1.5,10,0.1,1.5,stoping",
        "A2,6.5,abc,1.5,10,0.1,1.5,stoping",  # line 3
        "",
        "A3,6.5,0.2,inf,10,0.2,1.5,stoping",  # line 5
        ",6.5,0.3,1.5,10,0.3,1.5,stoping",
        "A1,6.5,0.4,1.5,10,0.4,1.5,stoping",
        "A5,6.5,0.5,1.5,6.5,0.5,1.5,stoping",
        "A6,6.5,0.6,,10,0.6,1.5,",
        "007,6.5,-0.6,1.5,10,-0.6,1.5,cut",
    ]
    (tmp_path / "p.csv").write_text("\n".join([HEADER, *rows]) + "\n")
    plan = read_csv_plan(tmp_path / "p.csv")
    assert plan.holes["hole_id"].tolist() == ["A1", "007"]  # ids stay strings
    got = [(p.row, p.hole_id, p.column) for p in plan.problems]
    assert got == [(3, "A2", "collar_y"), (5, "A3", "collar_z"), (6, "", "hole_id"), (7, "A1", "hole_id"),
                   (8, "A5", "toe"), (9, "A6", "collar_z")]
    report = "\n".join(plan.report())
    for piece in ["row 3, hole 'A2', column 'collar_y': non-numeric value 'abc'", "non-finite value 'inf'",
                  "empty hole id", "duplicate hole id 'A1' (first at row 2)", "zero-length hole", "missing value"]:
        assert piece in report
    assert report.startswith(str(tmp_path / "p.csv"))
    assert list(plan.problems_frame().columns) == ["row", "hole_id", "column", "message"]
    assert hole_poses(plan, 3.3).shape == (2, 6)


def _hole(hid, start, end, kind="stoping"):
    pt = "".join(f"<IR:Point{a}>{v}</IR:Point{a}>" for a, v in zip("XYZ", start, strict=True))
    ept = "" if end is None else "<EndPoint>" + "".join(
        f"<IR:Point{a}>{v}</IR:Point{a}>" for a, v in zip("XYZ", end, strict=True)) + "</EndPoint>"
    return f"    <Hole><HoleId>{hid}</HoleId><StartPoint>{pt}</StartPoint>{ept}<TypeOfHole>{kind}</TypeOfHole></Hole>"


def _iredes(holes):
    return "\n".join([
        '<?xml version="1.0" encoding="UTF-8"?>',
        '<DRPPlan xmlns="http://www.iredes.org/xml/DrillRig" xmlns:IR="http://www.iredes.org/xml" IRVersion="V 1.0">',
        "  <IR:PlanId>P7</IR:PlanId><IR:PlanName>Face 7</IR:PlanName>",
        "  <DrillPlan>", *holes, "  </DrillPlan>",
        "</DRPPlan>", ""])


def test_iredes_row_problems_name_the_hole_line(tmp_path):
    holes = [
        _hole("H1", (6.5, 0.1, 1.5), (10, 0.1, 1.5)),  # line 5
        _hole("H2", (6.5, "1,5", 1.5), (10, 0.1, 1.5)),
        _hole("H3", (6.5, 0.3, 1.5), None),
        _hole("H1", (6.5, 0.4, 1.5), (10, 0.4, 1.5)),
        _hole("H5", (6.5, 0.5, 1.5), (6.5, 0.5, 1.5)),
        _hole("H6", (6.5, -0.5, "nan"), (10, -0.5, 1.5), kind="cut"),
        _hole("H7", (6.5, -0.6, 1.5), (10, -0.6, 1.5), kind="cut"),
    ]
    (tmp_path / "p.xml").write_text(_iredes(holes))
    plan = read_iredes_plan(tmp_path / "p.xml", checksum="warn")  # no trailer: unverified
    assert plan.checksum == "unverified"
    assert plan.holes["hole_id"].tolist() == ["H1", "H7"] and plan.holes["hole_type"].tolist() == ["stoping", "cut"]
    assert (plan.plan_id, plan.name) == ("P7", "Face 7")
    got = [(p.row, p.hole_id, p.column) for p in plan.problems]
    assert got == [(6, "H2", "StartPoint/PointY"), (7, "H3", "EndPoint/PointX"), (7, "H3", "EndPoint/PointY"),
                   (7, "H3", "EndPoint/PointZ"), (8, "H1", "HoleId"), (9, "H5", "EndPoint"),
                   (10, "H6", "StartPoint/PointZ")]
    assert "non-numeric value '1,5'" in plan.problems[0].message and "non-finite" in plan.problems[-1].message


def test_malformed_xml_names_file_and_line(tmp_path):
    text = _iredes([_hole("H1", (6.5, 0.1, 1.5), (10, 0.1, 1.5))]).replace("</DrillPlan>", "</DrillPlam>")
    (tmp_path / "p.xml").write_text(text)
    with pytest.raises(InputError, match=r"p.xml: malformed XML at line 6, column \d+: mismatched tag"):
        read_iredes_plan(tmp_path / "p.xml")
    (tmp_path / "q.xml").write_text('<?xml version="1.0"?>\n<Plan/>\n')
    with pytest.raises(InputError, match=r"q.xml: root element is 'Plan', expected 'DRPPlan'"):
        read_iredes_plan(tmp_path / "q.xml")


def test_reads_a_rig_style_file(tmp_path):
    """Nesting and extras as rig software writes them: DrillPosPlan, HoleName, MwdOn, HoleOptions,
    northing in PointX (read with axes='yxz' and the base frame's origin given in mine coordinates)."""
    text = "\r\n".join([
        '<?xml version="1.0" encoding="UTF-8"?>',
        '<DRPPlan xmlns:IR="http://www.iredes.org/xml" IRVersion="V 1.0" IRDownwCompat="V 1.0" '
        'DRPPlanDownwCompat="V 1.0" DRPPlanVersion="V 1.0" xmlns="http://www.iredes.org/xml/DrillRig">',
        "  <IR:GenHead><IR:FileCreateDate>2025-01-01T00:00:00</IR:FileCreateDate></IR:GenHead>",
        "  <IR:PlanId>R12</IR:PlanId><IR:PlanName>Round 12</IR:PlanName>",
        "  <DrillPosPlan IRVersion=\"V 1.0\" IRDownwCompat=\"V 1.0\"><PositionData><Bearing>0.000</Bearing>"
        "</PositionData></DrillPosPlan>",
        "  <DrillPlan><NumberOfHoles>1</NumberOfHoles>",
        "    <Hole><HoleId>1</HoleId><HoleName>R12-1</HoleName>",
        "      <StartPoint><IR:PointX>7000100.250</IR:PointX><IR:PointY>480006.500</IR:PointY>"
        "<IR:PointZ>101.500</IR:PointZ></StartPoint>",
        "      <EndPoint><IR:PointX>7000100.250</IR:PointX><IR:PointY>480010.000</IR:PointY>"
        "<IR:PointZ>101.500</IR:PointZ></EndPoint>",
        "      <TypeOfHole>Undefined</TypeOfHole><DrillBitDia>48</DrillBitDia><MwdOn>1</MwdOn>",
        '      <HoleOptions xmlns:opt="opt"><opt:HoleData><ExtendedHoleStatus>Undrilled</ExtendedHoleStatus>'
        "</opt:HoleData></HoleOptions></Hole>",
        '    <EquipmentData xmlns=""><IR:OptionData /></EquipmentData>',
        "  </DrillPlan>",
        "  <IR:GenTrailer><IR:FileCloseDate>2025-01-01T00:00:00</IR:FileCloseDate><IR:ChkSum>0</IR:ChkSum>"
        "</IR:GenTrailer>",
        "</DRPPlan>",
    ])
    data = text.encode()
    crc, _ = file_crc32(data)
    (tmp_path / "rig.xml").write_bytes(data.replace(b"<IR:ChkSum>0<", f"<IR:ChkSum>{crc}<".encode()))
    plan = read_iredes_plan(tmp_path / "rig.xml", axes="yxz", origin=(7000100.0, 480000.0, 100.0))
    h = plan.holes.iloc[0]
    assert h["hole_id"] == "1" and h["HoleName"] == "R12-1" and h["MwdOn"] == 1
    assert h["hole_type"] == ""  # TypeOfHole Undefined: no type
    np.testing.assert_allclose(h[COORDS].to_numpy(dtype=float), [6.5, 0.25, 1.5, 10.0, 0.25, 1.5], atol=1e-9)


# --- the demo face ----------------------------------------------------------------------------


def test_demo_face_holes_are_drillable_and_inside_the_profile(demo, safety):
    h = demo.holes
    assert 50 <= len(h) <= 90 and h["hole_id"].is_unique
    assert set(h["hole_type"]) == set(HOLE_TYPES)
    assert {t: h["hole_id"][h["hole_type"] == t].str[0].unique().tolist() for t in HOLE_TYPES} == {
        "cut": ["C"], "relief": ["R"], "stoping": ["S"], "lifter": ["L"], "contour": ["K"]}
    clear = plan_clearances(safety, demo)
    assert all(float(c.min()) >= 0 for c in clear.values())  # wall 0.5, ground 0.1, arch 0.1 kept
    collar = torch.tensor(h[COLLAR].to_numpy())
    assert bool(safety.tunnel.contains(collar[:, 1], collar[:, 2], 0.2 - 1e-9).all())
    axis = h[TOE].to_numpy() - h[COLLAR].to_numpy()
    angle = np.degrees(np.arccos(axis[:, 0] / np.linalg.norm(axis, axis=1)))
    assert angle.max() <= 12.0 and np.all(angle[h["hole_type"].isin(["cut", "relief", "stoping"])] == 0)
    assert np.all((h["collar_x"] == 6.5) & np.isclose(h["toe_x"], 10.0))
    assert set(h["diameter_mm"][h["hole_type"] == "relief"]) == {102}


def _outline(tunnel, n=4000):
    r, h = tunnel.half_width, tunnel.wall_height
    phi = np.linspace(0, np.pi, n)
    walls = np.linspace(0, h, n)
    return np.concatenate([np.stack([np.full(n, -r), walls], 1), np.stack([np.full(n, r), walls], 1),
                           np.stack([r * np.cos(phi), h + r * np.sin(phi)], 1),
                           np.stack([np.linspace(-r, r, n), np.zeros(n)], 1)])


def test_demo_face_contour_and_lifters_look_out_beyond_the_profile(demo, safety):
    h = demo.holes[demo.holes["hole_type"].isin(["contour", "lifter"])]
    toe = h[["toe_y", "toe_z"]].to_numpy()
    gap = np.linalg.norm(toe[:, None, :] - _outline(safety.tunnel)[None], axis=-1).min(1)
    inside = safety.tunnel.contains(torch.tensor(toe[:, 0]), torch.tensor(toe[:, 1])).numpy()
    assert not inside.any() and np.allclose(gap, 0.1, atol=2e-3)  # toes 0.1 m beyond the profile


def test_demo_face_is_deterministic_and_checks_its_parameters(demo, safety):
    pd.testing.assert_frame_equal(demo_face(safety=safety).holes, demo.holes)
    with pytest.raises(ConfigError, match=r"x_face = 8.0"):
        demo_face(safety=safety, x_face=8.0)


def test_the_demo_face_stage_writes_the_plan_as_csv_and_iredes_and_generate_does_not(tmp_path, make_cfg, demo):
    from pipeline import demo_face as stage
    from pipeline import generate

    written = stage.run(make_cfg(tmp_path / "a"))
    plans = tmp_path / "a" / "data" / "plans"
    assert written == [plans / "demo_face.csv", plans / "demo_face.xml"]
    rerun = stage.run(make_cfg(tmp_path / "b"))  # the same config gives the same bytes (DVC sees no change)
    for path, again in zip(written, rerun, strict=True):
        assert again.read_bytes() == path.read_bytes(), path.name
        _same_holes(demo.holes, read_plan(path).holes)
    assert not hasattr(generate, "write_demo_plan")  # the study stage no longer writes the product's plan


# --- poses ------------------------------------------------------------------------------------


def test_hole_poses_put_the_preview_point_d_along_the_hole(demo):
    P = hole_poses(demo, 3.3)
    assert P.dtype == torch.float64 and P.shape == (len(demo), 6)
    collar = torch.tensor(demo.holes[COLLAR].to_numpy())
    axis = torch.tensor(demo.holes[TOE].to_numpy()) - collar
    assert torch.equal(P[:, :3], collar)
    assert float(((P[:, 3:] - P[:, :3]).norm(dim=-1) - 3.3).abs().max()) < 1e-12
    assert float(torch.linalg.cross(P[:, 3:] - P[:, :3], axis).norm(dim=-1).max()) < 1e-12
    assert math.isclose(float(P[0, 3]), float(collar[0, 0]) + 3.3)  # a cut hole runs along +x
    with pytest.raises(ConfigError, match="preview depth"):
        hole_poses(demo, 0.0)
    assert isinstance(demo, DrillPlan) and torch.equal(demo.poses(3.3), P)


# --- hostile files: every one built here -------------------------------------------


def _moved(demo, tmp_path, name="face.xml"):
    """The demo face as IREDES with the first collar moved by 1 m (the attack the checksum must catch)."""
    holes = demo.holes.copy()
    holes.loc[0, "collar_y"] += 1.0
    return iredes_bytes(holes, created=STAMP, checksum=None), tmp_path / name


def _trailer(data: bytes, chksum: str) -> bytes:
    return data.replace(b"</DRPPlan>", f"  <IR:GenTrailer><IR:ChkSum>{chksum}</IR:ChkSum></IR:GenTrailer>\n"
                        "</DRPPlan>".encode())


@pytest.mark.parametrize("attack", ["no trailer", "chksum 0", "utf-16", "chksum in a comment", "chksum empty"])
def test_an_iredes_plan_that_cannot_be_verified_is_refused_and_warn_records_it(demo, tmp_path, attack, caplog):
    data, path = _moved(demo, tmp_path)
    if attack == "chksum 0":
        data = _trailer(data, "0")
    elif attack == "chksum empty":
        data = _trailer(data, "")
    elif attack == "utf-16":
        crc = file_crc32(_trailer(data, "0"))[0]  # a valid checksum of the UTF-8 file ...
        data = _trailer(data, str(crc)).decode().replace('encoding="UTF-8"', 'encoding="UTF-16"').encode("utf-16")
    elif attack == "chksum in a comment":
        data = data.replace(b"</DRPPlan>", b"<!-- <IR:GenTrailer><IR:ChkSum>0</IR:ChkSum></IR:GenTrailer> -->"
                            b"\n</DRPPlan>")
    path.write_bytes(data)
    with pytest.raises(InputError, match=r"face.xml: .*refused \(solve.iredes.checksum=refuse\)"):
        read_iredes_plan(path)
    with caplog.at_level(logging.WARNING, logger="pipeline.plans.iredes"):
        plan = read_iredes_plan(path, checksum="warn")
    assert plan.checksum == "unverified" and "unverified" in caplog.text and len(plan) == len(demo)
    assert read_iredes_plan(path, checksum="ignore").checksum == "ignored"


def test_a_real_chksum_beside_a_commented_one_is_the_one_checked(demo, tmp_path):
    path = tmp_path / "face.xml"
    data = iredes_bytes(demo, created=STAMP).replace(b"<IR:PlanId>", b"<!-- <IR:ChkSum>1</IR:ChkSum> --><IR:PlanId>")
    crc, stored = file_crc32(data)
    data = data.replace(f"<IR:ChkSum>{stored}<".encode(), b"<IR:ChkSum>0<")
    path.write_bytes(data.replace(b"<IR:ChkSum>0<", f"<IR:ChkSum>{file_crc32(data)[0]}<".encode()))
    assert read_iredes_plan(path).checksum == "verified"
    assert read_csv_plan_of(demo, tmp_path).checksum == "not applicable"


def read_csv_plan_of(demo, tmp_path):
    write_csv_plan(demo, tmp_path / "face.csv")
    return read_csv_plan(tmp_path / "face.csv")


def test_a_huge_text_node_or_file_is_refused_with_a_clear_message(demo, tmp_path):
    path = tmp_path / "big.xml"
    data = iredes_bytes(demo, created=STAMP, checksum=None)
    path.write_bytes(data.replace(b"<IR:PlanName>", b"<IR:PlanName>" + b"x" * 100_000, 1))
    line = data[: data.index(b"<IR:PlanName>")].count(b"\n") + 1
    with pytest.raises(InputError, match=rf"big.xml: line {line}: a text node in <PlanName> is longer than 65536"):
        read_iredes_plan(path, checksum="ignore")
    path.write_bytes(data)
    with pytest.raises(InputError, match=r"big.xml: .* MB, over solve.max_plan_mb = 0.001 MB"):
        read_plan(path, max_mb=0.001, checksum="ignore")


@pytest.mark.parametrize("huge", ["1e154", "1e200", "1.7e308", "-1e300"])
def test_one_row_with_huge_finite_coordinates_is_a_row_problem(tmp_path, huge):
    rows = ["A1,6.5,0.1,1.5,10,0.1,1.5,cut", f"A2,{huge},0.2,1.5,10,0.2,1.5,cut", "A3,6.5,0.3,1.5,10,0.3,1.5,cut"]
    (tmp_path / "p.csv").write_text("\n".join([HEADER, *rows]) + "\n")
    plan = read_csv_plan(tmp_path / "p.csv")
    assert plan.holes["hole_id"].tolist() == ["A1", "A3"]
    (p,) = plan.problems
    assert (p.row, p.hole_id, p.column) == (3, "A2", "collar_x") and "beyond 1e+08 m" in p.message
    assert torch.isfinite(plan.poses(3.3)).all()


def test_huge_iredes_coordinates_name_the_point(tmp_path):
    holes = [_hole("H1", (6.5, 0.1, 1.5), (10, 0.1, 1.5)), _hole("H2", (6.5, 0.2, 1.5), (1e300, 0.2, 1.5))]
    (tmp_path / "p.xml").write_text(_iredes(holes))
    plan = read_iredes_plan(tmp_path / "p.xml", checksum="ignore", unit="mm")
    assert [(p.row, p.hole_id, p.column) for p in plan.problems] == [(6, "H2", "EndPoint")]


def test_a_duplicated_csv_header_is_an_error(tmp_path):
    (tmp_path / "p.csv").write_text(HEADER + ",collar_y\nA1,6.5,0.1,1.5,10,0.1,1.5,cut,9\n")
    with pytest.raises(InputError, match=r"p.csv: column\(s\) \['collar_y'\] appear more than once .*\[3, 9\]"):
        read_csv_plan(tmp_path / "p.csv")


@pytest.mark.parametrize("hid, bad", [('=HYPERLINK("http://x","y")', True), ("+A1", True), ("-A1", True),
                                      ("@SUM(A1)", True), ("H\x07", True), ("H\x1b[31m", True), ("-12", False),
                                      ("C-01", False), ("12", False)])
def test_ids_a_spreadsheet_would_evaluate_or_with_control_characters_are_row_problems(tmp_path, hid, bad):
    rows = ["A1,6.5,0.1,1.5,10,0.1,1.5,cut", f'"{hid.replace(chr(34), chr(34) * 2)}",6.5,0.2,1.5,10,0.2,1.5,cut']
    (tmp_path / "p.csv").write_text("\n".join([HEADER, *rows]) + "\n")
    plan = read_csv_plan(tmp_path / "p.csv")
    assert (len(plan.problems) == 1) == bad and (hid in plan.holes["hole_id"].tolist()) != bad
    if bad:
        assert plan.problems[0].row == 3 and plan.problems[0].column == "hole_id"
        assert "formula" in plan.problems[0].message or "control character" in plan.problems[0].message
