"""LSS-fisheye BEV segmentation model (see docs/model.md).

    from model import build_model, load_checkpoint, load_config, predict
    cfg = load_config("configs/train/cpu_default.yaml"); model = build_model(cfg, rig)

Training is `model.training`, scoring `model.evaluation` (train.py and eval.py are their command lines).
"""

from .checkpoint import CheckpointError, build_model, load_checkpoint, read_checkpoint, save_checkpoint
from .config import load_config
from .data import BevDataset
from .frustum import Frustum
from .lss import NUM_CLASSES, LSSFisheye
from .inference import Prediction, predict
from .run_dir import EvalDir, RunDir

__all__ = ["build_model", "load_checkpoint", "read_checkpoint", "save_checkpoint", "CheckpointError", "load_config", "BevDataset",
           "Frustum", "LSSFisheye", "NUM_CLASSES", "Prediction", "predict", "EvalDir", "RunDir"]
