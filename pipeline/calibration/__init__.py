"""Kinematic error compensation (paper 004): a boom with per-joint geometric errors,
simulated and field measurements, the paper's BP / PSO-BP / SSA-BP compensation networks, and
identification of the errors by Levenberg-Marquardt with an identifiability check.

Modules, one job each: ``error_model`` (error twists, :class:`BoomWithErrors`), ``measurements``
(simulate / read), ``swarm`` (batched PSO and sparrow search), ``compensation`` (the networks),
``identification`` (basis, fit), ``ik`` (nominal NM from a start), ``model_file`` (save / load).
"""

from pipeline.calibration.error_model import BoomWithErrors, ErrorLevel, draw_errors
from pipeline.calibration.model_file import load_model, save_model

__all__ = ["BoomWithErrors", "ErrorLevel", "draw_errors", "load_model", "save_model"]
