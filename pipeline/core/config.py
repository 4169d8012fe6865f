"""Where the configs live and how plain code (not a Hydra app) loads them."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from pipeline.core.errors import ConfigError

PROJECT_ROOT = Path(__file__).resolve().parents[2]
CONF_DIR = PROJECT_ROOT / "conf"


def main_root() -> Path:
    """The checkout whose MLflow store results belong to.

    This checkout, except inside a DVC temporary copy (``<repo>/.dvc/tmp/exps/...``), where it
    is the repository holding the copy, so experiments run there log to the same store.
    """
    parts = PROJECT_ROOT.parts
    for i in range(len(parts) - 2):
        if parts[i : i + 3] == (".dvc", "tmp", "exps"):
            return Path(*parts[:i])
    return PROJECT_ROOT


def project_path(path: str | Path) -> Path:
    """``path`` as given if absolute, else under this checkout (not the working directory, so
    Hydra job folders and any cwd give the same answer)."""
    path = Path(path).expanduser()
    return path if path.is_absolute() else PROJECT_ROOT / path


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
        rel = path.relative_to(PROJECT_ROOT)
        raise ConfigError(f"unknown {group} {name!r}: no {rel}; available: {available(group)}")
    return OmegaConf.to_container(OmegaConf.load(path), resolve=True)
