"""The model on a batch, and its output as a prediction (class ids and p(o)), written once for
training, validation, eval.py, the ablation and predict.py; the one writer of prediction files;
and a trained model on the images of any rig (`RigModel`, what predict.py runs).

    pred = predict(model, batch)      # batch: BevDataset samples, collated
    pred.classes                      # (B, X, Y) class ids 1..K-1 (0, invalid, is never predicted)
    pred.occlusion_logit              # (B, X, Y) logit of visibility p(o)
    pred.visibility                   # (B, X, Y) p(o) = sigmoid(logit)
    write_prediction(path, pred, j)   # <name>.npz: semantic uint8, visibility and occlusion_logit float32

    rm = RigModel(model, cfg, ckpt["rig"], rig)   # rig: any rig, its cameras matched to the model's by name
    pred = rm({"front": img, ...})                # uint8 (H, W, 3) images at the rig cameras' sizes
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from common.errors import InputError
from common.files import write_bytes_atomic
from geometry.rig import Rig

from .augment import warp_image
from .rectified import model_view


@dataclass
class Prediction:
    classes: torch.Tensor
    occlusion_logit: torch.Tensor

    @property
    def visibility(self) -> torch.Tensor:
        return torch.sigmoid(self.occlusion_logit)


def pick_device(kind: str = "auto") -> torch.device:
    """auto: the GPU when torch sees one, else the CPU; cpu; cuda (an InputError without one)."""
    if kind == "cuda" and not torch.cuda.is_available():
        raise InputError("--device cuda: this machine has no CUDA device (use auto or cpu)")
    return torch.device("cuda" if kind == "cuda" or (kind == "auto" and torch.cuda.is_available()) else "cpu")


def to_device(batch: dict, device) -> dict:
    return {k: (v.to(device, non_blocking=True) if isinstance(v, torch.Tensor) else v) for k, v in batch.items()}


def forward(model, batch: dict) -> dict:
    """The model's raw output on a batch: augmented samples bring their cameras' geometry, others
    use the model's cached nominal geometry."""
    return model(batch["images"], batch.get("point_cell"), batch.get("intrinsics"), batch.get("ground_grid"))


def decode(out: dict) -> Prediction:
    """The model's raw output as class ids (the head scores classes 1..K-1) and the occlusion logit."""
    return Prediction(out["semantic"].argmax(1) + 1, out["occlusion"])


def predict(model, batch: dict) -> Prediction:
    return decode(forward(model, batch))


def write_prediction(path, pred: Prediction, j: int = 0) -> None:
    """The prediction file of sample `j` of a batch's prediction (atomic): `semantic` uint8 class ids
    1..K-1, `visibility` float32 p(o) and `occlusion_logit` float32, on the model's BEV grid."""
    logit = pred.occlusion_logit[j].detach().float().cpu()
    buf = io.BytesIO()
    np.savez_compressed(buf, semantic=pred.classes[j].cpu().numpy().astype(np.uint8),
                        visibility=torch.sigmoid(logit).numpy().astype(np.float32),
                        occlusion_logit=logit.numpy().astype(np.float32))
    write_bytes_atomic(Path(path), buf.getvalue())


class PredictError(InputError):
    pass


def in_model_order(rig: Rig, model_names, source: str, cameras: list[str] | None = None) -> Rig:
    """The rig's cameras in the model's camera order: matched by name, or, where the rig names them
    otherwise, as `cameras` (--cameras: the rig's cameras in the model's order) says. Refused, naming
    `source` (the rig file or option), where the number of cameras or the names do not fit."""
    model_names = list(model_names)
    if len(rig) != len(model_names):
        raise PredictError(f"{source}: {len(rig)} cameras ({', '.join(rig.names)}), the model was trained with "
                           f"{len(model_names)} ({', '.join(model_names)})")
    if cameras is None:
        if set(rig.names) != set(model_names):
            raise PredictError(f"{source}: cameras {', '.join(rig.names)} are not the model's ({', '.join(model_names)}); "
                               f"give --cameras with the rig's cameras in the model's order")
        cameras = model_names
    elif sorted(cameras) != sorted(rig.names):
        raise PredictError(f"--cameras: {','.join(cameras)} must name each camera of {source} once ({', '.join(rig.names)})")
    return Rig([rig[n] for n in cameras], rig.name, rig.origins)


class RigModel:
    """A trained model and the lift geometry of one rig: the images of a frame -> Prediction."""

    def __init__(self, model, cfg: dict, train_rig_dict: dict, rig, source: str = "--rig", cameras: list[str] | None = None):
        self.model, self.cfg = model, cfg
        rig = in_model_order(rig, model.camera_names, source, cameras)
        self.rig = rig
        view = model_view(rig, cfg)
        self.rectify, self.frustum = view.rectifier, view.frustum
        # the training rig itself: the model's own cached geometry, as eval uses it
        self.geometry = None
        if rig.to_dict() != train_rig_dict:
            pc, intr = self.frustum.nominal
            self.geometry = {"point_cell": pc[None], "intrinsics": intr[None]}
            if self.frustum.ground:
                self.geometry["ground_grid"] = self.frustum.nominal_ground[None]

    def inputs(self, images: dict) -> torch.Tensor:
        out = []
        for rc, t, src in zip(self.frustum.rig, self.frustum.nominal_transforms(), self.rig):
            img = images[src.name]
            if self.rectify:
                img = self.rectify(src.name, img)
            out.append(warp_image(img, rc.camera, t))
        return (torch.from_numpy(np.stack(out)).permute(0, 3, 1, 2).contiguous().float() / 255.0)[None]  # NCHW, as BevDataset hands eval.py its images

    @torch.no_grad()
    def __call__(self, images: dict) -> Prediction:
        batch = {"images": self.inputs(images)}
        if self.geometry is not None:
            batch.update(self.geometry)
        self.model.eval()
        return predict(self.model, batch)
