"""Levers for less work per step (issue 33), each off by default: model.trunk_frozen (the pretrained
trunk's first levels stay as loaded: no gradient, BatchNorm at ImageNet's statistics; the same
function in eval), model.trunk_depthwise_frozen (the other blocks' depthwise weights stay as loaded)
and model.bev_encoder.separable (depthwise-separable decoder convolutions)."""

import pytest
import torch

from common.errors import ConfigError
from geometry.rig import load_rig
from model import build_model
from model.config import validate


def cfg(frozen: int, trunk: str = "efficientnet_lite0", stride: int = 8, depthwise: bool = False) -> dict:
    return validate({"data": {"input_size": [64, 64], "grid": {"bound": 12.0, "res": 0.5}, "num_workers": 0},
                     "model": {"context_channels": 8, "depth": {"bins": 8}, "bev_encoder": {"widths": [8, 16, 32]},
                               "trunk": trunk, "trunk_frozen": frozen, "stride": stride, "trunk_depthwise_frozen": depthwise}})


def test_frozen_levels_get_no_gradient_and_keep_their_statistics():
    rig = load_rig("configs/rigs/default.yaml")
    torch.manual_seed(0)
    free = build_model(cfg(0), rig)
    torch.manual_seed(0)
    frozen = build_model(cfg(2), rig)
    enc = frozen.encoder
    assert enc.frozen_blocks == enc.ends[2] + 1 > 0
    x = torch.rand(2, len(rig), 3, 64, 64)
    built = build_model(cfg(2), rig)  # as built: training mode without a call to train() (train.py's model)
    bns = [m for m in built.encoder.stem.modules() if isinstance(m, torch.nn.BatchNorm2d)]
    stats = [m.running_mean.clone() for m in bns]
    built(x)
    assert built.training and not built.encoder.stem.training
    assert all(torch.equal(u, m.running_mean) for u, m in zip(stats, bns)), "a frozen BatchNorm moved before train()"
    free.eval(), frozen.eval()
    with torch.no_grad():  # the same network: freezing changes training, not the function
        a, b = free(x), frozen(x)
    assert torch.equal(a["semantic"], b["semantic"])
    frozen.train()
    stats = [m.running_mean.clone() for m in enc.stem.modules() if isinstance(m, torch.nn.BatchNorm2d)]
    out = frozen(x)
    sum(v.float().square().mean() for v in out.values()).backward()
    for name, p in enc.named_parameters():
        first = name.startswith("stem.") or (name.startswith("blocks.") and int(name.split(".")[1]) < enc.frozen_blocks)
        assert (p.grad is None) == first, name  # frozen: no gradient; the rest trains
    after = [m.running_mean for m in enc.stem.modules() if isinstance(m, torch.nn.BatchNorm2d)]
    assert all(torch.equal(u, v) for u, v in zip(stats, after)), "a frozen BatchNorm moved its statistics"
    assert not enc.stem.training and enc.blocks[enc.frozen_blocks].training


def test_frozen_depthwise_weights_get_no_gradient_but_pass_one_on():
    rig = load_rig("configs/rigs/default.yaml")
    torch.manual_seed(0)
    plain = build_model(cfg(2), rig)
    torch.manual_seed(0)
    model = build_model(cfg(2, depthwise=True), rig)
    enc = model.encoder
    x = torch.rand(2, len(rig), 3, 64, 64)
    plain.eval(), model.eval()
    with torch.no_grad():  # the same function: only what trains changes
        assert torch.equal(plain(x)["semantic"], model(x)["semantic"])
    model.train()
    out = model(x)
    sum(v.float().square().mean() for v in out.values()).backward()
    trained = list(enc.blocks[enc.frozen_blocks :])
    assert len(trained) == 13  # EfficientNet-Lite0's 16 blocks, 3 of them through stride 4
    for b in trained:
        assert b._depthwise_conv.weight.grad is None
        assert b._project_conv.weight.grad is not None and b._project_conv.weight.grad.abs().sum() > 0
    # the first trained block's expansion sits before its depthwise conv: its gradient crossed it
    first = trained[0]._expand_conv.weight.grad
    assert first is not None and first.abs().sum() > 0
    assert all(p.grad is not None for p in model.bev.parameters() if p.requires_grad)


@pytest.mark.parametrize("frozen, trunk, stride, msg", [
    (1, "scratch", 8, "only the pretrained trunk"),
    (3, "efficientnet_lite0", 8, "at most 2"),
])
def test_trunk_frozen_is_checked(frozen, trunk, stride, msg):
    with pytest.raises(ConfigError, match=msg):
        cfg(frozen, trunk, stride)
    with pytest.raises(ConfigError, match="trunk_depthwise_frozen: only the pretrained trunk"):
        cfg(0, "scratch", depthwise=True)


def test_a_separable_bev_decoder_does_a_fraction_of_the_work():
    from torch.utils.flop_counter import FlopCounterMode

    from model.bev_encoder import BevEncoder

    x = torch.rand(1, 32, 200, 200)
    flops = {}
    for sep in (False, True):
        enc = BevEncoder(32, (32, 64, 128), (1, 1), separable=sep)
        with FlopCounterMode(display=False) as fc, torch.no_grad():
            y = enc(x)
        assert y.shape == (1, 32, 200, 200)
        flops[sep] = fc.get_total_flops()
    assert flops[True] < 0.4 * flops[False]
    c = validate({"model": {"bev_encoder": {"separable": True}}})
    assert c["model"]["bev_encoder"]["separable"] is True
    assert validate({})["model"]["bev_encoder"]["separable"] is False  # the default is today's encoder
