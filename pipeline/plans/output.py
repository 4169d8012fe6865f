"""A result's files as one set (a solution, an as-drilled quality report): ``<name>.csv``, ``<name>.json`` and
``<name>.png``.

Checked before any work (never the plan itself, never a name that collides with the set's own
derived names, never an existing folder), written into a private staging folder, then published
together by renames under one lock (:func:`pipeline.core.io.publish`): a reader that takes the lock
(:func:`read_solution_set`) sees one run's set, never a mix, and a failure while writing (a full
disk) leaves the previous set whole. The summary holds the MD5 of the CSV and the figure, so any
reader can check the three belong together. Staging folders of killed runs are removed by the next.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from pipeline.core.errors import InputError
from pipeline.core.io import file_md5, publish, same_file, save_figure, staged_folder, write_csv, write_json
from pipeline.plans.solutions import spreadsheet_safe


@dataclass(frozen=True)
class SolutionPaths:
    csv: Path
    json: Path
    png: Path

    @property
    def lock(self) -> Path:
        return self.csv.with_name(f".{self.csv.name}.lock")

    def all(self) -> tuple[Path, Path, Path]:
        return self.csv, self.json, self.png


def solution_paths(plan_path: str | Path, out: str | Path | None, kind: str = "solution",
                   inputs: tuple[Path, ...] = ()) -> SolutionPaths:
    """The set for ``out`` (default ``<plan stem>_<kind>.csv`` beside the plan: a solution, an as-drilled
    quality report), checked: raises :class:`InputError` naming ``out`` when it is not a ``.csv`` name (its
    ``.json`` / ``.png`` siblings are the summary and the figure, so any other suffix collides with one of
    them), when a file of the set is the plan or another of the ``inputs`` (after resolving paths and
    links), or when one is a folder."""
    plan_path = Path(plan_path)
    out = Path(out) if out is not None else plan_path.with_name(f"{plan_path.stem}_{kind}.csv")
    if out.is_dir():
        raise InputError(f"out = {out}: an existing folder; give the solution's file name, e.g. "
                         f"out={out / (plan_path.stem + '_solution.csv')}")
    if out.suffix.lower() != ".csv":
        raise InputError(f"out = {out}: expected a .csv file name; the summary ({out.stem}.json) and the figure "
                         f"({out.stem}.png) are written beside it, so '{out.suffix or 'no suffix'}' would collide "
                         "with them or hide the table")
    paths = SolutionPaths(out, out.with_suffix(".json"), out.with_suffix(".png"))
    for p in paths.all():
        for given, what in ((plan_path, "the drill plan"), *((i, "the input") for i in inputs)):
            if same_file(p, given):
                raise InputError(f"out = {out}: {p} is {what} {given} itself; refusing to overwrite an input "
                                 "(choose another out=)")
        if p.is_dir():
            raise InputError(f"out = {out}: {p} is an existing folder; the solution's set needs that name")
        if p.parent.exists() and not p.parent.is_dir():
            raise InputError(f"out = {out}: {p.parent} is a file, not a folder")
    return paths


def write_solution_set(paths: SolutionPaths, table: pd.DataFrame, summary: dict, figure=None,
                       log_staged: Callable[[dict[str, Path]], None] | None = None) -> dict:
    """Stage the CSV (spreadsheet-safe), the figure (``None``: none, and an old one is removed) and
    the summary (with the MD5 of the other two), call ``log_staged`` with the staged files (MLflow
    logs them from there), then publish the set under its lock. Returns the summary as written."""
    with staged_folder(paths.csv.parent, paths.csv.name) as stage:
        staged = {"csv": stage / paths.csv.name, "json": stage / paths.json.name, "png": stage / paths.png.name}
        write_csv(spreadsheet_safe(table), staged["csv"])
        files = {"csv": file_md5(staged["csv"])}
        if figure is not None:
            save_figure(figure, staged["png"])
            files["png"] = file_md5(staged["png"])
        else:
            del staged["png"]
        summary = {**summary, "files": {getattr(paths, k).name: md5 for k, md5 in files.items()}}
        write_json(summary, staged["json"])
        if log_staged is not None:
            log_staged(staged)
        publish({staged[k]: getattr(paths, k) for k in staged}, paths.lock,
                 remove=() if figure is not None else (paths.png,))
    return summary


def read_solution_set(out: str | Path) -> tuple[pd.DataFrame, dict]:
    """The solution table and its summary, read under the set's lock and checked to be one set
    (the MD5s the summary names): for scripts that read while solves may run."""
    from filelock import FileLock

    out = Path(out)
    paths = SolutionPaths(out, out.with_suffix(".json"), out.with_suffix(".png"))
    with FileLock(str(paths.lock), timeout=600):
        summary = json.loads(paths.json.read_text())
        for name, md5 in summary.get("files", {}).items():
            if file_md5(out.with_name(name)) != md5:
                raise InputError(f"{out.with_name(name)}: not the file {paths.json} describes (MD5 differs)")
        table = pd.read_csv(paths.csv, keep_default_na=False)
    return table, summary
