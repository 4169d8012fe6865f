"""Where the checker finds the configs and a relative path, as the stages do (``pipeline/core/config.py``,
which this package does not import).

In a checkout (``scripts/round_check/`` two folders below a root holding ``conf/`` and ``dvc.yaml`` or
``pyproject.toml``): the checkout's ``conf/``, relative paths from the checkout's root. Installed from the
wheel (``round_check`` beside ``pipeline`` in ``site-packages``): the configs the wheel carries
(``pipeline/_conf/``, read as files), relative paths from the current working directory, and a ``conf/...``
path that is not there is the wheel's copy of that config file.
"""

from __future__ import annotations

from pathlib import Path

_HERE = Path(__file__).resolve()
CHECKOUT = _HERE.parents[2]  # scripts/round_check/paths.py -> the checkout's root
PACKAGED_CONF = _HERE.parents[1] / "pipeline" / "_conf"  # site-packages/round_check -> site-packages/pipeline/_conf


def in_checkout(root: Path = CHECKOUT) -> bool:
    return (root / "conf").is_dir() and ((root / "dvc.yaml").is_file() or (root / "pyproject.toml").is_file())


IN_CHECKOUT = in_checkout()
CONF_DIR = CHECKOUT / "conf" if IN_CHECKOUT else PACKAGED_CONF


def base_dir() -> Path:
    """Where a relative path is taken from: the checkout's root, else the current working directory."""
    return CHECKOUT if IN_CHECKOUT else Path.cwd()


def project_path(value: str | Path, root: Path | None = None) -> Path:
    """``value`` as given if absolute, else under ``root`` (default :func:`base_dir`); outside a checkout a
    ``conf/...`` path that is not there but is in the wheel's copy of the configs is that file."""
    path = Path(value)
    if path.is_absolute():
        return path
    here = (base_dir() if root is None else root) / path
    if not IN_CHECKOUT and path.parts[:1] == ("conf",) and not here.exists():
        packaged = CONF_DIR.joinpath(*path.parts[1:])
        return packaged if packaged.exists() else here
    return here
