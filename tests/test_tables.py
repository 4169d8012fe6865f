"""Hole tables read from disk: bad files are named with their column and row."""

import math

import pandas as pd
import pytest

from pipeline.core.errors import InputError
from pipeline.core.io import write_parquet
from pipeline.data.tables import POSE_COLUMNS, read_poses


def _plan():
    return pd.DataFrame([[0, 6.5, 0.1, 1.5, 9.8, 0.1, 1.5], [1, 6.5, -1.0, 2.0, 9.8, -1.1, 2.0]],
                        columns=["hole_id", *POSE_COLUMNS])


def test_round_trip(tmp_path):
    write_parquet(_plan(), tmp_path / "plan.parquet")
    df, poses = read_poses(tmp_path / "plan.parquet")
    assert poses.shape == (2, 6) and float(poses[1, 1]) == -1.0


def test_missing_column_is_named(tmp_path):
    _plan().drop(columns=["preview_z"]).to_csv(tmp_path / "plan.csv", index=False)
    with pytest.raises(InputError, match=r"plan.csv: missing column\(s\) \['preview_z'\]"):
        read_poses(tmp_path / "plan.csv")


@pytest.mark.parametrize("bad", [math.nan, math.inf, "abc"])
def test_non_finite_value_is_named_with_its_row(tmp_path, bad):
    df = _plan().astype({"collar_y": object})
    df.loc[1, "collar_y"] = bad
    df.to_csv(tmp_path / "plan.csv", index=False)
    with pytest.raises(InputError, match=r"plan.csv: column 'collar_y' has 1 non-finite .* first at row 1"):
        read_poses(tmp_path / "plan.csv")


def test_failed_write_leaves_the_old_file(tmp_path):
    path = tmp_path / "plan.parquet"
    write_parquet(_plan(), path)
    before = path.read_bytes()
    import pyarrow as pa

    with pytest.raises(pa.ArrowException):
        write_parquet(pd.DataFrame({"x": [object()]}), path)  # pyarrow cannot write this
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["plan.parquet"]
