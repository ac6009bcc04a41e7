"""The model on a batch, and its output as a prediction (class ids and p(o)), written once for
training, validation, eval.py and the ablation.

    pred = predict(model, batch)      # batch: BevDataset samples, collated
    pred.classes                      # (B, X, Y) class ids 1..K-1 (0, invalid, is never predicted)
    pred.occlusion_logit              # (B, X, Y) logit of visibility p(o)
    pred.visibility                   # (B, X, Y) p(o) = sigmoid(logit)
"""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass
class Prediction:
    classes: torch.Tensor
    occlusion_logit: torch.Tensor

    @property
    def visibility(self) -> torch.Tensor:
        return torch.sigmoid(self.occlusion_logit)


def to_device(batch: dict, device) -> dict:
    return {k: (v.to(device, non_blocking=True) if isinstance(v, torch.Tensor) else v) for k, v in batch.items()}


def forward(model, batch: dict) -> dict:
    """The model's raw output on a batch: augmented samples bring their cameras' geometry, others
    use the model's cached nominal geometry."""
    return model(batch["images"], batch.get("point_cell"), batch.get("intrinsics"))


def decode(out: dict) -> Prediction:
    """The model's raw output as class ids (the head scores classes 1..K-1) and the occlusion logit."""
    return Prediction(out["semantic"].argmax(1) + 1, out["occlusion"])


def predict(model, batch: dict) -> Prediction:
    return decode(forward(model, batch))
