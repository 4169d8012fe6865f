"""IREDES files as vendors write them (tests/vendor_iredes.py): Epiroc's empty-value checksum, CRLF line ends
and copies that changed only those, a TMatrix that places a local plan in mine coordinates, the fields real
files carry, ids that are text, and no entity expansion. Expected values come from binascii and numpy."""

import binascii
import json
import logging
import re

import numpy as np
import pandas as pd
import pytest
from vendor_iredes import placement, text_sorted_ids, vendor_drpplan

from pipeline import solve
from pipeline.core.errors import InputError
from pipeline.plans.csv_plan import read_csv_plan
from pipeline.plans.iredes import iredes_bytes, read_iredes_plan
from pipeline.plans.model import COORDS

SHIFT = (478114.5, 6771714.0, 239.0)  # mine coordinates (easting, northing, elevation) of the local origin
TURN = 37.0  # degrees about z
N = 612


def _local_holes(n: int, seed: int = 7) -> np.ndarray:
    """``(n, 6)`` holes in the local frame: collars spread over a face, toes 4-5 m further, tilted a little."""
    rng = np.random.default_rng(seed)
    collar = np.c_[rng.uniform(-2.0, 2.0, n), rng.uniform(-30.0, 30.0, n), rng.uniform(-4.0, 4.0, n)]
    toe = collar + np.c_[rng.uniform(4.0, 5.0, n), rng.uniform(-0.3, 0.3, n), rng.uniform(-0.3, 0.3, n)]
    return np.c_[collar, toe]


def _expected_base(M: np.ndarray, local: np.ndarray, origin) -> np.ndarray:
    """M @ [p, 1] for collar and toe (numpy), less the base frame's origin."""
    out = []
    for part in (local[:, :3], local[:, 3:]):
        h = np.c_[part, np.ones(len(part))]
        out.append((M @ h.T).T[:, :3] - np.asarray(origin))
    return np.hstack(out)


def _line_of(data: bytes, needle: bytes, nth: int = 0) -> int:
    at = -1
    for _ in range(nth + 1):
        at = data.index(needle, at + 1)
    return data[:at].count(b"\n") + 1


@pytest.fixture
def vendor(tmp_path):
    """The 612-hole vendor file (CRLF, empty-value checksum, TMatrix), its path, bytes, holes, ids, matrix."""
    local, ids, M = _local_holes(N), text_sorted_ids(N), placement(TURN, SHIFT)
    path = tmp_path / "R612.xml"
    data = vendor_drpplan(path, local, ids, M)
    return path, data, local, ids, M


def _chksum(data: bytes) -> bytes:
    return re.search(rb"<IR:ChkSum>([^<]*)</IR:ChkSum>", data).group(1)


# --- the checksum conventions and line ends --------------------------------------------------


def test_the_vendor_file_is_what_its_writer_says(vendor):
    """The helper's own claims, checked from the bytes: CRLF only, and the stored value is the CRC32 of
    the file with the value empty (and not of the file with it 0)."""
    _, data, *_ = vendor
    assert data.count(b"\r\n") == data.count(b"\n") > 1000
    stored = _chksum(data)
    empty = data.replace(b"<IR:ChkSum>" + stored + b"<", b"<IR:ChkSum><")
    assert int(stored) == binascii.crc32(empty) != binascii.crc32(empty.replace(b"<IR:ChkSum><", b"<IR:ChkSum>0<"))


def test_an_epiroc_file_verifies_under_the_empty_value_convention(vendor):
    path, *_ = vendor
    plan = read_iredes_plan(path, origin=SHIFT)
    assert (plan.checksum, plan.checksum_convention, plan.checksum_line_ends) == ("verified", "empty-value",
                                                                                  "as written")
    assert "ChkSum empty" in plan.checksum_detail and len(plan) == N and not plan.problems


def test_the_documented_convention_and_hex_still_verify(tmp_path):
    local, ids, M = _local_holes(20), text_sorted_ids(20), placement(TURN, SHIFT)
    for fmt in ("decimal", "hex"):
        path = tmp_path / f"doc_{fmt}.xml"
        data = vendor_drpplan(path, local, ids, M, convention="documented", checksum_format=fmt)
        stored = _chksum(data)
        assert int(stored, 10 if fmt == "decimal" else 16) == binascii.crc32(
            data.replace(b"<IR:ChkSum>" + stored + b"<", b"<IR:ChkSum>0<"))
        plan = read_iredes_plan(path, origin=SHIFT)
        assert (plan.checksum, plan.checksum_convention, plan.checksum_line_ends) == ("verified", "documented",
                                                                                      "as written")
    path = tmp_path / "hex_empty.xml"
    vendor_drpplan(path, local, ids, M, checksum_format="hex")
    assert read_iredes_plan(path, origin=SHIFT).checksum_convention == "empty-value"


def test_our_own_files_verify_under_the_documented_convention(tmp_path, vendor):
    path, *_ = vendor
    plan = read_iredes_plan(path, origin=SHIFT)
    data = iredes_bytes(plan, created="2025-01-01T00:00:00")
    stored = _chksum(data)
    assert b"\r" not in data and int(stored) == binascii.crc32(
        data.replace(b"<IR:ChkSum>" + stored + b"<", b"<IR:ChkSum>0<"))
    (tmp_path / "ours.xml").write_bytes(data)
    back = read_iredes_plan(tmp_path / "ours.xml")
    assert (back.checksum, back.checksum_convention, back.checksum_line_ends) == ("verified", "documented",
                                                                                  "as written")
    assert back.local_to_plan is None  # ours are written in the base frame, no TMatrix


def test_a_copy_that_only_changed_its_line_ends_is_named_so_not_accused(vendor, tmp_path, caplog):
    path, data, *_ = vendor
    lf = tmp_path / "lf.xml"
    lf.write_bytes(data.replace(b"\r\n", b"\n"))
    with caplog.at_level(logging.INFO, logger="pipeline.plans.iredes"):
        plan = read_iredes_plan(lf, origin=SHIFT)
    assert (plan.checksum, plan.checksum_convention, plan.checksum_line_ends) == (
        "verified", "empty-value", "converted (CRLF -> LF)")
    assert "changed after" not in plan.checksum_detail and "content is unchanged" in plan.checksum_detail
    assert "line ends converted (CRLF -> LF)" in caplog.text
    # the other way: written with LF under the documented convention, then turned into CRLF
    local, ids, M = _local_holes(10), text_sorted_ids(10), placement(TURN, SHIFT)
    written = vendor_drpplan(None, local, ids, M, convention="documented", line_end="\n")
    (tmp_path / "crlf.xml").write_bytes(written.replace(b"\n", b"\r\n"))
    plan = read_iredes_plan(tmp_path / "crlf.xml", origin=SHIFT)
    assert (plan.checksum, plan.checksum_convention, plan.checksum_line_ends) == (
        "verified", "documented", "converted (LF -> CRLF)")


def _one_digit_changed(data: bytes, hole: int = 300) -> bytes:
    """The hole's StartPoint/PointY with one digit changed (one byte), nothing else."""
    at = data.index(b"<IR:PointY>", data.index(b"<Hole>", 0) + 1)
    for _ in range(hole):
        at = data.index(b"<IR:PointY>", at + 1)
    digit = at + len(b"<IR:PointY>") + 3
    while not data[digit:digit + 1].isdigit():
        digit += 1
    changed = bytes([ord("0") + (data[digit] - ord("0") + 1) % 10])
    out = data[:digit] + changed + data[digit + 1:]
    assert len(out) == len(data) and sum(a != b for a, b in zip(out, data, strict=True)) == 1
    return out


def test_one_changed_byte_is_refused_as_changed_content(vendor, tmp_path, caplog):
    path, data, *_ = vendor
    for name, bad in [("crlf", _one_digit_changed(data)), ("lf", _one_digit_changed(data).replace(b"\r\n", b"\n"))]:
        target = tmp_path / f"tampered_{name}.xml"
        target.write_bytes(bad)
        with pytest.raises(InputError, match=rf"tampered_{name}.xml: IREDES checksum mismatch: .*"
                                             r"the file changed after it was written.*refused \(solve.iredes"):
            read_iredes_plan(target, origin=SHIFT)
        with caplog.at_level(logging.WARNING, logger="pipeline.plans.iredes"):
            plan = read_iredes_plan(target, origin=SHIFT, checksum="warn")
        assert (plan.checksum, plan.checksum_convention, plan.checksum_line_ends) == ("unverified", None, None)
    # the message quotes both CRCs of the tampered bytes, computed here with binascii
    bad = _one_digit_changed(data)
    stored = _chksum(bad)
    crc0 = binascii.crc32(bad.replace(b"<IR:ChkSum>" + stored + b"<", b"<IR:ChkSum>0<"))
    crc_empty = binascii.crc32(bad.replace(b"<IR:ChkSum>" + stored + b"<", b"<IR:ChkSum><"))
    with pytest.raises(InputError, match=rf"with ChkSum 0 is {crc0} .* with ChkSum empty {crc_empty} "):
        read_iredes_plan(tmp_path / "tampered_crlf.xml", origin=SHIFT)


# --- the TMatrix ---------------------------------------------------------------------------------


def test_points_are_placed_by_the_tmatrix_then_the_axis_map(vendor):
    path, _, local, _, M = vendor
    plan = read_iredes_plan(path, origin=SHIFT)
    got = plan.holes[COORDS].to_numpy(dtype=float)
    np.testing.assert_allclose(got, _expected_base(M, local, SHIFT), rtol=0, atol=1e-9)
    assert np.array_equal(plan.local_to_plan, M)  # read back exactly (repr-written numbers)
    lengths = np.linalg.norm(got[:, 3:] - got[:, :3], axis=1)
    np.testing.assert_allclose(lengths, np.linalg.norm(local[:, 3:] - local[:, :3], axis=1), rtol=0, atol=1e-9)
    # the axis map acts after the TMatrix (its origin in the TMatrix's target coordinates): PointX read as y
    swapped = read_iredes_plan(path, origin=SHIFT, axes="yxz")
    want = _expected_base(M, local, SHIFT)[:, [1, 0, 2, 4, 3, 5]]
    np.testing.assert_allclose(swapped.holes[COORDS].to_numpy(dtype=float), want, rtol=0, atol=1e-9)


def _with_matrix_text(data: bytes, old: bytes, new: bytes) -> bytes:
    assert data.count(old) >= 1
    return data.replace(old, new, 1)


BAD_MATRICES = {
    "scale": (lambda M: M @ np.diag([1.001, 1.001, 1.001, 1.0]), r"3x3 part is not a rotation.*lengths"),
    "shear": (lambda M: M @ np.array([[1, 0.01, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]]),
              r"not a rotation"),
    "mirror": (lambda M: M @ np.diag([1.0, -1.0, 1.0, 1.0]), r"not a rotation.*det -1.*mirror"),
    "last row": (lambda M: M + np.array([[0, 0, 0, 0]] * 3 + [[0, 0, 0.5, 0]]), r"last row .* expected \[0, 0, 0, 1\]"),
}


@pytest.mark.parametrize("kind", sorted(BAD_MATRICES))
def test_a_non_rigid_tmatrix_is_refused_naming_its_line(tmp_path, kind):
    local, ids = _local_holes(5), text_sorted_ids(5)
    change, reason = BAD_MATRICES[kind]
    data = vendor_drpplan(tmp_path / "bad.xml", local, ids, change(placement(TURN, SHIFT)))
    line = _line_of(data, b"<IR:TMatrix>")
    with pytest.raises(InputError, match=rf"bad.xml: line {line}: TMatrix: .*{reason}"):
        read_iredes_plan(tmp_path / "bad.xml", origin=SHIFT)


MALFORMED = {
    "three columns": (lambda d: re.sub(rb"(\s*<IR:Col>(?:(?!</IR:Col>).)*</IR:Col>)", b"", d, count=1, flags=re.S),
                      r"expected four Col elements"),
    "no w": (lambda d: re.sub(rb"\s*<IR:w>[^<]*</IR:w>", b"", d, count=1), r"Col 1 holds \['x', 'y', 'z'\]"),
    "not a number": (lambda d: re.sub(rb"<IR:y>[^<]*</IR:y>", b"<IR:y>zero</IR:y>", d, count=1),
                     r"Col 1 y is 'zero', not a number"),
    "non-finite": (lambda d: re.sub(rb"<IR:x>[^<]*</IR:x>", b"<IR:x>NaN</IR:x>", d, count=1),
                   r"Col 1 x is 'NaN', not a finite number"),
}


@pytest.mark.parametrize("kind", sorted(MALFORMED))
def test_a_malformed_tmatrix_is_refused_naming_its_line(tmp_path, kind):
    edit, reason = MALFORMED[kind]
    data = edit(vendor_drpplan(None, _local_holes(5), text_sorted_ids(5), placement(TURN, SHIFT)))
    (tmp_path / "bad.xml").write_bytes(data)
    line = _line_of(data, b"<IR:TMatrix>")
    with pytest.raises(InputError, match=rf"bad.xml: line {line}: TMatrix: {reason}"):
        read_iredes_plan(tmp_path / "bad.xml", origin=SHIFT, checksum="ignore")


def test_a_rotation_written_with_three_decimals_needs_a_wider_tolerance(tmp_path):
    local, ids, M = _local_holes(5), text_sorted_ids(5), placement(TURN, SHIFT)
    data = vendor_drpplan(tmp_path / "r3.xml", local, ids, M, number=lambda v: f"{v:.3f}")
    with pytest.raises(InputError, match=rf"line {_line_of(data, b'<IR:TMatrix>')}: TMatrix: .*not a rotation"
                                         r".*tolerance 1e-06, solve.iredes.tmatrix_tol"):
        read_iredes_plan(tmp_path / "r3.xml", origin=SHIFT)
    plan = read_iredes_plan(tmp_path / "r3.xml", origin=SHIFT, tmatrix_tol=1e-3)
    assert np.array_equal(plan.local_to_plan, np.round(M, 3))  # applied as written, and recorded so


def test_repeated_tmatrix_must_be_equal_and_an_empty_one_is_the_identity(tmp_path, caplog):
    local, ids, M = _local_holes(5), text_sorted_ids(5), placement(TURN, SHIFT)
    data = vendor_drpplan(None, local, ids, M)
    block = re.search(rb"\s*<IR:TMatrix>.*?</IR:TMatrix>", data, re.S).group(0)
    (tmp_path / "twice.xml").write_bytes(data.replace(block, block + block))
    assert np.array_equal(read_iredes_plan(tmp_path / "twice.xml", origin=SHIFT, checksum="ignore").local_to_plan, M)
    east = float(M[0, 3])  # Col 4 x: the shift's easting
    moved = block.replace(f"<IR:x>{east!r}</IR:x>".encode(), f"<IR:x>{east + 1.0!r}</IR:x>".encode())
    assert moved != block
    differing = data.replace(block, block + moved)
    (tmp_path / "differ.xml").write_bytes(differing)
    first, second = _line_of(differing, b"<IR:TMatrix>"), _line_of(differing, b"<IR:TMatrix>", 1)
    with pytest.raises(InputError, match=rf"2 TMatrix elements \(lines \[{first}, {second}\]\), and the one at "
                                         rf"line\(s\) \[{second}\] differs from the one at line {first}"):
        read_iredes_plan(tmp_path / "differ.xml", origin=SHIFT, checksum="ignore")
    empty = data.replace(block, b"\r\n        <IR:TMatrix><!-- no placement --></IR:TMatrix>")
    (tmp_path / "empty.xml").write_bytes(empty)
    with caplog.at_level(logging.INFO, logger="pipeline.plans.iredes"):
        plan = read_iredes_plan(tmp_path / "empty.xml", checksum="ignore")
    assert np.array_equal(plan.local_to_plan, np.eye(4)) and "empty: read as the identity" in caplog.text
    np.testing.assert_array_equal(plan.holes[COORDS].to_numpy(dtype=float), local)


def test_a_tmatrix_inside_a_hole_is_refused_not_dropped(tmp_path):
    data = vendor_drpplan(None, _local_holes(3), text_sorted_ids(3), placement(TURN, SHIFT))
    block = re.search(rb"<IR:TMatrix>.*?</IR:TMatrix>", data, re.S).group(0)
    inside = data.replace(b"<HoleName>", block + b"<HoleName>", 1)
    (tmp_path / "hole_frame.xml").write_bytes(inside)
    line = _line_of(inside, b"<IR:TMatrix>", 1)
    with pytest.raises(InputError, match=rf"line {line}: a TMatrix inside a Hole"):
        read_iredes_plan(tmp_path / "hole_frame.xml", checksum="ignore")


# --- what real files carry ----------------------------------------------------------------------


def test_ids_stay_text_in_the_files_order_and_vendor_fields_are_columns(vendor):
    path, _, _, ids, _ = vendor
    h = read_iredes_plan(path, origin=SHIFT).holes
    assert h["hole_id"].tolist() == ids  # the file's order, not the text order or the numbers' order
    assert all(type(i) is str for i in h["hole_id"]) and {"001", "1", "10", "9", "010", "H001"} <= set(h["hole_id"])
    assert ids.index("9") < ids.index("10") and sorted(ids) != ids
    assert h["HoleName"].tolist() == ids  # a name such as "001" stays text too
    assert set(h["ExtendedHoleStatus"]) == {"Undrilled"} and set(h["MwdOn"]) == {1}
    assert set(h["hole_type"]) == {""}  # TypeOfHole Undefined: no type
    assert h["diameter_mm"].dtype == float and h["diameter_mm"].isna().all()  # DrillBitDia 0: not given, not 0 mm
    for gone in ("Project", "WorkOrder", "Bearing", "PlanIdRef", "OptionData", "HoleData"):
        assert gone not in h.columns


def test_types_and_diameters_as_vendors_write_them(tmp_path):
    kinds = ["Undefined", "3", "15", "cut", "", "undefined"]
    dias = ["0", "48", "0.0", "102", "64", "0"]
    vendor_drpplan(tmp_path / "t.xml", _local_holes(6), text_sorted_ids(6), placement(TURN, SHIFT),
                   type_of_hole=kinds, diameter=dias)
    h = read_iredes_plan(tmp_path / "t.xml", origin=SHIFT).holes
    assert h["hole_type"].tolist() == ["", "3", "15", "cut", "", ""]
    np.testing.assert_array_equal(h["diameter_mm"].to_numpy(dtype=float), [np.nan, 48, np.nan, 102, 64, np.nan])


def test_a_vendor_field_never_overwrites_a_known_column(tmp_path):
    local = _local_holes(3)
    extra = ["<opt:hole_type>X</opt:hole_type>", "<collar_x>999</collar_x>", "<HoleName>other</HoleName>"]
    vendor_drpplan(tmp_path / "c.xml", local, text_sorted_ids(3), placement(TURN, SHIFT), hole_data=extra,
                   type_of_hole="cut")
    h = read_iredes_plan(tmp_path / "c.xml", origin=SHIFT).holes
    assert set(h["hole_type"]) == {"cut"} and set(h["HoleOptions.hole_type"]) == {"X"}
    assert set(h["HoleOptions.collar_x"]) == {999} and h["HoleName"].tolist() == text_sorted_ids(3)
    assert set(h["HoleOptions.HoleName"]) == {"other"}
    np.testing.assert_allclose(h[COORDS].to_numpy(dtype=float), _expected_base(placement(TURN, SHIFT), local, SHIFT),
                               rtol=0, atol=1e-9)


# --- nothing expands or runs ---------------------------------------------------------------------

LAUGHS = (b'<?xml version="1.0"?>\n<!DOCTYPE DRPPlan [\n <!ENTITY lol "lol">\n'
          + b"".join(b' <!ENTITY lol%d "%s">\n' % (i, (b"&lol%d;" % (i - 1) if i > 1 else b"&lol;") * 10)
                     for i in range(1, 10))
          + b']>\n<DRPPlan><DrillPlan><Hole><HoleId>&lol9;</HoleId></Hole></DrillPlan></DRPPlan>\n')


def test_entity_declarations_are_refused_before_anything_expands(tmp_path):
    (tmp_path / "laughs.xml").write_bytes(LAUGHS)
    for policy in ("refuse", "ignore"):
        with pytest.raises(InputError, match=r"laughs.xml: line 2: a <!DOCTYPE DRPPlan> declaration.*refused"):
            read_iredes_plan(tmp_path / "laughs.xml", checksum=policy)
    secret = tmp_path / "secret.txt"
    secret.write_text("SECRET-CONTENT")
    xxe = (f'<?xml version="1.0"?>\n<!DOCTYPE DRPPlan [<!ENTITY xxe SYSTEM "file://{secret}">]>\n'
           "<DRPPlan><DrillPlan><Hole><HoleId>&xxe;</HoleId></Hole></DrillPlan></DRPPlan>\n")
    (tmp_path / "xxe.xml").write_text(xxe)
    with pytest.raises(InputError, match=r"xxe.xml: line 2: a <!DOCTYPE DRPPlan>") as err:
        read_iredes_plan(tmp_path / "xxe.xml", checksum="ignore")
    assert "SECRET" not in str(err.value)


# --- through the solve stage -----------------------------------------------------------------------


def _vendor_copy(holes: pd.DataFrame, path, ids, M, **kw) -> bytes:
    """A plan (base frame) as a vendor file in its local frame: p_local = R^T p, so that M, then the axis
    map with origin SHIFT, give the plan back."""
    B = holes[COORDS].to_numpy(dtype=float).reshape(-1, 2, 3)
    return vendor_drpplan(path, (B @ M[:3, :3]).reshape(-1, 6), ids, M, **kw)


@pytest.mark.slow
def test_solve_records_the_convention_the_line_ends_and_the_matrix_for_one_boom_and_a_rig(tiny_study, make_cfg):
    tmp = tiny_study
    plans = tmp / "data" / "plans"
    holes = read_csv_plan(plans / "demo_face.csv").holes.iloc[::6].reset_index(drop=True)  # 11 holes, every type
    ids, M = text_sorted_ids(len(holes)), placement(TURN, SHIFT)
    origin = f"solve.iredes.origin=[{SHIFT[0]},{SHIFT[1]},{SHIFT[2]}]"
    data = _vendor_copy(holes, plans / "R11.xml", ids, M)
    summary = solve.run(make_cfg(tmp, f"plan={plans / 'R11.xml'}", origin, "solve.figure=false"))
    record = json.loads((plans / "R11_solution.json").read_text())
    assert summary["checksum"] == record["checksum"] == "verified"
    assert (record["checksum_convention"], record["checksum_line_ends"]) == ("empty-value", "as written")
    assert record["local_to_plan"] == M.tolist() and "ChkSum empty" in record["checksum_detail"]
    table = pd.read_csv(plans / "R11_solution.csv", dtype={"hole_id": str, "HoleName": str}, keep_default_na=False)
    assert table["hole_id"].tolist() == ids and table["HoleName"].tolist() == ids
    assert set(table["status"]) == {"ok"} and summary["ok"] == len(holes)
    # a one-byte change is refused before any work, nothing written
    (plans / "R11_bad.xml").write_bytes(_one_digit_changed(data, hole=4))
    with pytest.raises(InputError, match=r"R11_bad.xml: IREDES checksum mismatch: .*changed after it was written"):
        solve.run(make_cfg(tmp, f"plan={plans / 'R11_bad.xml'}", origin))
    assert not (plans / "R11_bad_solution.json").exists()
    # the rig path, on a copy that turned CRLF into LF: the same record
    small = _vendor_copy(holes.iloc[:3], None, ids[:3], M)
    (plans / "R3_lf.xml").write_bytes(small.replace(b"\r\n", b"\n"))
    solve.run(make_cfg(tmp, f"plan={plans / 'R3_lf.xml'}", origin, "rig=twin", "solve.figure=false"))
    record = json.loads((plans / "R3_lf_solution.json").read_text())
    assert (record["checksum"], record["checksum_convention"], record["checksum_line_ends"]) == (
        "verified", "empty-value", "converted (CRLF -> LF)")
    assert record["local_to_plan"] == M.tolist() and record["rig"] == "twin"
    rig_table = pd.read_csv(plans / "R3_lf_solution.csv", dtype={"hole_id": str}, keep_default_na=False)
    assert rig_table["hole_id"].tolist() == [i for i in ids[:3] for _ in (0, 1)]  # each hole by L, then R
