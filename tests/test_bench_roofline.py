"""bench.model's roofline: a training step's GFLOP is counted from the forward pass
times 3; that factor is checked here on the scratch trunk, whose backward the flop counter counts
right (it has no grouped convolutions), against the counter's own forward + backward."""

import torch
from torch.utils.flop_counter import FlopCounterMode

from bench import model as bm
from geometry.rig import load_rig
from model import build_model
from model.config import load_config


def test_a_training_step_is_three_forward_passes_of_flops():
    cfg = load_config(bm.ROOT / "configs/train/cpu_default.yaml", {"train": {"batch_size": 1}})
    rig = load_rig(bm.ROOT / "configs/rigs/default.yaml")
    model = build_model(cfg, rig)
    assert not any(isinstance(m, torch.nn.Conv2d) and m.groups > 1 for m in model.modules())
    w, h = cfg["data"]["input_size"]
    x = torch.rand(1, len(rig.names), 3, h, w)
    with torch.no_grad(), FlopCounterMode(display=False) as fwd:
        model(x)
    with FlopCounterMode(display=False) as both:
        out = model(x)
        sum(v.float().sum() for v in out.values() if torch.is_tensor(v)).backward()
    ratio = both.get_total_flops() / fwd.get_total_flops()
    assert 2.9 < ratio < 3.05, ratio


def test_step_gflop_counts_the_default_batch():
    g = bm.step_gflop("scratch")["train_gflop_per_step"]
    assert 60 < g < 120, g  # cpu_default, 4 frames of 4 cameras: 84 GFLOP when written


def test_the_share_of_the_peak_is_steps_per_second_times_work_over_the_rate(monkeypatch):
    figures = {"matmul_gflops": {"matmul_gflops_fp32": 200.0, "matmul_gflops_bf16": 400.0},
               "step_gflop": {"train_gflop_per_step": 80.0}}
    monkeypatch.setattr(bm, "_in_child", lambda fn, *args: figures[fn])
    out = bm.roofline({"train_samples_per_s": 5.0, "train_samples_per_s_bf16": 8.0}, ["scratch"])
    assert out["train_share_of_matmul_peak"] == 5.0 / 4 * 80 / 200  # batch 4
    assert out["train_share_of_matmul_peak_bf16"] == 8.0 / 4 * 80 / 400
