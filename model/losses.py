"""Losses of the paper's eqs. 5-7.

semantic (eq. 5): per cell -p(o) * alpha_y * log q_y, the cross entropy of the true class y weighted
by the cell's true visibility p(o) and the class weight alpha_y; cells of class 0 (invalid) get no
loss. Each sample's loss is the weighted sum divided by the sum of the weights (a weighted mean, as
torch's weighted cross entropy), and the batch loss is the mean over samples, so that a batch split
across DDP processes gives the same gradient as the whole batch in one.
occlusion (eq. 6): binary cross entropy of the predicted visibility against the true p(o) (soft
target by default; `binary` thresholds it at 0.5), mean over cells (those with a label: `bev_known`,
model.data), then over samples.
total (eq. 7): semantic + lambda * occlusion.
Camera-view terms (off by default): + depth_weight * the cross entropy of the lift's
depth bins against the bin the pixel's ray hits, + camera_seg_weight * the cross entropy of the
camera-view semantic head (model.feature_targets); each a mean over a sample's valid feature pixels,
then over samples. With both weights 0 they are not computed and the total is eq. 7's exactly.
Dice (off by default): + dice_weight * (1 - mean soft Dice over the classes), for thin classes.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

CLASS_WEIGHTS = {"uniform": [1.0, 1.0, 1.0, 1.0], "paper": [13.0, 3.0, 1.0, 1.0]}  # vehicle, lane, street, background


def class_weights(spec) -> torch.Tensor:
    """'uniform', 'paper' (13-3-1-1) or a list of one weight per training class after invalid."""
    if isinstance(spec, str):
        if spec not in CLASS_WEIGHTS:
            raise ValueError(f"class weights must be {' or '.join(CLASS_WEIGHTS)} or a list, got {spec!r}")
        spec = CLASS_WEIGHTS[spec]
    return torch.tensor([float(v) for v in spec])


def semantic_loss(logits, target, visibility, alpha, use_visibility: bool = True):
    """logits (B, K, X, Y) over classes 1..K; target (B, X, Y) long in 0..K (0 = invalid);
    visibility (B, X, Y) in [0, 1]; alpha (K,)."""
    if logits.shape[1] != alpha.numel():
        raise ValueError(f"semantic loss: {logits.shape[1]} class logits but {alpha.numel()} class weights")
    valid = target > 0
    logp = F.log_softmax(logits, 1)
    cls = (target - 1).clamp(min=0)
    nll = -logp.gather(1, cls[:, None])[:, 0]
    w = alpha.to(logits)[cls] * valid
    if use_visibility:
        w = w * visibility
    per_sample = (w * nll).sum((1, 2)) / w.sum((1, 2)).clamp(min=1e-6)
    return per_sample.mean()


def occlusion_loss(logits, visibility, target: str = "soft", known=None):
    """logits (B, X, Y) of visibility; visibility (B, X, Y) true p(o); `known` (B, X, Y) or None: the
    cells with a label (a turned sample's corners have none), the mean over those."""
    t = visibility if target == "soft" else (visibility >= 0.5).to(visibility)
    bce = F.binary_cross_entropy_with_logits(logits, t, reduction="none")
    if known is None:
        return bce.mean((1, 2)).mean()
    return ((bce * known).sum((1, 2)) / known.sum((1, 2)).clamp(min=1)).mean()


def dice_loss(logits, target, visibility, use_visibility: bool = True):
    """1 - the mean over classes 1..K of the soft Dice of the BEV softmax against the truth, over
    the batch's valid cells (weighted by the true p(o)): a term that rewards overlap with thin,
    rare classes (lane markings) that the cell-averaged cross entropy lets the model never predict."""
    valid = (target > 0).to(logits)
    w = valid * visibility if use_visibility else valid
    p = F.softmax(logits, 1) * w[:, None]
    y = F.one_hot((target - 1).clamp(min=0), logits.shape[1]).permute(0, 3, 1, 2).to(logits) * w[:, None]
    inter, total = (p * y).sum((0, 2, 3)), (p + y).sum((0, 2, 3))
    return 1 - ((2 * inter + 1.0) / (total + 1.0)).mean()


def pixel_cross_entropy(logits, target, ignore: int):
    """logits (B, N, K, h, w); target (B, N, h, w) long, `ignore` where masked -> the mean over each
    sample's valid pixels, then over samples (a sample with none adds 0)."""
    valid = target != ignore
    cls = torch.where(valid, target - (ignore + 1), 0)  # logit k is class ignore + 1 + k
    nll = -F.log_softmax(logits, 2).gather(2, cls[:, :, None])[:, :, 0]
    per_sample = (nll * valid).sum((1, 2, 3)) / valid.sum((1, 2, 3)).clamp(min=1)
    return per_sample.mean()


def depth_loss(depth_logits, target):
    """depth_logits (B, N, D, h, w); target (B, N, h, w) bin index, -1 masked."""
    return pixel_cross_entropy(depth_logits, target, -1)


def camera_semantic_loss(logits, target):
    """logits (B, N, K, h, w) over classes 1..K; target (B, N, h, w) in 0..K (0 = invalid)."""
    return pixel_cross_entropy(logits, target, 0)


def total_loss(out: dict, batch: dict, alpha, lam: float = 1.0, use_visibility: bool = True, occ_target: str = "soft",
               depth_weight: float = 0.0, camera_seg_weight: float = 0.0, dice_weight: float = 0.0):
    """-> (total, {'semantic': .., 'occlusion': .. [, 'depth': .., 'camera_semantic': .., 'dice': ..]}) detached parts for logging."""
    sem = semantic_loss(out["semantic"], batch["semantic"], batch["visibility"], alpha, use_visibility)
    occ = occlusion_loss(out["occlusion"], batch["visibility"], occ_target, batch.get("bev_known"))
    total, parts = sem + lam * occ, {"semantic": sem.detach(), "occlusion": occ.detach()}
    if depth_weight > 0:
        dep = depth_loss(out["depth_logits"], batch["depth_target"])
        total, parts["depth"] = total + depth_weight * dep, dep.detach()
    if camera_seg_weight > 0:
        cam = camera_semantic_loss(out["camera_semantic"], batch["camera_semantic"])
        total, parts["camera_semantic"] = total + camera_seg_weight * cam, cam.detach()
    if dice_weight > 0:
        dice = dice_loss(out["semantic"], batch["semantic"], batch["visibility"], use_visibility)
        total, parts["dice"] = total + dice_weight * dice, dice.detach()
    return total, parts


def config_loss(out: dict, batch: dict, alpha, loss_cfg: dict):
    """total_loss with the terms and weights of a training config's `loss` section."""
    return total_loss(out, batch, alpha, loss_cfg["occlusion_weight"], loss_cfg["visibility_weighting"],
                      loss_cfg["occlusion_target"], loss_cfg["depth_weight"], loss_cfg["camera_seg_weight"],
                      loss_cfg["dice_weight"])
