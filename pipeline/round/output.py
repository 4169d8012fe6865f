"""The round's files as one set, checked before any work and published whole.

``<stem>_round.csv`` (the round table), ``<stem>_trajectory.csv`` (docs/reference.md, section 7), ``<stem>_round.json``
(the summary), ``<stem>_problem.npz`` (what it was planned on: each boom's joints per hole, who can
drill what), ``<stem>_round_face.png``, ``<stem>_round_gantt.png`` and ``<stem>_round_replay.html``;
for every rig also ``<stem>_actions.csv`` and ``<stem>_interlocks.csv`` (docs/reference.md, section 8),
``<stem>_round_executed.png`` (realised makespans) and ``<stem>_round_executed_replay.html`` (the
slowest drawn round, executed by events).

- **Before any work** (:func:`round_paths`): ``out`` is a folder or a ``<stem>_round.csv`` (or
  ``<stem>.csv``) name; no file of the set may be an input (the drill plan, after resolving links and
  hard links: ``plan=P_trajectory.csv out=P.csv`` is refused), an existing folder, or sit below a file.
- **Published whole** (:func:`write_round_set`): every file is written into a private staging folder
  beside the destination, the summary last with the MD5 of each sibling (its ``files`` key: the
  manifest that tells a reader which files belong to it), then all are moved in by renames under one
  lock, the summary last; files of an earlier set that this one does not write (figures off, replay
  off) are removed under the same lock, so no stale sibling is read as part of the new set.

The executed round (``python -m pipeline.execute``) is a set of its own, ``EXECUTED`` (``<stem>_executed*``
and ``<stem>_draws.csv``), beside the planned one and written the same way; the planned files are its
inputs, so it can never overwrite them.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

from pipeline.core.errors import InputError
from pipeline.core.io import file_md5, publish, same_file, staged_folder, write_json

SUFFIXES = {"round": "_round.csv", "trajectory": "_trajectory.csv", "json": "_round.json",
            "face": "_round_face.png", "gantt": "_round_gantt.png", "replay": "_round_replay.html",
            # executed by events (docs/reference.md, section 8): the actions and interlocks files, realised makespans
            "actions": "_actions.csv", "interlocks": "_interlocks.csv", "executed": "_round_executed.png",
            "zones": "_zones.csv",  # docs/reference.md, section 9: its header alone when the round has no zone
            "executed_replay": "_round_executed_replay.html",
            "moves": "_moves.npz",  # the planner's move book, re-used by a round handed on (round/move_file.py)
            "problem": "_problem.npz"}  # what the round was planned on, loaded by execute (round/problem_file.py)
# the executed round (pipeline.execute): realised files, the draws, and the figures
EXECUTED = {"round": "_executed_round.csv", "trajectory": "_executed_trajectory.csv", "json": "_executed.json",
            "actions": "_executed_actions.csv", "interlocks": "_executed_interlocks.csv",
            "zones": "_executed_zones.csv",
            "draws": "_draws.csv", "makespans": "_executed_makespans.png", "replay": "_executed_replay.html",
            # an IREDES plan's holes as the execute stage read them, as CSV: the independent checker's plan
            "plan": "_executed_plan.csv",
            # the as-drilled log: IREDES DRPQual, each hole where the rig's real boom drilled it (plan frame)
            "quality": "_executed_quality.xml"}


@dataclass(frozen=True)
class RoundPaths:
    folder: Path
    stem: str
    suffixes: Mapping[str, str] = field(default_factory=lambda: SUFFIXES)

    def __getitem__(self, kind: str) -> Path:
        return self.folder / f"{self.stem}{self.suffixes[kind]}"

    def all(self) -> dict[str, Path]:
        return {k: self[k] for k in self.suffixes}

    @property
    def tag(self) -> str:
        return f"{self.stem}{self.suffixes['json'].removesuffix('.json')}"

    @property
    def lock(self) -> Path:
        return self.folder / f".{self.tag}.lock"


def round_paths(plan_path: str | Path, out: str | Path | None, inputs: Iterable[str | Path] = (),
                suffixes: Mapping[str, str] = SUFFIXES) -> RoundPaths:
    """The set for ``out`` (default: beside the plan, named after it), checked before any work.

    ``out``: a folder (an existing one, or a name without a suffix, created) or the round table's name
    (``<stem>_round.csv``, or ``<stem>.csv``: the set is then ``<stem>_round.csv``, ...). Raises
    :class:`InputError` naming ``out`` for any other suffix (``out=x.json`` would make a folder
    ``x.json``), and when a file of the set is the plan or one of ``inputs``, an existing folder, or
    below a file."""
    plan_path = Path(plan_path)
    if out is None or str(out) == "":
        paths = RoundPaths(plan_path.parent, plan_path.stem, suffixes)
    else:
        o = Path(out)
        if o.is_dir() or str(out).endswith(("/", "\\")) or (o.suffix == "" and not o.exists()):
            paths = RoundPaths(o, plan_path.stem, suffixes)
        elif o.suffix.lower() == ".csv":
            name = o.name[: -len(".csv")]
            paths = RoundPaths(o.parent, name.removesuffix("_round") or name, suffixes)
        else:
            raise InputError(f"out = {out}: expected a folder or the round table's name (<stem>_round.csv); the "
                             f"set's other files ({', '.join(suffixes.values())}) are named after it, so "
                             f"'{o.suffix or o.name}' would collide with them or make a folder of that name")
    if paths.folder.exists() and not paths.folder.is_dir():
        raise InputError(f"out = {out}: {paths.folder} is a file, not a folder")
    protected = [plan_path, *map(Path, inputs)]
    for kind, p in paths.all().items():
        for src in protected:
            if same_file(p, src):
                raise InputError(f"out = {out}: the round's {kind} file {p} is the input {src} itself; "
                                 "refusing to overwrite an input (choose another out=)")
        if p.is_dir():
            raise InputError(f"out = {out}: {p} is an existing folder; the round's {kind} file needs that name")
    return paths


def write_round_set(paths: RoundPaths, summary: dict, writers: Mapping[str, Callable[[Path], None]],
                    log_staged: Callable[[dict[str, Path]], None] | None = None,
                    check: Callable[[dict[str, Path]], dict] | None = None) -> dict:
    """Stage every file ``writers`` names (kind -> ``write(path)``), then the summary with the MD5 of
    each (``files``); call ``check`` (kind -> staged path, the summary's among them) and put the keys it
    returns into the summary, written again in the stage; call ``log_staged`` (kind -> staged path: MLflow
    logs from there), and publish the set under its lock; an earlier set's files of kinds not written are
    removed. Returns the summary. Whatever ``check`` raises (a check that could not run, an interrupt)
    publishes nothing: the previous set stays as it was and the stage is removed."""
    unknown = (set(writers) - set(paths.suffixes)) | (set(writers) & {"json"})  # the summary is written here, last
    if unknown:
        raise ValueError(f"write_round_set: not a file of the set written by a writer: {sorted(unknown)}")
    paths.folder.mkdir(parents=True, exist_ok=True)
    with staged_folder(paths.folder, paths.tag) as stage:
        staged = {}
        for kind, write in writers.items():
            staged[kind] = stage / paths[kind].name
            write(staged[kind])
        summary = {**summary, "files": {paths[k].name: file_md5(p) for k, p in staged.items()}}
        staged["json"] = stage / paths["json"].name
        write_json(summary, staged["json"])
        if check is not None:  # on the staged files: nothing is published that was not checked
            more = check(dict(staged))
            if more:
                summary = {**summary, **more}
                write_json(summary, staged["json"])
        if log_staged is not None:
            log_staged(dict(staged))
        stale = [p for k, p in paths.all().items() if k not in staged]
        publish({p: paths[k] for k, p in staged.items()}, paths.lock, remove=stale)  # the summary last
    return summary
