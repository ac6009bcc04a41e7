"""model.cpu: the CPU thread count and memory format a run uses, and that they change
rounding only."""

import copy

import pytest
import torch

from geometry.rig import load_rig
from model import build_model
from model import cpu
from model.config import validate


def cfg(**train):
    return validate({"data": {"input_size": [64, 40], "grid": {"bound": 12.0, "res": 0.5}, "num_workers": 1},
                     "model": {"encoder": {"widths": [8, 16, 32, 32], "blocks": [1, 1, 1]}, "context_channels": 8,
                               "depth": {"bins": 8}, "bev_encoder": {"widths": [8, 16, 32]}},
                     "train": train})


def test_compute_threads_share_the_cores_among_processes(monkeypatch):
    monkeypatch.setattr(cpu, "cores", lambda: 2)
    assert cpu.compute_threads() == 2  # the 2-core machine: the loader worker is idle most of a step
    assert cpu.compute_threads(processes=4) == 1  # never fewer than one
    monkeypatch.setattr(cpu, "cores", lambda: 16)
    assert cpu.compute_threads(processes=4) == 4


def test_tune_cpu_sets_threads_and_channels_last_and_leaves_other_devices(monkeypatch):
    monkeypatch.setattr(cpu, "cores", lambda: 3)
    before = torch.get_num_threads()
    try:
        torch.manual_seed(0)
        model = build_model(cfg(), load_rig("configs/rigs/mixed.yaml"))
        untouched = copy.deepcopy(model)
        cpu.tune_cpu(cfg(), torch.device("meta"), untouched)  # not a CPU: nothing changes
        assert torch.get_num_threads() == before
        assert untouched.bev.stem[0].weight.is_contiguous()
        cpu.tune_cpu(cfg(), torch.device("cpu"), model)
        assert torch.get_num_threads() == 3
        assert model.bev.stem[0].weight.is_contiguous(memory_format=torch.channels_last)
        assert model.encoder.stem[0].weight.is_contiguous(memory_format=torch.channels_last)
        cpu.tune_cpu(cfg(threads=1), torch.device("cpu"))  # train.threads wins
        assert torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(before)


@pytest.mark.parametrize("trunk", ["scratch", "efficientnet_lite0"])
def test_channels_last_changes_rounding_only(trunk):
    """Within float32 rounding of NCHW (the pretrained trunk stays NCHW, see model.cpu)."""
    c = cfg()
    c["model"]["trunk"] = trunk
    torch.manual_seed(0)
    model = build_model(c, load_rig("configs/rigs/mixed.yaml"))
    fast = cpu.channels_last(copy.deepcopy(model))
    x = torch.rand(2, 5, 3, 40, 64)
    a, b = model(x), fast(x)
    for k in a:
        assert float((a[k] - b[k]).detach().norm()) <= 3e-4 * float(a[k].detach().norm()), k
    (a["semantic"].square().mean() + a["occlusion"].mean()).backward()
    (b["semantic"].square().mean() + b["occlusion"].mean()).backward()
    for (n, p), q in zip(model.named_parameters(), fast.parameters()):
        assert float((p.grad - q.grad).norm()) <= 3e-3 * float(p.grad.norm()) + 1e-12, n
    # the state dict loads into a model of either layout unchanged
    plain = build_model(c, load_rig("configs/rigs/mixed.yaml"))
    plain.load_state_dict(fast.state_dict())
    assert all(torch.equal(p, q) for p, q in zip(plain.parameters(), fast.parameters()))


def test_the_pretrained_trunk_runs_nhwc_in_bf16_and_nchw_in_fp32():
    """model.cpu: the EfficientNet trunk (`keep_contiguous`) stays NCHW in fp32, where its NHWC
    backward rounds worse, and runs NHWC in bf16 (0.81x its forward + backward, docs/model.md), as
    close to fp32's outputs as NCHW in bf16 is (this small untrained model with batch statistics
    over 2 samples amplifies bf16's rounding to about 25 % of the output either way)."""
    def config(precision):
        c = cfg()
        c["model"].update(trunk="efficientnet_lite0", precision=precision, trunk_frozen=1, norm="batch")
        return c

    rig = load_rig("configs/rigs/mixed.yaml")
    torch.manual_seed(0)
    models = {p: build_model(config(p), rig) for p in ("fp32", "bf16")}
    models["bf16"].load_state_dict(models["fp32"].state_dict())
    nchw = cpu.channels_last(copy.deepcopy(models["bf16"]))  # the rule until 2026-12-07
    before = torch.get_num_threads()
    try:
        for p, model in models.items():
            cpu.tune_cpu(config(p), torch.device("cpu"), model)
            stem = model.encoder.stem[0].weight
            assert stem.is_contiguous(memory_format=torch.channels_last) == (p == "bf16"), p
            assert model.bev.stem[0].weight.is_contiguous(memory_format=torch.channels_last), p
    finally:
        torch.set_num_threads(before)
    x = torch.rand(2, 5, 3, 40, 64)
    with torch.no_grad():  # training mode: batch statistics
        ref, a, b = models["fp32"](x), nchw(x), models["bf16"](x)
    for k in ref:
        err_nchw, err_nhwc = (float((o[k] - ref[k]).norm() / ref[k].norm()) for o in (a, b))
        assert 0 < err_nhwc <= 1.25 * err_nchw, (k, err_nhwc, err_nchw)
