"""build_model(cfg, rig) and checkpoints that carry their config, rig and class names: the one writer
(`save_checkpoint`), the one reader (`read_checkpoint`, used by resume, eval and the ablation) and
the one place that brings an older checkpoint up to date (`upgrade_checkpoint`)."""

from __future__ import annotations

from pathlib import Path

import torch

from common.errors import InputError
from common.files import write_bytes_atomic
from geometry.rig import Rig, rig_from_dict

from dataset_tools.labels.classes import TRAIN_CLASSES

from .lss import NUM_CLASSES

MODEL_KEYS = ("config", "model", "rig")  # what every checkpoint holds
TRAINING_KEYS = ("optimizer", "step", "epoch", "step_in_epoch", "best", "rng")  # and what a resume needs


class CheckpointError(InputError):
    pass


def build_model(cfg: dict, rig: Rig, num_classes: int = NUM_CLASSES):
    """The model of a validated config for a rig (cameras at their native image size)."""
    from .lss import LSSFisheye
    from .rectified import model_view

    return LSSFisheye(cfg["model"], model_view(rig, cfg).frustum, num_classes, cfg["loss"]["camera_seg_weight"] > 0)


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
    # what decides the network and its inputs (of a validated config); training knobs may differ
    from .rectified import rectify_part

    return {"model": cfg["model"], "input_size": list(cfg["data"]["input_size"]), "grid": cfg["data"]["grid"], **rectify_part(cfg)}


def upgrade_checkpoint(ckpt: dict, path) -> dict:
    """A checkpoint as the current code writes it. The config is validated, which gives options
    added since it was written their defaults (model.trunk, data.rectify, ...); a checkpoint
    without `num_classes` predicts NUM_CLASSES; one without `class_names` was trained on the
    default classes (the first `num_classes` of TRAIN_CLASSES); one without `cuda_rng` was written on CPU."""
    from .config import validate

    cfg = ckpt["config"]
    if not isinstance(cfg, dict):
        raise CheckpointError(f"{path}: config: must be a mapping, got {type(cfg).__name__}")
    try:
        cfg = validate(cfg, f"{path}: config")
    except InputError as exc:
        raise CheckpointError(str(exc)) from None
    ckpt = {"num_classes": NUM_CLASSES, "cuda_rng": None, **ckpt, "config": cfg}
    names = ckpt.get("class_names", list(TRAIN_CLASSES)[: ckpt["num_classes"]])
    if not (isinstance(names, list) and len(names) == ckpt["num_classes"] and all(isinstance(n, str) for n in names)):
        raise CheckpointError(f"{path}: class_names: must be a list of {ckpt['num_classes']} names (num_classes)")
    return {**ckpt, "class_names": names}


def read_checkpoint(path, expect_config: dict | None = None, expect_rig: Rig | None = None, resume: bool = False) -> dict:
    """The checkpoint at `path`, upgraded (`upgrade_checkpoint`); any problem is one
    CheckpointError line naming the file. With expect_config, refuses a checkpoint whose model,
    input size or grid differ from that config's; with expect_rig, one of another rig. `resume`:
    the training state must be there too, and the messages say how to start afresh."""
    path = Path(path)
    afresh = "; move it away to start afresh" if resume else ""
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # torch.load raises many kinds (pickle, zip, runtime) on a bad file
        what = "no such file" if isinstance(exc, FileNotFoundError) else f"torch.load failed: {type(exc).__name__}"
        raise CheckpointError(f"{path}: not a readable checkpoint ({what}){afresh}") from None
    for k in MODEL_KEYS + (TRAINING_KEYS if resume else ()):
        if not isinstance(ckpt, dict) or k not in ckpt:
            raise CheckpointError(f"{path}: not a checkpoint of train.py (missing '{k}'){afresh}")
    ckpt = upgrade_checkpoint(ckpt, path)
    other = "; use another --out" if resume else ""
    if expect_config is not None and model_part(expect_config) != model_part(ckpt["config"]):
        have, want = model_part(ckpt["config"]), model_part(expect_config)
        raise CheckpointError(f"{path}: checkpoint is from another config ({', '.join(k for k in have if have[k] != want[k])} differ){other}")
    if expect_rig is not None and ckpt["rig"] != expect_rig.to_dict():
        raise CheckpointError(f"{path}: checkpoint is from another rig{other}")
    return ckpt


def load_checkpoint(path, expect_config: dict | None = None):
    """-> (model, config, checkpoint dict): `read_checkpoint` and the model it holds."""
    ckpt = read_checkpoint(path, expect_config)
    rig = rig_from_dict(ckpt["rig"], f"{Path(path)}: rig")
    model = build_model(ckpt["config"], rig, ckpt["num_classes"])
    load_weights(model, ckpt["model"], path)
    return model, ckpt["config"], ckpt


def in_precision(model, cfg: dict, precision: str) -> dict:
    """Run a loaded model in `precision` (fp32 | bf16, model.precision) rather than the one it was
    trained in; -> its config saying so."""
    model.bf16 = precision == "bf16"
    return {**cfg, "model": {**cfg["model"], "precision": precision}}


def load_weights(model, state, path) -> None:
    """model.load_state_dict(state), a mismatch (another shape, missing keys) being one CheckpointError line."""
    try:
        model.load_state_dict(state)
    except (RuntimeError, ValueError, KeyError, TypeError, AttributeError) as exc:
        first = str(exc).strip().splitlines()[1:2] or str(exc).strip().splitlines()[:1] or [type(exc).__name__]
        raise CheckpointError(f"{path}: does not fit this model ({first[0].strip()[:160]})") from None
