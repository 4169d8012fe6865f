"""Old import path of the IK network, kept because MLflow models logged before the package was
layered pickle the class as ``pipeline.models.IKNet``; new code imports ``pipeline.learning.models``."""

from pipeline.learning.models import IKNet, build_model, load_checkpoint, save_checkpoint

__all__ = ["IKNet", "build_model", "load_checkpoint", "save_checkpoint"]
