"""Reading a round's files, refusing what cannot be judged (:class:`InputError`, exit 2).

Rows are named by file line (the header is line 1). The trajectory file is docs/reference.md section 7's: columns
``boom, t, q1 .. q8, event, hole_id``, each boom's rows in strictly increasing t.

Sizes are bounded before a file is parsed, so a malformed file is named, never a reason to run out of
memory: a CSV over :data:`MAX_CSV_MB`, a line over :data:`MAX_LINE_BYTES` (a 200 MB cell once took the
checker to 8.9 GB: text columns become fixed-width numpy strings, rows x longest cell), a used column's
cell over :data:`MAX_CELL_CHARS`, a round JSON over :data:`MAX_JSON_MB`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from .errors import InputError

MAX_CSV_MB = 256.0  # a CSV input (trajectory, round table, plan, actions, draws, ...): far above any round's
MAX_LINE_BYTES = 64 * 1024  # one CSV line; a trajectory row is ~200 bytes
MAX_CELL_CHARS = 256  # one cell of a column the checker uses (ids, events, numbers)
MAX_JSON_MB = 64.0  # the round JSON; a round's is tens of kB

EVENTS = {"park", "move", "move_unclear", "collar", "drill", "retract", "wait", "done"}
HOLE_EVENTS = ("collar", "drill", "retract")
ROUND_COLUMNS = ["hole_id", "boom", "t_start", "t_end", "status"]
PLAN_COLUMNS = ["hole_id", "collar_x", "collar_y", "collar_z", "toe_x", "toe_y", "toe_z"]
STATUSES = {"ok", "unreachable", "invalid"}
INTERRUPTED = "interrupted"  # a realised round's hole its boom stopped (reference, section 8): realised sets only
TIMED = ("ok", INTERRUPTED)  # statuses whose rows carry the drilling's times


@dataclass
class BoomRows:
    t: np.ndarray  # (n,)
    q: np.ndarray  # (n, joints) rad / m, as written (full-turn joints may be unwrapped)
    event: np.ndarray  # (n,) str
    hole: np.ndarray  # (n,) str
    line: np.ndarray  # (n,) file line of each row


def _longest_line(path: Path) -> tuple[int, int]:
    """(length in bytes, 1-based line number) of the file's longest line, read in blocks (no line held whole)."""
    longest, at, line, run = 0, 1, 1, 0
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            parts = block.split(b"\n")
            for k, part in enumerate(parts):
                run += len(part)
                if k < len(parts) - 1:  # a line ends here
                    if run > longest:
                        longest, at = run, line
                    line, run = line + 1, 0
    if run > longest:
        longest, at = run, line
    return longest, at


def check_size(path: Path, what: str, max_mb: float | None = None, lines: bool = True) -> None:
    """Refuse (naming the file, and the line) a file too large to judge, before it is parsed (``max_mb``:
    default :data:`MAX_CSV_MB`)."""
    max_mb = MAX_CSV_MB if max_mb is None else max_mb
    size = path.stat().st_size
    if size > max_mb * 1e6:
        raise InputError(f"{path}: {size / 1e6:.1f} MB, over the checker's {max_mb:g} MB for a {what}; not read")
    if lines:
        n, line = _longest_line(path)
        if n > MAX_LINE_BYTES:
            raise InputError(f"{path}: line {line} is {n} bytes long, over the checker's {MAX_LINE_BYTES} for a "
                             f"{what} line; not read")


def _table(path: Path, what: str) -> pd.DataFrame:
    if not path.is_file():
        raise InputError(f"{path}: no such {what}")
    check_size(path, what)
    try:
        df = pd.read_csv(path, dtype=str, keep_default_na=False)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: not a readable CSV {what}: {' '.join(str(e).split())}") from None
    df.columns = [str(c).strip() for c in df.columns]
    return df


def _require(df: pd.DataFrame, cols, path: Path) -> None:
    """The columns ``cols`` are there, and none of their cells is longer than :data:`MAX_CELL_CHARS`."""
    missing = [c for c in cols if c not in df.columns]
    if missing:
        raise InputError(f"{path}: missing column(s) {missing}; found {list(df.columns)}"[:2000])
    for c in cols:
        n = df[c].str.len().to_numpy()
        if len(n) and n.max() > MAX_CELL_CHARS:
            i = int(n.argmax())
            raise InputError(f"{path}: row {i + 2}: the {c} cell is {int(n[i])} characters long, over the checker's "
                             f"{MAX_CELL_CHARS}: not a value of that column")


def _numbers(df: pd.DataFrame, cols, path: Path, who: pd.Series | None = None,
             lines: np.ndarray | None = None) -> np.ndarray:
    """``(n, len(cols))`` floats; a missing, unreadable or non-finite cell is an error naming its row
    (``lines``: the file line of each row of a filtered ``df``; else row i is line i + 2)."""
    vals = np.stack([pd.to_numeric(df[c].str.strip(), errors="coerce").to_numpy(float) for c in cols], -1)
    bad = ~np.isfinite(vals)
    if bad.any():
        i, j = np.argwhere(bad)[0]
        boom = f"boom {who.iloc[i]!r}, " if who is not None else ""
        line = int(lines[i]) if lines is not None else i + 2
        raise InputError(f"{path}: {boom}row {line}: {cols[j]} = {df[cols[j]].iloc[i]!r} is not a finite number"
                         f" ({int(bad.any(1).sum())} such row(s))")
    return vals


def read_trajectory(path: Path, booms: dict[str, list[str]]) -> dict[str, BoomRows]:
    """Each rig boom's rows; ``booms``: name -> joint names (every rig boom must have rows)."""
    df = _table(path, "trajectory file")
    joints = list(dict.fromkeys(j for names in booms.values() for j in names))
    _require(df, ["boom", "t", *joints, "event", "hole_id"], path)
    if df.empty:
        raise InputError(f"{path}: no rows")
    name = df["boom"].str.strip()
    unknown = ~name.isin(list(booms))
    if unknown.any():
        i = int(np.flatnonzero(unknown)[0])
        raise InputError(f"{path}: row {i + 2}: boom {name.iloc[i]!r} is not a boom of the rig {sorted(booms)}")
    missing = [b for b in booms if not (name == b).any()]
    if missing:
        raise InputError(f"{path}: no rows for boom(s) {missing} of the rig {sorted(booms)}")
    vals = _numbers(df, ["t", *joints], path, name)
    event = df["event"].str.strip().to_numpy(str)
    hole = df["hole_id"].str.strip().to_numpy(str)
    bad = ~np.isin(event, sorted(EVENTS))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise InputError(f"{path}: boom {name.iloc[i]!r}, row {i + 2}: event {event[i]!r} is not one of "
                         f"{sorted(EVENTS)}")
    nameless = np.isin(event, HOLE_EVENTS) & (hole == "")
    if nameless.any():
        i = int(np.flatnonzero(nameless)[0])
        raise InputError(f"{path}: boom {name.iloc[i]!r}, row {i + 2}: a {event[i]} row without hole_id")
    out = {}
    for b, names in booms.items():
        idx = np.flatnonzero((name == b).to_numpy())
        t = vals[idx, 0]
        step = np.diff(t)
        if (step <= 0).any():
            k = int(np.flatnonzero(step <= 0)[0])
            what = "repeats the time of" if step[k] == 0 else "goes back in time from"
            raise InputError(f"{path}: boom {b!r}, row {idx[k + 1] + 2}: t = {t[k + 1]!r} {what} its previous row "
                             f"(row {idx[k] + 2}, t = {t[k]!r}); a boom's rows must be in strictly increasing t")
        q = vals[idx][:, [1 + joints.index(j) for j in names]]
        out[b] = BoomRows(t, q, event[idx], hole[idx], idx + 2)
    return out


def read_round_table(path: Path, realised: bool = False) -> pd.DataFrame:
    """The round table; ``realised``: an executed round's, where a hole may also be ``interrupted``."""
    df = _table(path, "round table")
    _require(df, ROUND_COLUMNS, path)
    df = df.assign(hole_id=df["hole_id"].str.strip(), boom=df["boom"].str.strip(), status=df["status"].str.strip())
    allowed = sorted(STATUSES | ({INTERRUPTED} if realised else set()))
    bad = ~df["status"].isin(allowed)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        hint = " (an executed round's status: check it with --realised)" if df["status"].iloc[i] == INTERRUPTED else ""
        raise InputError(f"{path}: row {i + 2}: status {df['status'].iloc[i]!r} is not one of {allowed}{hint}")
    dup = df["hole_id"].duplicated(keep=False)
    if dup.any():
        raise InputError(f"{path}: hole(s) {sorted(set(df['hole_id'][dup]))} listed more than once")
    ok = df["status"].isin(TIMED).to_numpy()
    times = _numbers(df[ok], ["t_start", "t_end"], path, lines=np.flatnonzero(ok) + 2)
    df["t_start_s"], df["t_end_s"] = np.nan, np.nan
    df.loc[ok, "t_start_s"], df.loc[ok, "t_end_s"] = times[:, 0], times[:, 1]
    return df


def read_summary(path: Path) -> dict:
    if not path.is_file():
        raise InputError(f"{path}: no such round JSON")
    check_size(path, "round JSON", MAX_JSON_MB, lines=False)
    try:
        doc = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as e:
        raise InputError(f"{path}: not readable JSON: {e}") from None
    if not isinstance(doc, dict):
        raise InputError(f"{path}: expected a JSON object")
    m = doc.get("makespan_s")
    if isinstance(m, bool) or not isinstance(m, (int, float)) or not np.isfinite(m):
        raise InputError(f"{path}: makespan_s = {m!r}: expected a finite number")
    return doc


@dataclass
class Plan:
    ids: list[str]
    collar: np.ndarray  # (n, 3), NaN on rows that do not read as numbers (the round table's `invalid`)
    toe: np.ndarray


def read_plan(path: Path) -> Plan:
    """A CSV drill plan (``hole_id``, collar and toe x y z in the rig frame, m); an unreadable row keeps
    NaN coordinates: the planner reports such a row as ``invalid`` and does not drill it."""
    if path.suffix.lower() == ".xml":
        raise InputError(f"{path}: an IREDES plan; the independent checker reads CSV plans only: pass the same holes "
                         "as CSV with --plan (the execute stage writes them into its set: <stem>_executed_plan.csv)")
    df = _table(path, "drill plan")
    _require(df, PLAN_COLUMNS, path)
    ids = df["hole_id"].str.strip()
    dup = ids.duplicated(keep=False) & (ids != "")
    if dup.any():
        raise InputError(f"{path}: hole id(s) {sorted(set(ids[dup]))} appear more than once")
    xyz = np.stack([pd.to_numeric(df[c].str.strip(), errors="coerce").to_numpy(float) for c in PLAN_COLUMNS[1:]], -1)
    return Plan(ids.tolist(), xyz[:, :3], xyz[:, 3:])
