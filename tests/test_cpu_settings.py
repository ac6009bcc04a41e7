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
