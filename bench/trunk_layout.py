"""The pretrained trunk in NCHW and in NHWC (channels_last), in fp32 and bf16: its forward +
backward time, and how far its trained weights' gradients are from a float64 copy's.

    PYTHONPATH=. python -m bench.trunk_layout [--config cpu_medium] [--images 16] [--rounds 5]

The trunk of the config (`model.trunk: efficientnet_lite0`, its frozen levels and depthwise option) in
training mode on `--images` random images at the config's input size, with random output gradients
(seeded); the float64 reference is the same trunk in NCHW. model.cpu runs the trunk NHWC in bf16 and
NCHW in fp32 on these figures (docs/model.md, "The trunk in NHWC in bf16").
"""

from __future__ import annotations

import argparse
import copy
import statistics
import time

import torch


def gradients(enc, x, bf16: bool) -> dict:
    enc.zero_grad(set_to_none=True)
    with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
        depth, ctx = enc(x)
    g = torch.Generator().manual_seed(1)
    gd, gc = (torch.randn(t.shape, generator=g, dtype=torch.float64) for t in (depth, ctx))
    ((depth.double() * gd).sum() + (ctx.double() * gc).sum()).backward()
    return {n: p.grad.detach().double().clone() for n, p in enc.named_parameters() if p.grad is not None}


def relative_error(got: dict, ref: dict) -> float:
    num = sum(float(((got[n] - ref[n]) ** 2).sum()) for n in ref)
    return (num / sum(float((ref[n] ** 2).sum()) for n in ref)) ** 0.5


def main(argv=None):
    from common.resources import preset
    from model.config import load_config
    from model.lss import make_encoder

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default="cpu_medium", help="a training config (file or preset name) with a pretrained trunk")
    ap.add_argument("--images", type=int, default=16, help="images per pass (the default chain's batch of 4 x 4 cameras)")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--threads", type=int, default=0, help="torch threads (default: the machine's cores)")
    args = ap.parse_args(argv)
    cfg = load_config(preset(args.config, "train"))
    if cfg["model"]["trunk"] != "efficientnet_lite0":
        raise SystemExit(f"{args.config}: model.trunk is {cfg['model']['trunk']}; this compares the pretrained trunk's layouts")
    if args.threads:
        torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    enc = make_encoder(cfg["model"]).train()
    w, h = cfg["data"]["input_size"]
    x = enc.normalise(torch.rand(args.images, 3, h, w))
    ref = gradients(copy.deepcopy(enc).double(), x.double(), bf16=False)
    print(f"{args.config}: trunk forward + backward on {args.images} images of {w}x{h}, {torch.get_num_threads()} threads")
    print(f"{'layout':8s} {'precision':9s} {'ms (median)':>12s} {'grad error vs float64':>22s}")
    for name, fmt in (("NCHW", torch.contiguous_format), ("NHWC", torch.channels_last)):
        e, xi = copy.deepcopy(enc).to(memory_format=fmt), x.contiguous(memory_format=fmt)
        for bf16 in (False, True):
            err = relative_error(gradients(e, xi, bf16), ref)
            ts = []
            for _ in range(args.rounds):
                t = time.perf_counter()
                gradients(e, xi, bf16)
                ts.append(time.perf_counter() - t)
            print(f"{name:8s} {'bf16' if bf16 else 'fp32':9s} {1000 * statistics.median(ts):12.1f} {err:22.2e}")
    return 0


if __name__ == "__main__":
    from common.cli import run_cli

    run_cli(main, prog="bench.trunk_layout")
