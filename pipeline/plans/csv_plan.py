"""CSV drill plans: one row per hole, columns :data:`~pipeline.plans.model.REQUIRED` (metres,
base frame), every other column carried through."""

from __future__ import annotations

import csv
from collections import Counter
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.core.errors import InputError
from pipeline.core.io import write_csv
from pipeline.plans.model import COORDS, MIN_LENGTH, REQUIRED, DrillPlan, checked_plan, plan_frame


def _read_csv_text(path: Path, **kw) -> pd.DataFrame:
    try:
        # Blank lines are kept (and dropped below) so that row i is line i + 2 of the file.
        df = pd.read_csv(path, skip_blank_lines=False, **kw)
    except pd.errors.EmptyDataError:
        raise InputError(f"{path}: empty file; expected a header with columns {REQUIRED}") from None
    except (pd.errors.ParserError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: not a readable CSV file: {e}") from None
    df.columns = [str(c).strip() for c in df.columns]
    return df


def _refuse_duplicate_header(path: Path) -> None:
    """pandas renames a repeated column ``x`` to ``x.1`` and the checks would read the first one: which
    of the two holds the value is the user's to say, so the file is refused."""
    with open(path, newline="", encoding="utf-8", errors="replace") as f:
        header = next(csv.reader(f), [])
    names = [c.strip() for c in header]
    dups = sorted(c for c, k in Counter(names).items() if k > 1 and c)
    if dups:
        where = {c: [i + 1 for i, n in enumerate(names) if n == c] for c in dups}
        raise InputError(f"{path}: column(s) {dups} appear more than once in the header (columns {where}); "
                         "keep one of each")


def read_csv_plan(path: str | Path, *, min_length: float = MIN_LENGTH) -> DrillPlan:
    """Read a CSV drill plan (columns :data:`REQUIRED`, metres, base frame; others carried).

    Row numbers in problems are file lines (header = line 1). Raises :class:`InputError` for a
    missing file, an empty file, a missing column (naming the missing and the found ones) or a
    file without a single good row.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such drill plan")
    # Text for the checked columns (ids keep leading zeros, bad numbers keep their spelling);
    # pandas' own typing for the carried columns.
    _refuse_duplicate_header(path)
    text = _read_csv_text(path, dtype=str, keep_default_na=False)
    missing = [c for c in REQUIRED if c not in text.columns]
    if missing:
        raise InputError(f"{path}: missing column(s) {missing}; found {list(text.columns)}")
    blank = text.apply(lambda c: c.astype("string").fillna("").str.strip().eq("")).all(axis=1).to_numpy()
    if blank.all():
        raise InputError(f"{path}: no holes (only a header)")
    typed = _read_csv_text(path)
    keep = np.flatnonzero(~blank)
    extras = typed.loc[keep, [c for c in typed.columns if c not in REQUIRED]]
    return checked_plan(
        text.loc[keep, "hole_id"].tolist(),
        text.loc[keep, COORDS],
        extras,
        keep + 2,
        source=str(path),
        fmt="csv",
        plan_id=path.stem,
        name=path.stem,
        min_length=min_length,
    )


def write_csv_plan(plan: DrillPlan | pd.DataFrame, path: str | Path) -> None:
    """Write a plan as CSV, atomically (floats at full precision: a re-read gives the same holes)."""
    write_csv(plan_frame(plan), path)
