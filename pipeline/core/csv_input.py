"""Small CSV inputs a user hands over (a tunnel profile, surveyed reference points), read as text.

Every cell is read as text, so the caller decides what is a number and names the row of the first cell
that is not; nothing is evaluated. A file over ``max_mb`` is refused before it is read: these files have
tens to thousands of rows, and a huge one is a wrong file (or a 200 MB cell).
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from pipeline.core.errors import InputError


def read_text_csv(path: str | Path, what: str, columns: list[str], *, lower: bool = False,
                  max_mb: float = 16.0) -> pd.DataFrame:
    """The file's rows as stripped text, its header stripped (and lower-cased with ``lower``); every
    column of ``columns`` present, else :class:`InputError` naming the file, ``what`` it should be, and the
    columns missing."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such {what}")
    if path.stat().st_size > max_mb * 1e6:
        raise InputError(f"{path}: {path.stat().st_size / 1e6:.1f} MB, over {max_mb:g} MB for a {what}")
    try:
        df = pd.read_csv(path, dtype=str, keep_default_na=False, skipinitialspace=True)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: not a readable CSV {what} ({' '.join(str(e).split())})") from None
    df.columns = [str(c).strip().lower() if lower else str(c).strip() for c in df.columns]
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise InputError(f"{path}: {what} without column(s) {missing}; expected {', '.join(columns)}")
    return df
