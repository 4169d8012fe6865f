"""Where the configs live and how plain code (not a Hydra app) loads them.

Two layouts: a checkout (``pipeline/`` beside ``conf/`` and ``dvc.yaml`` or ``pyproject.toml``), where the
configs are the checkout's ``conf/`` and relative paths are taken from the checkout's root; and an
installed wheel, where the configs are the copy the wheel carries (``pipeline/_conf/``, the same files)
and relative paths, outputs included, are taken from the current working directory."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from pipeline.core.errors import ConfigError

PROJECT_ROOT = Path(__file__).resolve().parents[2]
PACKAGED_CONF = Path(__file__).resolve().parents[1] / "_conf"  # conf/ as the wheel carries it (setup.py)


def in_checkout(root: Path = PROJECT_ROOT) -> bool:
    """Whether ``root`` (the folder above ``pipeline/``) is a checkout: its ``conf/`` and ``dvc.yaml`` or
    ``pyproject.toml`` there. An installed wheel's is ``site-packages``, which has none of them."""
    return (root / "conf").is_dir() and ((root / "dvc.yaml").is_file() or (root / "pyproject.toml").is_file())


def config_dir(root: Path = PROJECT_ROOT) -> Path:
    """The config folder: the checkout's ``conf/`` when ``root`` is a checkout, else the wheel's copy."""
    return root / "conf" if in_checkout(root) else PACKAGED_CONF


IN_CHECKOUT = in_checkout()
CONF_DIR = config_dir()


def base_dir() -> Path:
    """Where relative paths and outputs go: the checkout's root, else the current working directory."""
    return PROJECT_ROOT if IN_CHECKOUT else Path.cwd()


def main_root() -> Path:
    """The checkout whose MLflow store results belong to.

    This checkout, except inside a DVC temporary copy (``<repo>/.dvc/tmp/exps/...``), where it
    is the repository holding the copy, so experiments run there log to the same store.
    """
    if not IN_CHECKOUT:
        return base_dir()  # installed from the wheel: the current working directory
    parts = PROJECT_ROOT.parts
    for i in range(len(parts) - 2):
        if parts[i : i + 3] == (".dvc", "tmp", "exps"):
            return Path(*parts[:i])
    return PROJECT_ROOT


def project_path(path: str | Path) -> Path:
    """``path`` as given if absolute, else under this checkout (not the working directory, so
    Hydra job folders and any cwd give the same answer).

    Installed from the wheel (no checkout): under the current working directory, except a ``conf/...`` path
    that is not there but is in the wheel's copy of the configs, which is that file
    (``tunnel.file=conf/tunnel/profiles/d_5x5.csv`` works as in a checkout)."""
    path = Path(path).expanduser()
    if path.is_absolute():
        return path
    if IN_CHECKOUT:
        return PROJECT_ROOT / path
    here = base_dir() / path
    if path.parts[:1] == ("conf",) and not here.exists():
        packaged = CONF_DIR.joinpath(*path.parts[1:])
        return packaged if packaged.exists() else here
    return here


def available(group: str) -> list[str]:
    return sorted(p.stem for p in (CONF_DIR / group).glob("*.yaml"))


def as_dict(cfg) -> dict:
    """A plain dict from a DictConfig (resolved) or a mapping."""
    if isinstance(cfg, DictConfig):
        return OmegaConf.to_container(cfg, resolve=True)
    if isinstance(cfg, Mapping):
        return dict(cfg)
    raise ConfigError(f"expected a mapping, got {type(cfg).__name__}: {cfg!r}")


def compose(overrides: list[str] | None = None, config_name: str = "config") -> DictConfig:
    """Compose ``conf/<config_name>.yaml`` with overrides, outside a Hydra app (tests, notebooks)."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir

    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        return hydra_compose(config_name=config_name, overrides=list(overrides or []))


def load_group_file(group: str, name: str) -> dict:
    """Load ``conf/<group>/<name>.yaml`` as a dict, naming the options when it is missing."""
    path = CONF_DIR / group / f"{name}.yaml"
    if not path.is_file():
        rel = Path("conf", group, path.name)
        raise ConfigError(f"unknown {group} {name!r}: no {rel}; available: {available(group)}")
    return OmegaConf.to_container(OmegaConf.load(path), resolve=True)
