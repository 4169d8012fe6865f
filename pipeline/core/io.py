"""Writes that land whole or not at all: a temporary file in the same folder, then a rename.

Every file a user or a later stage reads (tables, JSON, figures, checkpoints) goes through here, so
an interrupted stage never leaves a half-written file behind. JSON is strict: NaN and infinity
are not JSON, so a non-finite value is refused with the file and the key that holds it.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
import shutil
import tempfile
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

from pipeline.core.errors import InputError
from pipeline.core.signals import raise_if_terminated


def atomic_write(path: str | Path, write: Callable[[str], None]) -> None:
    """Call ``write(tmp_path)`` and move the result onto ``path``; on failure ``path`` is untouched."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # The writer's pid and start time in the name: a later run can tell a kill -9's leftover (remove_stale_temps).
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.{process_token()}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        write(tmp)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; give the file the usual mode
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _non_finite_key(obj, where: str = "") -> str | None:
    """The dotted key of the first NaN or infinity in ``obj``, or None."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return where or "<top level>"
    items = obj.items() if isinstance(obj, dict) else enumerate(obj) if isinstance(obj, (list, tuple)) else ()
    for key, value in items:
        found = _non_finite_key(value, f"{where}.{key}" if where else str(key))
        if found:
            return found
    return None


def json_text(obj, where: str = "JSON") -> str:
    """Strict JSON (``allow_nan=False``), with the offending key named when a value is not finite."""
    try:
        return json.dumps(obj, indent=2, sort_keys=True, allow_nan=False) + "\n"
    except ValueError:
        raise InputError(f"{where}: value at '{_non_finite_key(obj)}' is not finite (NaN or infinity); "
                         "refusing to write invalid JSON") from None


def write_json(obj, path: str | Path) -> None:
    text = json_text(obj, str(path))
    atomic_write(path, lambda tmp: Path(tmp).write_text(text))


def write_text(text: str, path: str | Path) -> None:
    atomic_write(path, lambda tmp: Path(tmp).write_text(text))


def write_csv(df, path: str | Path) -> None:
    """A pandas DataFrame as CSV, without the index."""
    atomic_write(path, lambda tmp: df.to_csv(tmp, index=False))


def write_parquet(df, path: str | Path) -> None:
    atomic_write(path, lambda tmp: df.to_parquet(tmp, index=False, engine="pyarrow"))


def copy_file(src: str | Path, dst: str | Path) -> None:
    atomic_write(dst, lambda tmp: shutil.copyfile(src, tmp))


def save_figure(fig, path: str | Path, dpi: int = 120) -> None:
    """A matplotlib figure as PNG."""
    atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=dpi, format="png"))


def file_md5(path: str | Path) -> str:
    """MD5 of a file's bytes: what DVC 3 records for a file, so MLflow and DVC name data alike."""
    h = hashlib.md5()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def same_file(a: Path, b: Path) -> bool:
    """Whether two paths name one file (after resolving links, or as hard links of one file)."""
    a, b = Path(a), Path(b)
    if a.resolve() == b.resolve():
        return True
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)  # hard links
    except OSError:
        return False


def publish(files: dict[Path, Path], lock: Path, remove: Iterable[Path] = (), folders: dict[Path, Path] | None = None
            ) -> None:
    """Move finished files onto their destinations, each with one atomic rename, all under one
    file lock: a set written together (a checkpoint, its history, its summary) is replaced together,
    and a concurrent writer's set never interleaves with it. ``remove``: files of an earlier set that
    this set has no counterpart for (they would be read as part of it), deleted under the same lock.
    ``folders``: finished folders that replace their destinations whole (the earlier folder is renamed
    aside first and deleted after), under the same lock, before the files."""
    from filelock import FileLock

    folders = folders or {}
    lock.parent.mkdir(parents=True, exist_ok=True)
    in_the_way = [str(dst) for dst in files.values() if Path(dst).is_dir() and not Path(dst).is_symlink()]
    in_the_way += [str(dst) for dst in folders.values() if Path(dst).exists() and not Path(dst).is_dir()]
    if in_the_way:  # checked before the first rename: a set is published whole or not at all
        raise InputError(f"cannot publish: {', '.join(in_the_way)} is in the way; the set needs that name")
    raise_if_terminated()  # a signal whose exception a library swallowed (a native solver's callback) stops it here
    with FileLock(str(lock), timeout=600):
        aside = []
        for src, dst in folders.items():
            dst = Path(dst)
            dst.parent.mkdir(parents=True, exist_ok=True)
            if dst.is_dir():
                old = dst.with_name(f".{dst.name}.{process_token()}.old.tmp")  # a stale temp if killed here
                os.replace(dst, old)
                aside.append(old)
            os.replace(src, dst)
        for src, dst in files.items():
            Path(dst).parent.mkdir(parents=True, exist_ok=True)
            os.replace(src, dst)
        for old in remove:
            Path(old).unlink(missing_ok=True)
        for old in aside:
            shutil.rmtree(old, ignore_errors=True)


def publish_lock(folder: Path, name: str) -> Path:
    """The lock that serialises publishing ``name`` into ``folder`` (:func:`publish`): in the temporary
    folder, keyed by the destination, so no lock file is left among the outputs (removing it after use
    would not be safe: a waiting process may hold it open)."""
    key = hashlib.sha1(str(folder.resolve()).encode()).hexdigest()[:16]
    return Path(tempfile.gettempdir()) / "boom-ik-locks" / f"{key}-{name}.lock"


# ---------------------------------------------------------------------------------------------
# Temporary files that name their writer, so a later run can remove those of dead processes

_TOKEN: dict[int, str] = {}
# .<name>.<pid>-<start ms>.<random or "stage">.tmp: atomic_write's files and staged_folder's folders
_TEMP_NAME = re.compile(r"^\..+\.(?P<pid>\d+)-(?P<start>\d+)\.[A-Za-z0-9_]+\.tmp$")


def process_token() -> str:
    """``<pid>-<process start time, ms>``: a pid alone is reused, the pair names one process."""
    pid = os.getpid()
    if pid not in _TOKEN:  # per pid: a forked child is another writer
        import psutil

        _TOKEN[pid] = f"{pid}-{int(psutil.Process(pid).create_time() * 1000)}"
    return _TOKEN[pid]


def process_alive(pid: int, start_s: float | None = None) -> bool:
    """Whether process ``pid`` runs and, when ``start_s`` is given, is the one started then."""
    import psutil

    try:
        proc = psutil.Process(pid)
        return start_s is None or abs(proc.create_time() - float(start_s)) < 0.01  # a reused pid is another process
    except (psutil.NoSuchProcess, ValueError):
        return False


def remove_stale_temps(folder: str | Path) -> list[Path]:
    """Delete the temporary files and staging folders in ``folder`` whose writer (on this host) is
    gone, e.g. killed with ``kill -9`` mid-write; a live writer's are left alone. Returns them."""
    folder = Path(folder)
    removed = []
    for entry in folder.iterdir() if folder.is_dir() else ():
        m = _TEMP_NAME.match(entry.name)
        if m and not process_alive(int(m["pid"]), int(m["start"]) / 1000):
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry, ignore_errors=True)
            else:
                entry.unlink(missing_ok=True)
            removed.append(entry)
    return removed


@contextmanager
def staged_folder(folder: str | Path, name: str) -> Iterator[Path]:
    """A private folder ``.<name>.<pid>-<start>.stage.tmp`` inside ``folder`` (same file system, so
    its files can be published by rename), removed on the way out; stale ones of dead runs first."""
    folder = Path(folder)
    remove_stale_temps(folder)
    stage = folder / f".{name}.{process_token()}.stage.tmp"
    shutil.rmtree(stage, ignore_errors=True)
    stage.mkdir(parents=True)
    try:
        yield stage
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def require_writable(folder: Path, what: str, error: type[ValueError] = InputError) -> Path:
    """Create ``folder`` if needed and check it can be written, before any long work."""
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise error(f"{what} = {folder}: cannot create the folder ({exc.strerror})") from None
    if not os.access(folder, os.W_OK | os.X_OK):
        raise error(f"{what} = {folder}: the folder is not writable")
    return folder
