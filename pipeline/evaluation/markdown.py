"""GitHub Markdown tables of results (docs, reports, MLflow text artifacts): the one renderer."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence

import pandas as pd


def markdown_rows(header: Sequence, rows: Iterable[Sequence]) -> str:
    """A GitHub Markdown table of cells already written as text (an empty cell stays empty: ``| |``)."""
    def line(cells) -> str:
        return "|" + "|".join(f" {c} " if c != "" else " " for c in map(str, cells)) + "|\n"

    return line(header) + "|" + "---|" * len(header) + "\n" + "".join(line(r) for r in rows)


def markdown_table(df: pd.DataFrame, digits: int = 4, formats: Mapping[str, Callable] | None = None,
                   nan: str | None = None) -> str:
    """A GitHub Markdown table of ``df``: a column in ``formats`` through its function, other floats to
    ``digits`` significant figures (a NaN as ``nan`` when given), anything else as ``str``."""
    formats = formats or {}

    def cell(col, v) -> str:
        if col in formats:
            return formats[col](v)
        if isinstance(v, float):
            return nan if nan is not None and math.isnan(v) else f"{v:.{digits}g}"
        return str(v)

    cols = list(df.columns)
    rows = ([cell(c, v) for c, v in zip(cols, row, strict=True)] for row in df.itertuples(index=False))
    return markdown_rows(cols, rows)
