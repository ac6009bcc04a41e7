"""Metrics: a confusion matrix accumulated with one bincount, per-class IoU, occlusion IoU, mIoU.

Semantic cells count where the true class is valid (> 0) and the true visibility p(o) >= 0.5 (the
paper scores perceived cells only). Occlusion IoU is the IoU of the occluded mask (p(o) < 0.5)
between prediction (sigmoid of the occlusion logit < 0.5) and truth, over all cells. mIoU is the
mean of the five IoUs occlusion, vehicle, lane_marking, street, background (the paper's), over
those that are defined: a class absent from both truth and prediction has no IoU (NaN) and is left
out rather than counted as 0.

Tolerance IoU of lane markings (`iou_tol/lane_marking`, beside the strict one; not in the mIoU): a
0.25 m cell is as wide as the paint, so a line predicted one cell off scores 0 strictly. Over the
same scored cells: TP = predicted marking cells with a true marking cell in their 3x3
neighbourhood, FP = the other predicted marking cells, FN = true marking cells with no predicted
one in their 3x3 neighbourhood; IoU = TP / (TP + FP + FN), never below the strict IoU (TP + FP is
the predicted cells in both; TP can only grow and FN only shrink).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from .lss import NUM_CLASSES

VISIBLE = 0.5
TOLERANCE_CLASS = "lane_marking"


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


def _near(mask: torch.Tensor) -> torch.Tensor:
    """(..., X, Y) bool -> True within one cell (3x3 neighbourhood) of a True cell."""
    x = mask.reshape(-1, 1, *mask.shape[-2:]).float()
    return F.max_pool2d(x, 3, stride=1, padding=1).reshape(mask.shape) > 0


def tolerance_counts(pred, target, visibility, cls: int) -> torch.Tensor:
    """(3,) int64 [TP, FP, FN] of class `cls` with a one-cell tolerance, over valid, visible cells;
    pred and target (..., X, Y) class ids in 0..K-1."""
    keep = (target > 0) & (visibility >= VISIBLE)
    p, t = (pred == cls) & keep, (target == cls) & keep
    near_t, near_p = _near(t), _near(p)
    return torch.stack([(p & near_t).sum(), (p & ~near_t).sum(), (t & ~near_p).sum()]).long()


def iou_from_tolerance(counts: torch.Tensor) -> float:
    tp, fp, fn = (int(v) for v in counts)
    return tp / (tp + fp + fn) if tp + fp + fn else float("nan")


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
        self.tol_class = self.class_names.index(TOLERANCE_CLASS) if TOLERANCE_CLASS in self.class_names else None
        self.reset()

    def reset(self):
        self.cm = torch.zeros(self.k, self.k, dtype=torch.int64)
        self.occ = torch.zeros(2, 2, dtype=torch.int64)
        self.tol = torch.zeros(3, dtype=torch.int64)  # tolerance counts of TOLERANCE_CLASS

    @torch.no_grad()
    def update(self, pred, batch: dict):
        """pred: a model.inference.Prediction of the batch."""
        classes, semantic, visibility = pred.classes.cpu(), batch["semantic"].cpu(), batch["visibility"].cpu()
        self.cm += confusion(classes, semantic, visibility, self.k)
        self.occ += occlusion_confusion(pred.occlusion_logit.cpu(), visibility)
        self.add_tolerance(classes, semantic, visibility)

    def add_tolerance(self, pred, target, visibility):
        """Count the tolerance IoU of whole (..., X, Y) maps (not masked subsets: it needs neighbours)."""
        if self.tol_class is not None:
            self.tol += tolerance_counts(pred, target, visibility, self.tol_class)

    def merge_(self, other_cm: torch.Tensor, other_occ: torch.Tensor):
        self.cm += other_cm
        self.occ += other_occ

    def compute(self) -> dict:
        iou = iou_from_confusion(self.cm)
        res = {f"iou/{n}": float(iou[i]) for i, n in enumerate(self.class_names) if i > 0}
        res["iou/occlusion"] = float(iou_from_confusion(self.occ)[1])
        vals = torch.tensor([res["iou/occlusion"]] + [res[f"iou/{n}"] for n in self.class_names[1:]])
        res["miou"] = float(vals.nanmean())  # a class absent from truth and prediction is left out
        if self.tol_class is not None:
            res[f"iou_tol/{TOLERANCE_CLASS}"] = iou_from_tolerance(self.tol)
        return res
