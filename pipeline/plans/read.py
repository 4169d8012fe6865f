"""A drill plan from a file, by its suffix: CSV or IREDES XML."""

from __future__ import annotations

from pathlib import Path

from pipeline.core.errors import InputError
from pipeline.plans.csv_plan import read_csv_plan
from pipeline.plans.iredes import read_iredes_plan
from pipeline.plans.model import DrillPlan


def read_plan(path: str | Path, **kw) -> DrillPlan:
    """A CSV (``.csv``) or IREDES (``.xml``) plan; ``kw`` goes to the reader."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".csv":
        return read_csv_plan(path, **kw)
    if suffix == ".xml":
        return read_iredes_plan(path, **kw)
    raise InputError(f"{path}: unknown drill plan format '{suffix}'; expected .csv or .xml (IREDES)")
