"""Shared fixtures: the reference boom and safety model, and config composition (as the stages see it)."""

from pathlib import Path

import pytest

from pipeline.assembly.build import build_safety, load_boom
from pipeline.core.config import compose, load_group_file


@pytest.fixture(scope="session")
def jumbo8():
    return load_boom("jumbo8")


@pytest.fixture(scope="session")
def safety(jumbo8):
    return build_safety(jumbo8, load_group_file("tunnel", "horseshoe"), load_group_file("safety", "paper"))


@pytest.fixture(scope="session")
def make_cfg():
    """``make_cfg(tmp, *overrides)``: the quick experiment writing data, MLflow store and artifacts under
    ``tmp``, so a test never touches the checkout's own ``data/`` or ``mlflow.db``."""

    def make(tmp: Path, *overrides: str):
        return compose(["experiment=quick", f"paths.data={tmp}/data", f"tracking.uri=sqlite:///{tmp}/mlflow.db",
                        f"tracking.artifact_root={tmp}/artifacts", *overrides])

    return make
