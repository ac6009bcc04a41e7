"""CPU settings of a training or inference process, measured on the 2-core machine.

- Compute threads: the cores shared among the processes of a CPU DDP run (all of them for one
  process). An earlier rule left the loader workers their cores (1 compute thread on 2 cores with
  cpu_default's loader worker): faster on a machine loaded by other jobs, but on an idle 2-core
  machine 0.82x the training samples/s and 1.6x the inference time of 2 threads
  (docs/benchmarks.md); the loader worker is idle most of a step. The count depends
  only on the machine's cores and the process count (never on its load), so a resumed run computes
  with the same threads as an uninterrupted one.
- channels_last weights: oneDNN's convolutions and GroupNorm run faster in NHWC on CPU, and the
  splat already hands the BEV encoder an NHWC grid. A module with `keep_contiguous = True` (the
  pretrained EfficientNet trunk, whose BatchNorm/depthwise backward in NHWC was 20x further from a
  float64 reference than in NCHW: 2.5e-2 against 1e-3 relative) stays NCHW in fp32; in bf16 it
  runs NHWC too: its gradients are as far from float64 either way (bf16's rounding, 0.38 relative
  with batch statistics), and its forward + backward takes 0.81x (docs/model.md, "The trunk in NHWC
  in bf16").

`train.threads` (> 0) overrides the count. The GPU path is left as it was.

`model.precision: auto` (the default chain's) is bf16 where the device computes it natively
(`native_bf16`: a CPU with AVX512-BF16 or AMX-BF16, a CUDA device with bf16) and fp32 elsewhere, where
bf16 would be emulated, slower than fp32 (docs/model.md).
"""

from __future__ import annotations

import os

import torch


def cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def compute_threads(processes: int = 1) -> int:
    """Intra-op threads of one of `processes` processes on this machine."""
    return max(1, cores() // max(1, processes))


def cpu_flags() -> set[str]:
    """The CPU's feature flags (/proc/cpuinfo; empty where there is none)."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("flags"):
                    return set(line.split(":", 1)[1].split())
    except OSError:
        pass
    return set()


def native_bf16(device: torch.device) -> str:
    """Why `device` computes bf16 natively ("AVX512-BF16", "AMX-BF16", "CUDA bf16"), or "" if it does not."""
    if device.type == "cuda":
        return "CUDA bf16" if torch.cuda.is_bf16_supported() else ""
    if device.type != "cpu":
        return ""
    flags = cpu_flags()
    return "AMX-BF16" if "amx_bf16" in flags else "AVX512-BF16" if "avx512_bf16" in flags else ""


def resolve_precision(precision: str, device: torch.device) -> str:
    """model.precision as run on `device`: fp32 or bf16 as given; auto -> bf16 where native_bf16, else fp32."""
    if precision != "auto":
        return precision
    return "bf16" if native_bf16(device) else "fp32"


def tune_cpu(cfg: dict, device: torch.device, model: torch.nn.Module | None = None, processes: int = 1) -> None:
    """Thread count and memory format for the config's run on `device` (nothing on a GPU)."""
    if device.type != "cpu":
        return
    threads = cfg["train"]["threads"] or compute_threads(processes)
    torch.set_num_threads(threads)
    if model is not None:
        channels_last(model, every=resolve_precision(cfg["model"]["precision"], device) == "bf16")


def channels_last(model: torch.nn.Module, every: bool = False) -> torch.nn.Module:
    """The model's 4-D weights in NHWC, but for modules marked `keep_contiguous` (`every`: theirs too)."""
    model.to(memory_format=torch.channels_last)
    if not every:
        for m in model.modules():
            if getattr(m, "keep_contiguous", False):
                m.to(memory_format=torch.contiguous_format)
    return model
