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


@pytest.mark.parametrize("flags, chosen", [({"avx2", "avx512f"}, "fp32"), ({"avx512f", "avx512_bf16"}, "bf16"),
                                           ({"amx_tile", "amx_bf16"}, "bf16"), (set(), "fp32")])
def test_auto_is_bf16_only_where_the_cpu_computes_it(monkeypatch, flags, chosen):
    import model.cpu as cpu

    monkeypatch.setattr(cpu, "cpu_flags", lambda: flags)
    assert cpu.resolve_precision("auto", torch.device("cpu")) == chosen
    assert cpu.resolve_precision("fp32", torch.device("cpu")) == "fp32"  # given: as given, on any CPU
    assert cpu.resolve_precision("bf16", torch.device("cpu")) == "bf16"
    assert build_model(cfg("auto"), load_rig("configs/rigs/mixed.yaml")).bf16 == (chosen == "bf16")


def test_a_run_records_what_auto_chose_and_a_resume_keeps_it(monkeypatch, tmp_path, capsys):
    """train.py decides auto once: the config it saves in its checkpoints says fp32 or bf16 (eval
    runs the same); a resumed run keeps its checkpoint's choice, also on a CPU that would choose
    otherwise."""
    import model.cpu as cpu
    from model.training import run_precision

    latest = tmp_path / "latest.pt"
    monkeypatch.setattr(cpu, "cpu_flags", lambda: {"avx512_bf16"})
    c = run_precision(cfg("auto"), torch.device("cpu"), latest, quiet=False)
    assert c["model"]["precision"] == "bf16"
    assert "model.precision auto: bf16 (this CPU computes bf16 natively (AVX512-BF16))" in capsys.readouterr().err
    assert run_precision(cfg("fp32"), torch.device("cpu"), latest) == cfg("fp32")  # only auto is decided
    torch.save({"config": c, "rig": load_rig("configs/rigs/mixed.yaml").to_dict(), "model": {}}, latest)
    monkeypatch.setattr(cpu, "cpu_flags", lambda: {"avx2"})
    assert run_precision(cfg("auto"), torch.device("cpu"), latest)["model"]["precision"] == "bf16"
    latest.unlink()
    assert run_precision(cfg("auto"), torch.device("cpu"), latest)["model"]["precision"] == "fp32"
