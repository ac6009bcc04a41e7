"""The training recipe's options: soft Dice for thin classes, warm-up and cosine decay."""

import math

import pytest
import torch

from model.losses import dice_loss, total_loss
from model.training import learning_rate


def _truth():
    target = torch.full((1, 8, 8), 3)  # street
    target[0, :, 4] = 2  # one marking column
    target[0, 0, 0] = 0  # invalid
    return target, torch.ones(1, 8, 8)


def _logits(classes, sharp=8.0):
    return sharp * torch.nn.functional.one_hot(classes - 1, 4).permute(0, 3, 1, 2).double()


def test_dice_is_near_zero_for_the_truth_and_punishes_missing_a_thin_class():
    target, vis = _truth()
    right = dice_loss(_logits(target.clamp(min=1)), target, vis)
    no_marking = dice_loss(_logits(torch.full_like(target, 3)), target, vis)
    assert right < 0.02  # softmax of logits 8 apart, and the +1 smoothing
    assert no_marking > right + 0.2  # a marking class never predicted costs about a class's worth of Dice
    # the cross entropy of the same miss is small: 8 of 63 cells; Dice does not average it away
    assert no_marking > 0.2


def test_dice_ignores_invalid_and_invisible_cells():
    target, vis = _truth()
    logits = _logits(target.clamp(min=1))
    vis2 = vis.clone()
    vis2[0, 5:, :] = 0  # invisible rows: whatever is predicted there does not count
    logits2 = logits.clone()
    logits2[0, :, 5:, :] = _logits(torch.full((1, 3, 8), 1))[0]
    assert torch.allclose(dice_loss(logits, target, vis2), dice_loss(logits2, target, vis2))


def test_dice_gradcheck():
    target, vis = _truth()
    logits = torch.randn(1, 4, 8, 8, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda x: dice_loss(x, target, vis.double()), (logits,))


def test_dice_weight_zero_is_the_old_total():
    target, vis = _truth()
    out = {"semantic": torch.randn(1, 4, 8, 8), "occlusion": torch.randn(1, 8, 8)}
    batch = {"semantic": target, "visibility": vis}
    alpha = torch.ones(4)
    base, parts = total_loss(out, batch, alpha)
    with_dice, parts_d = total_loss(out, batch, alpha, dice_weight=0.5)
    assert "dice" not in parts and torch.equal(base, total_loss(out, batch, alpha, dice_weight=0.0)[0])
    assert torch.allclose(with_dice, base + 0.5 * parts_d["dice"])


@pytest.mark.parametrize("step,want", [(0, 0.25), (3, 1.0), (4, 1.0), (14, 0.5), (24, 0.0)])
def test_learning_rate_warmup_then_cosine(step, want):
    t = {"lr": 1.0, "warmup_steps": 4, "lr_schedule": "cosine"}
    assert math.isclose(learning_rate(t, step, 24), want, abs_tol=1e-12)


def test_learning_rate_constant_is_the_config_lr():
    t = {"lr": 1e-3, "warmup_steps": 0, "lr_schedule": "constant"}
    assert all(learning_rate(t, s, 10) == 1e-3 for s in range(20))
