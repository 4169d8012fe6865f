"""Write ``params.yaml``: ``conf/`` composed and resolved, exactly as DVC's Hydra composition does.

``dvc exp run`` rewrites params.yaml itself (``hydra.enabled`` is on). Plain ``dvc repro`` reads
the committed file, so after editing ``conf/`` run::

    python -m pipeline.params [override ...]

A test keeps the committed params.yaml equal to the composition of ``conf/``.
"""

from __future__ import annotations

import sys

from omegaconf import OmegaConf

from pipeline.core.config import base_dir, compose
from pipeline.core.io import write_text


def composed_yaml(overrides: list[str] | None = None) -> str:
    cfg = compose(overrides)
    OmegaConf.resolve(cfg)
    return OmegaConf.to_yaml(cfg)


def main(argv: list[str] | None = None) -> None:
    write_text(composed_yaml(list(sys.argv[1:] if argv is None else argv)), base_dir() / "params.yaml")


if __name__ == "__main__":
    main()
