"""build_model(cfg, rig) and checkpoints that carry their config and rig."""

from __future__ import annotations

from pathlib import Path

import torch

from common.errors import InputError
from common.files import write_bytes_atomic
from geometry.rig import Rig, rig_from_dict


class CheckpointError(InputError):
    pass


def build_model(cfg: dict, rig: Rig, num_classes: int = 5):
    """The model of a validated config for a rig (cameras at their native image size)."""
    from .frustum import Frustum
    from .lss import LSSFisheye
    from .rectified import model_rig

    return LSSFisheye(cfg["model"], Frustum(model_rig(rig, cfg), cfg), num_classes, cfg["loss"]["camera_seg_weight"] > 0)


def save_checkpoint(path, state: dict) -> None:
    """Atomic: write a temp file, then rename. Serialised in memory first, so a full disk is an
    OSError naming the file (torch's own writer raises a RuntimeError that names neither)."""
    import io

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    buf = io.BytesIO()
    torch.save(state, buf)
    write_bytes_atomic(path, buf.getvalue())


def model_part(cfg: dict) -> dict:
    # what decides the network and its inputs; training knobs may differ
    from .rectified import rectify_part

    return {"model": {"trunk": "scratch", **cfg["model"]}, "input_size": list(cfg["data"]["input_size"]), "grid": cfg["data"]["grid"],
            **rectify_part(cfg)}


def load_checkpoint(path, expect_config: dict | None = None, map_location="cpu"):
    """-> (model, config, checkpoint dict). With expect_config, refuses (CheckpointError) a
    checkpoint whose model, input size or grid differ from that config's."""
    path = Path(path)
    try:
        ckpt = torch.load(path, map_location=map_location, weights_only=False)
    except Exception as exc:  # torch.load raises many kinds (pickle, zip, runtime) on a bad file
        what = "no such file" if isinstance(exc, FileNotFoundError) else f"torch.load failed: {type(exc).__name__}"
        raise CheckpointError(f"{path}: not a readable checkpoint ({what})") from None
    for k in ("config", "model", "rig"):
        if not isinstance(ckpt, dict) or k not in ckpt:
            raise CheckpointError(f"{path}: not a checkpoint of train.py (missing '{k}')")
    cfg = ckpt["config"]
    from .config import validate

    if not isinstance(cfg, dict):
        raise CheckpointError(f"{path}: config: must be a mapping, got {type(cfg).__name__}")
    try:
        cfg = validate(cfg, f"{path}: config")
    except InputError as exc:
        raise CheckpointError(str(exc)) from None
    if expect_config is not None and model_part(expect_config) != model_part(cfg):
        diff = [k for k in model_part(cfg) if model_part(cfg)[k] != model_part(expect_config)[k]]
        raise CheckpointError(f"{path}: checkpoint is from another config ({', '.join(diff)} differ)")
    rig = rig_from_dict(ckpt["rig"], f"{path}: rig")
    model = build_model(cfg, rig, ckpt.get("num_classes", 5))
    load_weights(model, ckpt["model"], path)
    return model, cfg, ckpt


def load_weights(model, state, path) -> None:
    """model.load_state_dict(state), a mismatch (another shape, missing keys) being one CheckpointError line."""
    try:
        model.load_state_dict(state)
    except (RuntimeError, ValueError, KeyError, TypeError, AttributeError) as exc:
        first = str(exc).strip().splitlines()[1:2] or str(exc).strip().splitlines()[:1] or [type(exc).__name__]
        raise CheckpointError(f"{path}: does not fit this model ({first[0].strip()[:160]})") from None
