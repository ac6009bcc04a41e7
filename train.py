"""Train the LSS-fisheye BEV model.

    python train.py --config configs/train/cpu_default.yaml [--out runs/cpu_default] [--set train.lr=1e-4 ...]
    torchrun --nproc_per_node 2 train.py --config ...          # DDP (gloo on CPU, nccl on GPU)

A run directory holds latest.pt, best.pt (best validation mIoU) and TensorBoard logs. Running the
same command again resumes from latest.pt and continues exactly as an uninterrupted run would.
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import sys
import threading
import time
from pathlib import Path

import torch
import torch.distributed as dist
from torch.utils.data import DataLoader

from dataset_tools.reader import DatasetError, DatasetIndex
from geometry.cameras import CameraError
from geometry.rig import RigError
from model import CheckpointError, build_model, save_checkpoint
from model.checkpoint import model_part
from model.config import ConfigError, load_config, parse_override
from model.data import BevDataset, DataError
from model.losses import class_weights, total_loss
from model.metrics import BevMetrics

PALETTE = torch.tensor([[0, 0, 0], [220, 40, 40], [250, 250, 250], [110, 110, 120], [70, 150, 70]], dtype=torch.uint8)


class EpochBatches:
    """This process's share of each global batch of an epoch, from a permutation seeded by
    (seed, epoch); starts at batch `start` (resume). Incomplete last batches are dropped."""

    def __init__(self, n: int, batch: int, seed: int, epoch: int, rank: int, world: int, start: int = 0, shuffle=True):
        self.n, self.batch, self.rank, self.world, self.start = n, batch, rank, world, start
        g = torch.Generator().manual_seed(seed * 7919 + epoch)
        self.order = torch.randperm(n, generator=g).tolist() if shuffle else list(range(n))

    def __len__(self):
        return max(0, self.n // self.batch - self.start)

    def __iter__(self):
        for k in range(self.start, self.n // self.batch):
            yield self.order[k * self.batch : (k + 1) * self.batch][self.rank :: self.world]


def colourise(sem: torch.Tensor, vis: torch.Tensor | None = None) -> torch.Tensor:
    img = PALETTE[sem.clamp(0, 4).long()].float()
    if vis is not None:
        img = img * (0.35 + 0.65 * (vis >= 0.5).float())[..., None]
    return img.permute(2, 0, 1) / 255.0


def to_device(batch: dict, device) -> dict:
    return {k: (v.to(device, non_blocking=True) if isinstance(v, torch.Tensor) else v) for k, v in batch.items()}


def setup_distributed(device_kind: str):
    world = int(os.environ.get("WORLD_SIZE", "1"))
    rank = int(os.environ.get("RANK", "0"))
    local = int(os.environ.get("LOCAL_RANK", "0"))
    cuda = device_kind == "cuda" or (device_kind == "auto" and torch.cuda.is_available())
    device = torch.device(f"cuda:{local}" if cuda else "cpu")
    if cuda:
        torch.cuda.set_device(device)
    if world > 1:
        dist.init_process_group("nccl" if cuda else "gloo")
    return rank, world, device


@torch.no_grad()
def evaluate(model, ds, cfg, device, rank, world) -> dict:
    model.eval()
    metrics = BevMetrics(ds.class_names)
    n = len(ds) if not cfg["train"]["val_max_frames"] else min(len(ds), cfg["train"]["val_max_frames"])
    idx = list(range(n))[rank::world]
    loader = DataLoader(torch.utils.data.Subset(ds, idx), batch_size=max(1, cfg["train"]["batch_size"] // world),
                        num_workers=cfg["data"]["num_workers"], generator=torch.Generator())
    for batch in loader:
        batch = to_device(batch, device)
        out = model(batch["images"], batch["point_cell"], batch["intrinsics"])
        metrics.update(out, batch)
    if world > 1:
        for t in (metrics.cm, metrics.occ):
            dist.all_reduce(t)
    model.train()
    return metrics.compute()


def train(cfg: dict, out_dir: Path, quiet: bool = False) -> dict:
    t_cfg = cfg["train"]
    if t_cfg["threads"]:
        torch.set_num_threads(t_cfg["threads"])
    rank, world, device = setup_distributed(t_cfg["device"])
    if t_cfg["batch_size"] % world:
        raise ConfigError(f"train.batch_size: {t_cfg['batch_size']} is not divisible by {world} processes")
    index = DatasetIndex(cfg["data"]["root"])
    train_ds = BevDataset(index, cfg["data"]["train_split"], cfg, train=True)
    val_split = cfg["data"]["val_split"]
    val_ds = BevDataset(index, val_split, cfg, train=False) if val_split and index.splits.get(val_split) else None
    if len(train_ds) < t_cfg["batch_size"]:
        raise DataError(f"{index.root}: split '{cfg['data']['train_split']}' has {len(train_ds)} frames, fewer than train.batch_size {t_cfg['batch_size']}")

    torch.manual_seed(t_cfg["seed"])
    model = build_model(cfg, index.rig, len(index.class_names)).to(device)
    if world > 1 and cfg["model"]["norm"] == "batch" and device.type == "cuda":
        # batch statistics over the global batch (on CPU, BatchNorm stays per process; GroupNorm,
        # the default, needs neither)
        model = torch.nn.SyncBatchNorm.convert_sync_batchnorm(model)
    opt = torch.optim.Adam(model.parameters(), lr=t_cfg["lr"], weight_decay=t_cfg["weight_decay"])
    step, epoch, step_in_epoch, best = 0, 0, 0, -1.0
    latest = out_dir / "latest.pt"
    if latest.is_file():
        try:
            ckpt = torch.load(latest, map_location="cpu", weights_only=False)
        except Exception as exc:  # a truncated or foreign file; ours are written atomically
            raise CheckpointError(f"{latest}: cannot read checkpoint ({type(exc).__name__}); move it away to start afresh") from None
        if model_part(ckpt["config"]) != model_part(cfg) or ckpt.get("rig") != index.rig.to_dict():
            raise CheckpointError(f"{latest}: checkpoint is from another config or rig; use another --out")
        model.load_state_dict(ckpt["model"])
        opt.load_state_dict(ckpt["optimizer"])
        step, epoch, step_in_epoch, best = ckpt["step"], ckpt["epoch"], ckpt["step_in_epoch"], ckpt["best"]
        torch.set_rng_state(ckpt["rng"])
        if device.type == "cuda" and ckpt.get("cuda_rng") is not None:
            torch.cuda.set_rng_state(ckpt["cuda_rng"], device)
        if rank == 0 and not quiet:
            print(f"resuming from {latest} at step {step} (epoch {epoch})", file=sys.stderr)
    ddp = torch.nn.parallel.DistributedDataParallel(model) if world > 1 else model
    alpha = class_weights(cfg["loss"]["class_weights"]).to(device)
    lam, use_vis, occ_t = cfg["loss"]["occlusion_weight"], cfg["loss"]["visibility_weighting"], cfg["loss"]["occlusion_target"]
    writer = None
    if rank == 0:
        from torch.utils.tensorboard import SummaryWriter

        writer = SummaryWriter(str(out_dir / "tb"))

    def state(ep, sie):
        return {"config": cfg, "rig": index.rig.to_dict(), "num_classes": len(index.class_names),
                "model": model.state_dict(), "optimizer": opt.state_dict(), "step": step, "epoch": ep,
                "step_in_epoch": sie, "best": best, "rng": torch.get_rng_state(),
                "cuda_rng": torch.cuda.get_rng_state(device) if device.type == "cuda" else None}

    def validate_and_keep_best(ep, sie):
        nonlocal best
        if val_ds is None:
            return None
        res = evaluate(model, val_ds, cfg, device, rank, world)
        if rank == 0:
            for k, v in res.items():
                if not math.isnan(v):
                    writer.add_scalar(f"val/{k}", v, step)
            if res["miou"] > best:
                best = res["miou"]
                save_checkpoint(out_dir / "best.pt", state(ep, sie))
        return res

    # Ctrl-C / SIGTERM (single process): finish the step, save latest.pt, exit; a second Ctrl-C
    # stops at once. Under DDP the default handling stays (ranks could stop at different steps).
    stop = {"now": False}
    if world == 1 and threading.current_thread() is threading.main_thread():
        def on_signal(signum, frame):
            if stop["now"]:
                raise KeyboardInterrupt
            stop["now"] = True

        signal.signal(signal.SIGINT, on_signal)
        signal.signal(signal.SIGTERM, on_signal)

    max_steps = t_cfg["max_steps"] or None
    steps_per_epoch = len(train_ds) // t_cfg["batch_size"]
    total = min(max_steps or 10**12, steps_per_epoch * t_cfg["epochs"])
    from tqdm import tqdm

    bar = tqdm(total=total, initial=step, disable=rank != 0 or quiet, desc="train", dynamic_ncols=True)
    history, last_val = [], None
    t0, samples = time.time(), 0
    done = max_steps is not None and step >= max_steps
    while epoch < t_cfg["epochs"] and not done:
        train_ds.set_epoch(epoch)
        sampler = EpochBatches(len(train_ds), t_cfg["batch_size"], t_cfg["seed"], epoch, rank, world, step_in_epoch)
        # own generator: creating an iterator must not draw from the global RNG (dropout), or a
        # resumed run would diverge from an uninterrupted one
        loader = DataLoader(train_ds, batch_sampler=sampler, num_workers=cfg["data"]["num_workers"],
                            generator=torch.Generator().manual_seed(t_cfg["seed"] + epoch))
        batches = iter(loader)
        while True:
            try:
                batch = next(batches)
            except StopIteration:
                break
            except Exception:
                if stop["now"]:  # data workers died of the same Ctrl-C: stop at the last whole step
                    break
                raise
            batch = to_device(batch, device)
            out = ddp(batch["images"], batch["point_cell"], batch["intrinsics"])
            loss, parts = total_loss(out, batch, alpha, lam, use_vis, occ_t)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            if t_cfg["grad_clip"] > 0:
                torch.nn.utils.clip_grad_norm_(model.parameters(), t_cfg["grad_clip"])
            opt.step()
            step += 1
            step_in_epoch += 1
            samples += t_cfg["batch_size"]
            history.append(loss.item())
            if rank == 0:
                bar.update(1)
                bar.set_postfix(loss=f"{float(loss):.3f}")
                if step % t_cfg["log_every"] == 0 or step == 1:
                    writer.add_scalar("train/loss", float(loss), step)
                    writer.add_scalar("train/semantic", float(parts["semantic"]), step)
                    writer.add_scalar("train/occlusion", float(parts["occlusion"]), step)
                    writer.add_scalar("train/samples_per_s", samples / max(time.time() - t0, 1e-9), step)
                if t_cfg["image_every"] and step % t_cfg["image_every"] == 0:
                    pred = out["semantic"][0].argmax(0).cpu() + 1
                    truth = batch["semantic"][0].cpu()
                    vis = batch["visibility"][0].cpu()
                    gap = torch.ones(3, truth.shape[0], 4)
                    writer.add_image("bev/prediction_truth", torch.cat([colourise(pred), gap, colourise(truth, vis)], 2), step)
            if t_cfg["val_every"] and step % t_cfg["val_every"] == 0:
                last_val = validate_and_keep_best(epoch, step_in_epoch)
            if rank == 0 and step % t_cfg["checkpoint_every"] == 0:
                save_checkpoint(latest, state(epoch, step_in_epoch))
            if max_steps is not None and step >= max_steps:
                done = True
                break
            if stop["now"]:
                break
        if stop["now"]:
            if rank == 0:
                save_checkpoint(latest, state(epoch, step_in_epoch))
            raise KeyboardInterrupt
        if not done:
            epoch, step_in_epoch = epoch + 1, 0
            if not t_cfg["val_every"]:
                last_val = validate_and_keep_best(epoch, 0)
        if rank == 0:
            save_checkpoint(latest, state(epoch, step_in_epoch))
    bar.close()
    if writer is not None:
        writer.close()
    if world > 1:
        dist.barrier()
        dist.destroy_process_group()
    return {"step": step, "losses": history, "val": last_val, "best": best}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description="Train the LSS-fisheye BEV model.")
    p.add_argument("--config", default="configs/train/cpu_default.yaml")
    p.add_argument("--out", help="run directory (default runs/<config name>)")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.FIELD=VALUE", help="override a config field")
    p.add_argument("--quiet", action="store_true")
    a = p.parse_args(argv)
    try:
        overrides: dict = {}
        from model.config import _deep_merge

        for s in a.set:
            overrides = _deep_merge(overrides, parse_override(s))
        cfg = load_config(a.config, overrides)
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    out = Path(a.out or Path("runs") / Path(a.config).stem)
    out.mkdir(parents=True, exist_ok=True)
    try:
        res = train(cfg, out, a.quiet)
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except (DatasetError, DataError, CheckpointError, RigError, CameraError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"\ninterrupted; {out / 'latest.pt'} holds the last whole step: run the same command to resume", file=sys.stderr)
        return 130
    if int(os.environ.get("RANK", "0")) == 0 and not a.quiet:
        v = res["val"]
        print(f"done: step {res['step']}, last loss {res['losses'][-1] if res['losses'] else float('nan'):.4f}"
              + (f", val mIoU {v['miou']:.3f}" if v else ""), file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
