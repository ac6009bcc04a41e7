"""LSS-fisheye BEV segmentation model (see docs/model.md).

    from model import build_model, load_checkpoint, load_config
    cfg = load_config("configs/train/cpu_default.yaml"); model = build_model(cfg, rig)
"""

from .checkpoint import CheckpointError, build_model, load_checkpoint, save_checkpoint
from .config import load_config
from .data import BevDataset
from .frustum import Frustum
from .lss import LSSFisheye

__all__ = ["build_model", "load_checkpoint", "save_checkpoint", "CheckpointError", "load_config", "BevDataset", "Frustum",
           "LSSFisheye"]
