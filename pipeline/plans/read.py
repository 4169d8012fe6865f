"""A drill plan from a file, by its suffix: CSV or IREDES XML; and as the product stages read it, taken
into the rig frame by the navigation."""

from __future__ import annotations

from pathlib import Path

from pipeline.core.config import project_path
from pipeline.core.errors import InputError
from pipeline.plans.csv_plan import read_csv_plan
from pipeline.plans.iredes import read_iredes_plan
from pipeline.plans.model import DrillPlan
from pipeline.plans.navigation import NavigationSettings, in_rig_frame, rig_pose

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


def read_plan_in_rig_frame(path: str | Path, navigation: NavigationSettings, iredes: dict | None = None,
                           max_mb: float = MAX_PLAN_MB) -> DrillPlan:
    """The plan the product stages (solve, schedule, execute, move_benchmark) work on: read (an IREDES file
    with the ``solve.iredes`` settings ``iredes``), then taken into the rig frame by ``navigation`` (its
    pose, or the fit of its reference points, checked before the plan is read). ``plan.navigation`` holds
    the pose, so what goes back to the plan is taken back into its frame."""
    pose = rig_pose(navigation, project_path)
    path = Path(path)
    xml = path.suffix.lower() == ".xml"
    plan = read_plan(path, max_mb, **((iredes or {}) if xml else {}))
    return in_rig_frame(plan, pose)
