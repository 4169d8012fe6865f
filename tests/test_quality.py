"""The as-drilled log: IREDES DRPQual files written and read (a vendor's, written here with its own code: no
HoleName, a TMatrix, the empty-value checksum, CRLF), deviations against independent values, and the quality
stage's files, JSON, MLflow run and strict exit."""

import binascii
import json
import math

import numpy as np
import pandas as pd
import pytest

from pipeline.core.errors import ConfigError, InputError, StrictCheckFailed
from pipeline.plans.deviations import deviations
from pipeline.plans.drpqual import LOG_COLUMNS, read_quality_log, write_quality_log
from pipeline.plans.model import COORDS

PLAN = pd.DataFrame({"hole_id": ["001", "002", "010", "9"],
                     "collar_x": [6.5, 6.5, 6.5, 6.5], "collar_y": [0.0, 1.0, -1.0, 0.5],
                     "collar_z": [1.5, 2.0, 2.5, 3.0], "toe_x": [10.0, 10.0, 10.0, 10.0],
                     "toe_y": [0.0, 1.0, -1.0, 0.5], "toe_z": [1.5, 2.0, 2.5, 3.0]})


def drilled_log(plan: pd.DataFrame, shift: np.ndarray) -> pd.DataFrame:
    """Each hole drilled ``shift`` (collar and toe moved alike, per hole) off its plan."""
    holes = plan[["hole_id"]].assign(hole_name=plan["hole_id"], boom="L", status="Drilled",
                                     start_time="2026-01-01T07:00:00", end_time="2026-01-01T07:02:00")
    xyz = plan[COORDS].to_numpy() + np.concatenate([shift, shift], axis=1)
    holes[COORDS] = xyz
    return holes[LOG_COLUMNS]


def vendor_qual(holes_local: np.ndarray, ids, tmatrix: np.ndarray) -> bytes:
    """A DRPQual as a vendor's software writes it, by this test's own code: CRLF, no HoleName, a TMatrix placing
    the local points, the ChkSum the CRC32 of the file with the value empty (binascii)."""
    cols = "".join("<IR:Col>" + "".join(f"<IR:{a}>{float(v)!r}</IR:{a}>" for a, v in zip("xyzw", col, strict=True))
                   + "</IR:Col>\r\n" for col in tmatrix.T)
    lines = ['<?xml version="1.0" encoding="UTF-8"?>',
             '<DRPQual xmlns="http://www.iredes.org/xml/DrillRig" xmlns:IR="http://www.iredes.org/xml" '
             'IRVersion="V 1.0" IRDownwCompat="V 1.0" DRPQualVersion="V 1.0" DRPQualDownwCompat="V 1.0">',
             "  <IR:GenHead><IR:FileCreateDate>2026-11-30T06:00:00</IR:FileCreateDate></IR:GenHead>",
             "  <IR:PlanIdRef>R57</IR:PlanIdRef>",
             "  <DrillPosPlan><PositionData><Coordsystem><IR:TMatrix>", cols.rstrip("\r\n"),
             "  </IR:TMatrix></Coordsystem></PositionData></DrillPosPlan>"]
    for hid, (a, b) in zip(ids, holes_local.reshape(-1, 2, 3), strict=True):
        pt = lambda p: "".join(f"<IR:Point{k}>{float(v)!r}</IR:Point{k}>" for k, v in zip("XYZ", p, strict=True))  # noqa: E731
        lines += ["  <HoleQualityData>", "    <Hole>", f"      <HoleId>{hid}</HoleId>",
                  f"      <StartPoint>{pt(a)}</StartPoint>", f"      <EndPoint>{pt(b)}</EndPoint>",
                  "      <StartHoleTime>2026-11-30T07:00:00</StartHoleTime><Hstatus>Drilled</Hstatus>",
                  "      <EqpType>Boom1</EqpType>", "    </Hole>", "  </HoleQualityData>"]
    lines += ["  <IR:GenTrailer><IR:FileCloseDate>2026-11-30T09:00:00</IR:FileCloseDate><IR:ChkSum>"
              "</IR:ChkSum></IR:GenTrailer>", "</DRPQual>", ""]
    data = "\r\n".join(lines).encode()
    crc = binascii.crc32(data) & 0xFFFFFFFF
    return data.replace(b"<IR:ChkSum></IR:ChkSum>", f"<IR:ChkSum>{crc}</IR:ChkSum>".encode())


def test_the_execute_stage_s_log_reads_back_as_written(tmp_path):
    log = drilled_log(PLAN, np.zeros((4, 3)))
    write_quality_log(log, tmp_path / "q.xml", plan_id="demo", plan_name="demo face", created="2026-01-01T07:00:00")
    back = read_quality_log(tmp_path / "q.xml")
    assert back.checksum == "verified" and back.checksum_convention == "documented"
    assert back.plan_id == "demo" and back.holes["hole_id"].tolist() == ["001", "002", "010", "9"]
    np.testing.assert_array_equal(back.holes[COORDS].to_numpy(), log[COORDS].to_numpy())
    assert back.holes[["boom", "status", "start_time"]].iloc[0].tolist() == ["L", "Drilled", "2026-01-01T07:00:00"]


def test_a_vendor_log_is_read_and_its_deviations_are_the_independent_ones(tmp_path):
    """No HoleName, a TMatrix (a turn of 30 deg about z and a shift into mine coordinates), the empty-value
    checksum over CRLF bytes: deviations equal numpy's own, computed here from the points as drilled."""
    a = math.radians(30.0)
    M = np.array([[math.cos(a), -math.sin(a), 0, 478_000.0], [math.sin(a), math.cos(a), 0, 6_771_600.0],
                  [0, 0, 1, 240.0], [0, 0, 0, 1]])
    plan_mine = PLAN.copy()
    local_drilled = PLAN[COORDS].to_numpy() + np.array([[0.01, 0.0, 0.0, 0.01, 0.0, 0.0],
                                                        [0.0, 0.03, 0.0, 0.02, 0.25, 0.0],
                                                        [0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
                                                        [0.2, 0.0, 0.0, 0.1, 0.0, 0.0]])
    to_mine = lambda p: (p.reshape(-1, 3) @ M[:3, :3].T + M[:3, 3]).reshape(p.shape)  # noqa: E731
    plan_mine[COORDS] = to_mine(PLAN[COORDS].to_numpy())
    (tmp_path / "q.xml").write_bytes(vendor_qual(local_drilled, ["001", "002", "010", "77"], M))
    log = read_quality_log(tmp_path / "q.xml")
    assert log.checksum == "verified" and log.checksum_convention == "empty-value"
    assert log.holes["hole_name"].tolist() == log.holes["hole_id"].tolist()  # no HoleName: the id stands in
    table, summary = deviations(plan_mine, log.holes)
    drilled = to_mine(local_drilled)
    planned = plan_mine[COORDS].to_numpy()
    collar = np.linalg.norm(drilled[:, :3] - planned[:, :3], axis=1)
    toe = np.linalg.norm(drilled[:, 3:] - planned[:, 3:], axis=1)
    np.testing.assert_allclose(table["collar_dev_m"].to_numpy()[:3], collar[:3], atol=1e-7)
    np.testing.assert_allclose(table["toe_dev_m"].to_numpy()[:3], toe[:3], atol=1e-7)
    # 002: drilled along (3.52, 0.22, 0) in the plan's local frame, against (3.5, 0, 0)
    np.testing.assert_allclose(table["direction_err_deg"].iloc[1], math.degrees(math.atan2(0.22, 3.52)), atol=1e-6)
    np.testing.assert_allclose(table["length_err_m"].iloc[1], math.hypot(3.52, 0.22) - 3.5, atol=1e-7)
    # 001 off 10 mm: within; 002's toe 0.25 m off, over 6 % of 3.5 m: not; 010 exact; 9 never drilled
    assert table["within"].tolist() == [True, False, True, False]
    assert table["status"].tolist() == ["Drilled", "Drilled", "Drilled", "not drilled"]
    assert summary["missing_from_log"] == ["9"] and summary["not_in_plan"] == ["77"] and summary["within"] == 2


def test_a_changed_log_is_refused_and_one_whose_line_ends_changed_is_named(tmp_path):
    data = vendor_qual(PLAN[COORDS].to_numpy(), PLAN["hole_id"], np.eye(4))
    (tmp_path / "lf.xml").write_bytes(data.replace(b"\r\n", b"\n"))
    assert read_quality_log(tmp_path / "lf.xml").checksum_line_ends == "converted (CRLF -> LF)"
    (tmp_path / "edited.xml").write_bytes(data.replace(b"<IR:PointX>6.5</IR:PointX>", b"<IR:PointX>6.6</IR:PointX>", 1))
    with pytest.raises(InputError, match="checksum mismatch"):
        read_quality_log(tmp_path / "edited.xml")


@pytest.mark.parametrize(("text", "message"), [
    (b'<?xml version="1.0"?><DRPPlan/>', r"root element is 'DRPPlan', expected 'DRPQual'"),
    (b"<DRPQual><HoleQualityData><Hole>", r"malformed XML at line 1"),
    (b"<DRPQual><HoleQualityData><Hole><HoleId>A</HoleId><StartPoint><PointX>x</PointX></StartPoint></Hole>"
     b"</HoleQualityData></DRPQual>", r"no readable hole: .*row 1, hole 'A', column 'StartPoint/PointX'"),
    (b'<!DOCTYPE x [<!ENTITY a "aaaa">]><DRPQual/>', r"line 1: a <!DOCTYPE x> declaration"),
])
def test_a_log_that_cannot_be_read_is_refused_naming_the_place(tmp_path, text, message):
    (tmp_path / "q.xml").write_bytes(text)
    with pytest.raises(InputError, match=message):
        read_quality_log(tmp_path / "q.xml", checksum="ignore")


@pytest.mark.slow
def test_the_stage_writes_its_set_logs_a_run_and_strict_exits_1(tmp_path, make_cfg):
    from mlflow.tracking import MlflowClient

    from pipeline import quality

    plan = tmp_path / "round.csv"
    PLAN.to_csv(plan, index=False)
    log_path = tmp_path / "round_qual.xml"
    write_quality_log(drilled_log(PLAN, np.array([[0.004, 0, 0], [0, 0.02, 0], [0, 0, 0.15], [0, 0, 0]])), log_path,
                      plan_id="round", plan_name="round", created="2026-01-01T07:00:00")
    summary = quality.run(make_cfg(tmp_path, f"plan={plan}", f"log={log_path}"))
    table = pd.read_csv(tmp_path / "round_quality.csv", dtype={"hole_id": str})
    record = json.loads((tmp_path / "round_quality.json").read_text())
    assert table["hole_id"].tolist() == ["001", "002", "010", "9"] and table["within"].tolist() == [
        True, True, False, True]
    assert record["within"] == 3 and record["log_checksum"] == "verified" and record["collar_dev_m_max"] == \
        pytest.approx(0.15) and summary["within_share"] == 0.75
    assert (tmp_path / "round_quality.png").stat().st_size > 10_000
    client = MlflowClient(f"sqlite:///{tmp_path}/mlflow.db")
    (run,) = client.search_runs([client.get_experiment_by_name("boom-ik-tiny").experiment_id],
                                "tags.stage = 'quality'")
    assert run.info.status == "FINISHED" and run.data.metrics["within"] == 3
    with pytest.raises(StrictCheckFailed, match=r"strict: 1 of 4 holes not drilled within tolerance"):
        quality.run(make_cfg(tmp_path, f"plan={plan}", f"log={log_path}", "strict=true"))
    with pytest.raises(ConfigError, match=r"log = null: give the rig's quality log"):
        quality.run(make_cfg(tmp_path, f"plan={plan}"))
