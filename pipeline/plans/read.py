"""A drill plan from a file, by its suffix: CSV or IREDES XML."""

from __future__ import annotations

from pathlib import Path

from pipeline.core.errors import InputError
from pipeline.plans.csv_plan import read_csv_plan
from pipeline.plans.iredes import read_iredes_plan
from pipeline.plans.model import DrillPlan

MAX_PLAN_MB = 256.0  # a round has hundreds of holes; 1e5 holes of CSV are ~10 MB, of IREDES ~60 MB


def read_plan(path: str | Path, max_mb: float = MAX_PLAN_MB, **kw) -> DrillPlan:
    """A CSV (``.csv``) or IREDES (``.xml``) plan; ``kw`` goes to the reader. A file over ``max_mb``
    (``solve.max_plan_mb``) is refused before it is read: readers hold a few times the file in memory."""
    path = Path(path)
    suffix = path.suffix.lower()
    if path.is_file() and path.stat().st_size > max_mb * 1e6:
        raise InputError(f"{path}: {path.stat().st_size / 1e6:.1f} MB, over solve.max_plan_mb = {max_mb:g} MB; "
                         "split the plan, or raise solve.max_plan_mb")
    if suffix == ".csv":
        return read_csv_plan(path, **kw)
    if suffix == ".xml":
        return read_iredes_plan(path, **kw)
    raise InputError(f"{path}: unknown drill plan format '{suffix}'; expected .csv or .xml (IREDES)")
