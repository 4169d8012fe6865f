import pytest

from pipeline.core.build import build_safety, load_boom
from pipeline.core.config import load_group_file


@pytest.fixture(scope="session")
def jumbo8():
    return load_boom("jumbo8")


@pytest.fixture(scope="session")
def safety(jumbo8):
    return build_safety(jumbo8, load_group_file("tunnel", "horseshoe"), load_group_file("safety", "paper"))
