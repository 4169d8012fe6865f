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
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path

from pipeline.core.errors import InputError


def atomic_write(path: str | Path, write: Callable[[str], None]) -> None:
    """Call ``write(tmp_path)`` and move the result onto ``path``; on failure ``path`` is untouched."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
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


def publish(files: dict[Path, Path], lock: Path) -> None:
    """Move finished files onto their destinations, each with one atomic rename, all under one
    file lock: a set written together (a checkpoint, its history, its summary) is replaced together,
    and a concurrent writer's set never interleaves with it."""
    from filelock import FileLock

    lock.parent.mkdir(parents=True, exist_ok=True)
    with FileLock(str(lock), timeout=600):
        for src, dst in files.items():
            Path(dst).parent.mkdir(parents=True, exist_ok=True)
            os.replace(src, dst)


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
