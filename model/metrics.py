"""Metrics: a confusion matrix accumulated with one bincount, per-class IoU, occlusion IoU, mIoU.

Semantic cells count where the true class is valid (> 0) and the true visibility p(o) >= 0.5 (the
paper scores perceived cells only). Occlusion IoU is the IoU of the occluded mask (p(o) < 0.5)
between prediction (sigmoid of the occlusion logit < 0.5) and truth, over all cells. mIoU is the
mean of the five IoUs occlusion, vehicle, lane_marking, street, background (the paper's), over
those that are defined: a class absent from both truth and prediction has no IoU (NaN) and is left
out rather than counted as 0.
"""

from __future__ import annotations

import torch

from .lss import NUM_CLASSES

VISIBLE = 0.5


def confusion(pred, target, visibility, num_classes: int = NUM_CLASSES) -> torch.Tensor:
    """(K, K) int64 counts [true, pred] over valid, visible cells; pred and target in 0..K-1."""
    keep = (target > 0) & (visibility >= VISIBLE)
    idx = target[keep].long() * num_classes + pred[keep].long()
    return torch.bincount(idx, minlength=num_classes * num_classes).view(num_classes, num_classes)


def occlusion_confusion(occ_logits, visibility) -> torch.Tensor:
    """(2, 2) counts [true occluded, predicted occluded]."""
    pred = (occ_logits < 0).long().reshape(-1)  # sigmoid < 0.5
    true = (visibility < VISIBLE).long().reshape(-1)
    return torch.bincount(true * 2 + pred, minlength=4).view(2, 2)


def iou_from_confusion(cm: torch.Tensor) -> torch.Tensor:
    cm = cm.double()
    tp = cm.diag()
    denom = cm.sum(0) + cm.sum(1) - tp
    return torch.where(denom > 0, tp / denom.clamp(min=1), torch.full_like(tp, float("nan")))


class BevMetrics:
    """Accumulates over a split; `.compute()` -> {'iou/<class>': .., 'iou/occlusion': .., 'miou': ..}."""

    def __init__(self, class_names):
        self.class_names = list(class_names)
        self.k = len(self.class_names)
        self.reset()

    def reset(self):
        self.cm = torch.zeros(self.k, self.k, dtype=torch.int64)
        self.occ = torch.zeros(2, 2, dtype=torch.int64)

    @torch.no_grad()
    def update(self, pred, batch: dict):
        """pred: a model.predict.Prediction of the batch."""
        self.cm += confusion(pred.classes.cpu(), batch["semantic"].cpu(), batch["visibility"].cpu(), self.k)
        self.occ += occlusion_confusion(pred.occlusion_logit.cpu(), batch["visibility"].cpu())

    def merge_(self, other_cm: torch.Tensor, other_occ: torch.Tensor):
        self.cm += other_cm
        self.occ += other_occ

    def compute(self) -> dict:
        iou = iou_from_confusion(self.cm)
        res = {f"iou/{n}": float(iou[i]) for i, n in enumerate(self.class_names) if i > 0}
        res["iou/occlusion"] = float(iou_from_confusion(self.occ)[1])
        vals = torch.tensor([res["iou/occlusion"]] + [res[f"iou/{n}"] for n in self.class_names[1:]])
        res["miou"] = float(vals.nanmean())  # a class absent from truth and prediction is left out
        return res
