"""Where a training step spends its time, on a data set of yours.

    PYTHONPATH=. python -m bench.profile_step DATA_ROOT [--config cpu_default]
        [--steps 20] [--trunk NAME] [--set k=v ...]

Runs the training step as model.training does (same loader, model, loss with the config's terms,
optimiser; not the moving average of the weights), but splits the backward at the trunk's and the
splat's outputs so that each part's forward and backward is timed on its own (the gradients are
the same), and times the loader's parts (decoding, augmentation, lift geometry) on the same samples
in this process. Prints a table of median milliseconds per step, then torch.profiler's top
operators over the same steps.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np
import torch

from common.resources import CODE_DIR

ROOT = CODE_DIR  # the checkout (common.resources)


def _ms(ts):
    return 1000 * statistics.median(ts) if ts else float("nan")


def loader_parts(ds, indices) -> dict:
    """Per-sample costs of BevDataset.__getitem__'s parts, in this process."""
    from dataset_tools.format.reader import read_frame

    from model.augment import random_transform, warp_image

    parts = {"decode": [], "lift geometry": [], "warp": [], "colour jitter": [], "whole sample": []}
    a = ds.augment
    for i in indices:
        ref = ds.refs[i]
        t0 = time.perf_counter()
        f = read_frame(ref, cameras=ds.names, num_classes=len(ds.class_names))
        t1 = time.perf_counter()
        frustum, rectify = ds.geometry_of(ref, f["meta"])
        rng = np.random.default_rng([0, 0, i])
        if a:
            tr = [random_transform(rc.camera, ds.input_size, rng, a["scale"], a["rotation_deg"], a["crop"]) for rc in frustum.rig]
            frustum.geometry(tr, intrinsics=frustum.reads_intrinsics)  # as the data set does
            if frustum.ground:
                frustum.ground_grid(tr)
        else:
            tr = frustum.nominal_transforms()
        t2 = time.perf_counter()
        imgs = [warp_image(f["images"][rc.name], rc.camera, t) for rc, t in zip(frustum.rig, tr)]
        images = torch.from_numpy(np.stack(imgs)).permute(0, 3, 1, 2).float() / 255.0
        t3 = time.perf_counter()
        if ds.jitter is not None:
            ds.jitter(images)
        t4 = time.perf_counter()
        ds[i]
        t5 = time.perf_counter()
        for k, v in zip(parts, (t1 - t0, t2 - t1, t3 - t2, t4 - t3, t5 - t4)):
            parts[k].append(v)
    return {k: _ms(v) for k, v in parts.items()}


def main(argv=None):
    from common.resources import preset
    from common.schema import deep_merge
    from model.config import load_config, parse_overrides
    from model.cpu import resolve_precision
    from model.losses import config_loss
    from model.splat import splat

    from .model import training_setup

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", type=Path)
    ap.add_argument("--config", default="cpu_default",
                    help="the training config (a file or a preset's name) whose step is profiled; default "
                         "cpu_default, cpu_medium is the default chain's")
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--trunk", default=None, help="model.trunk (default: the config's)")
    ap.add_argument("--set", nargs="+", action="extend", default=[], help="config overrides key=value (repeatable: every --set counts)")
    ap.add_argument("--no-profiler", action="store_true")
    args = ap.parse_args(argv)
    given = {"data": {"root": str(args.data)}, **({"model": {"trunk": args.trunk}} if args.trunk else {})}
    path = preset(args.config, "train")
    cfg = load_config(path, deep_merge(given, parse_overrides(args.set)))
    t, m = cfg["train"], cfg["model"]
    print(f"{path.name}: trunk {m['trunk']} (frozen levels {m['trunk_frozen']}"
          f"{', depthwise weights frozen' if m['trunk_depthwise_frozen'] else ''}), {m['norm']} norm, input "
          f"{'x'.join(map(str, cfg['data']['input_size']))}, precision {resolve_precision(m['precision'], torch.device('cpu'))}")
    model, opt, alpha, loader = training_setup(cfg)
    sampler, ds = loader.batch_sampler, loader.dataset
    names = ["data wait", "trunk fwd", "splat index", "splat fwd", "bev encoder+heads fwd", "loss",
             "bev encoder+heads bwd", "splat bwd", "trunk bwd", "optimiser (clip+step)", "whole step"]
    times = {k: [] for k in names}
    steps = min(args.steps, len(sampler))
    if steps < 3:
        raise SystemExit(f"{args.data}: {len(sampler)} training batches of {t['batch_size']} with --steps {args.steps}; "
                         "the profile needs at least 3 (warm-up, then the steps it times)")
    it = iter(loader)
    prof = None
    if not args.no_profiler:
        prof = torch.profiler.profile(activities=[torch.profiler.ProfilerActivity.CPU], schedule=torch.profiler.schedule(wait=1, warmup=1, active=steps - 2))
        prof.start()
    for k in range(steps):
        marks = [time.perf_counter()]
        batch = next(it)
        marks.append(time.perf_counter())
        depth_logits, ctx = model.lift_logits(batch["images"])
        marks.append(time.perf_counter())
        index = model._index(batch.get("point_cell"), depth_logits.shape[0])
        marks.append(time.perf_counter())
        l2, c2 = depth_logits.detach().requires_grad_(), ctx.detach().requires_grad_()
        feats = splat(l2.softmax(2), c2, index)
        marks.append(time.perf_counter())
        f2 = feats.detach().requires_grad_()
        out = model.bev_outputs(f2, index, *depth_logits.shape[:2], batch.get("intrinsics"),
                                model.ground_samples(batch["images"], batch.get("ground_grid")))
        out = model.training_outputs(out, l2, c2)  # the depth and camera-view terms' outputs
        marks.append(time.perf_counter())
        loss, _ = config_loss(out, batch, alpha, cfg["loss"])
        marks.append(time.perf_counter())
        opt.zero_grad(set_to_none=True)
        loss.backward()
        marks.append(time.perf_counter())
        feats.backward(f2.grad)
        marks.append(time.perf_counter())
        torch.autograd.backward([depth_logits, ctx], [l2.grad, c2.grad])
        marks.append(time.perf_counter())
        torch.nn.utils.clip_grad_norm_(model.parameters(), t["grad_clip"])
        opt.step()
        marks.append(time.perf_counter())
        if k >= 2:  # the loader's start and first-step allocations
            for name, a, b in zip(names, marks, marks[1:]):
                times[name].append(b - a)
            times["whole step"].append(marks[-1] - marks[0])
        if prof:
            prof.step()
    if prof:
        prof.stop()
    per_step = {k: _ms(v) for k, v in times.items()}
    print(f"median ms per step of {t['batch_size']} samples over {len(times['whole step'])} steps "
          f"({torch.get_num_threads()} threads, {cfg['data']['num_workers']} loader workers):")
    for k, v in per_step.items():
        print(f"  {k:28s} {v:8.1f}")
    print(f"  samples/s                    {t['batch_size'] * 1000 / per_step['whole step']:8.2f}")
    lp = loader_parts(ds, list(range(min(8, len(ds)))))
    print("loader, median ms per sample in this process:")
    for k, v in lp.items():
        print(f"  {k:28s} {v:8.1f}")
    if prof:
        print(prof.key_averages(group_by_input_shape=True).table(sort_by="self_cpu_time_total", row_limit=25, max_name_column_width=40, max_shapes_column_width=60))
    return 0


if __name__ == "__main__":
    from common.cli import run_cli

    run_cli(main, prog="bench.profile_step")
