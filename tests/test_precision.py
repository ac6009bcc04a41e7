"""model.precision: bf16 autocast of the trunk and the BEV encoder, with the lift, the
splat and the outputs in float32; fp32 (the default) is today's model exactly."""

import pytest
import torch

from common.errors import ConfigError
from geometry.rig import load_rig
from model import build_model
from model.config import validate


def cfg(precision: str, trunk: str = "scratch") -> dict:
    return validate({"data": {"input_size": [64, 40], "grid": {"bound": 12.0, "res": 0.5}, "num_workers": 0},
                     "model": {"encoder": {"widths": [8, 16, 32, 32], "blocks": [1, 1, 1]}, "context_channels": 8,
                               "depth": {"bins": 8}, "bev_encoder": {"widths": [8, 16, 32]}, "trunk": trunk,
                               "precision": precision},
                     "loss": {"depth_weight": 1.0, "camera_seg_weight": 0.5}})


@pytest.mark.parametrize("trunk", ["scratch", "efficientnet_lite0"])
def test_bf16_is_the_fp32_model_rounded(trunk):
    rig = load_rig("configs/rigs/mixed.yaml")
    torch.manual_seed(0)
    full = build_model(cfg("fp32", trunk), rig)
    torch.manual_seed(0)
    half = build_model(cfg("bf16", trunk), rig)
    assert all(torch.equal(a, b) for a, b in zip(full.state_dict().values(), half.state_dict().values()))
    torch.manual_seed(1)
    x = torch.rand(2, 5, 3, 40, 64)
    full.eval(), half.eval()
    with torch.no_grad():
        a, b = full(x), half(x)
    for k in ("semantic", "occlusion"):
        assert b[k].dtype == torch.float32
        scale = float(a[k].abs().max())
        assert 0 < float((a[k] - b[k]).abs().max()) < 0.1 * scale, k  # rounded, not equal, not another model
    assert (a["semantic"].argmax(1) == b["semantic"].argmax(1)).float().mean() > 0.9

    # training: every output float32, every trained weight gets a finite gradient
    half.train()
    out = half(x)
    assert all(v.dtype == torch.float32 for v in out.values())
    sum(v.float().square().mean() for v in out.values()).backward()
    for name, p in half.named_parameters():
        if p.requires_grad and p.grad is not None:
            assert torch.isfinite(p.grad).all(), name
    assert sum(p.grad is not None for p in half.parameters()) > 0.9 * sum(1 for _ in half.parameters())


def test_precision_is_checked():
    with pytest.raises(ConfigError, match="model.precision"):
        cfg("fp16")
