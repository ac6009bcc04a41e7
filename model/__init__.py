"""LSS-fisheye BEV segmentation model (see README.md, "Model and training")."""

from .checkpoint import CheckpointError, build_model, load_checkpoint, save_checkpoint

__all__ = ["build_model", "load_checkpoint", "save_checkpoint", "CheckpointError"]
