"""A stage's trained network as the hybrid's first start: where it comes from, and one start per boom.

``solve``, ``schedule`` (the round and its benchmark) and ``move_benchmark`` all take their network the
same way: an MLflow model URI when one is set, else ``paths.data/models/<network>.pt``; each boom of a
rig gets its own :class:`NetworkSolver`, the network checked against that boom
(:func:`pipeline.learning.network_source.load_network`), so a calibrated boom is checked too.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from pipeline.geometry.kinematics import Boom
from pipeline.learning.network_source import load_network
from pipeline.solvers.base import NetworkSolver


def network_source(data_dir: str | Path, network: str | None, model_uri: str | None) -> str | Path | None:
    """``model_uri`` if set, else ``<data_dir>/models/<network>.pt``; None when neither is set (random
    starts only)."""
    if model_uri:
        return model_uri
    return Path(data_dir) / "models" / f"{network}.pt" if network else None


def first_starts(source: str | Path | None, name: str | None, tracking_uri: str | None,
                 setting: str) -> Callable[[Boom], NetworkSolver | None]:
    """Boom -> its first start (the network at ``source`` for that boom), or None without a source.
    ``setting`` names the config key of a URI, for the error when it cannot be loaded."""

    def start(boom: Boom) -> NetworkSolver | None:
        if source is None:
            return None
        return NetworkSolver(boom, load_network(source, boom, tracking_uri, setting)[0], name or "model")

    return start
