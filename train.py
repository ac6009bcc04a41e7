"""Train the LSS-fisheye BEV model.

    python train.py --config configs/train/cpu_default.yaml [--out runs/cpu_default] [--set train.lr=1e-4 ...]
    torchrun --nproc_per_node 2 train.py --config ...          # DDP (gloo on CPU, nccl on GPU)

A run directory holds latest.pt, best.pt (best validation mIoU) and TensorBoard logs. Running the
same command again resumes from latest.pt and continues exactly as an uninterrupted run would.
Read it top to bottom: prepare -> resume -> (train_one_epoch, validate, save_checkpoint) per epoch.
"""

from __future__ import annotations

import contextlib
import math
import os
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch
import torch.distributed as dist
from torch.utils.data import DataLoader

from common.cli import ArgumentParser, EXIT_INTERRUPTED, run_cli
from common.errors import ConfigError, MachineError
from common.files import clean_stale_temps, output_dir
from common.lock import hold_lock
from dataset_tools import DatasetIndex, colorize_train
from model import CheckpointError, build_model, save_checkpoint
from model.checkpoint import model_part
from model.config import load_config, parse_overrides
from model.data import BevDataset, DataError
from model.losses import class_weights, total_loss
from model.metrics import BevMetrics


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


class GracefulStop:
    """Ctrl-C / SIGTERM (single process): finish the step, save latest.pt, exit; a second Ctrl-C
    stops at once. Under DDP the default handling stays (ranks could stop at different steps)."""

    def __init__(self, world: int):
        self.requested = False
        if world == 1 and threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGINT, self._on_signal)
            signal.signal(signal.SIGTERM, self._on_signal)

    def _on_signal(self, signum, frame):
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True


@dataclass
class Run:
    """Everything one training process holds."""

    cfg: dict
    out: Path
    rank: int
    world: int
    device: torch.device
    index: DatasetIndex
    train_ds: BevDataset
    val_ds: BevDataset | None
    model: torch.nn.Module
    opt: torch.optim.Optimizer
    quiet: bool = False
    step: int = 0
    epoch: int = 0
    step_in_epoch: int = 0
    best: float = -1.0
    history: list = field(default_factory=list)
    last_val: dict | None = None
    writer: object = None
    ddp: torch.nn.Module | None = None
    stop: GracefulStop | None = None

    @property
    def latest(self) -> Path:
        return self.out / "latest.pt"

    @property
    def main(self) -> bool:
        return self.rank == 0


def to_device(batch: dict, device) -> dict:
    return {k: (v.to(device, non_blocking=True) if isinstance(v, torch.Tensor) else v) for k, v in batch.items()}


def forward(model, batch: dict) -> dict:
    """The model on a batch: augmented samples bring their cameras' geometry, others use the
    model's cached nominal geometry."""
    return model(batch["images"], batch.get("point_cell"), batch.get("intrinsics"))


def setup_distributed(device_kind: str):
    world = int(os.environ.get("WORLD_SIZE", "1"))
    rank = int(os.environ.get("RANK", "0"))
    local = int(os.environ.get("LOCAL_RANK", "0"))
    if device_kind == "cuda" and not torch.cuda.is_available():
        raise MachineError("train.device: cuda, but this machine has no CUDA device (use auto or cpu)")
    cuda = device_kind == "cuda" or (device_kind == "auto" and torch.cuda.is_available())
    device = torch.device(f"cuda:{local}" if cuda else "cpu")
    if cuda:
        torch.cuda.set_device(device)
    if world > 1:
        dist.init_process_group("nccl" if cuda else "gloo")
    return rank, world, device


def prepare(cfg: dict, out: Path, quiet: bool = False) -> Run:
    """Data sets, model and optimiser of a fresh run (seeded)."""
    t = cfg["train"]
    if t["threads"]:
        torch.set_num_threads(t["threads"])
    rank, world, device = setup_distributed(t["device"])
    if t["batch_size"] % world:
        raise ConfigError(f"train.batch_size: {t['batch_size']} is not divisible by {world} processes")
    index = DatasetIndex(cfg["data"]["root"])
    train_ds = BevDataset(index, cfg["data"]["train_split"], cfg, train=True)
    val_split = cfg["data"]["val_split"]
    if val_split and val_split not in index.splits:
        raise ConfigError(f"data.val_split: no split '{val_split}' in {index.root} (have: {', '.join(index.splits)}; '' for none)")
    val_ds = BevDataset(index, val_split, cfg, train=False) if val_split and index.splits[val_split] else None
    if len(train_ds) < t["batch_size"]:
        raise DataError(f"{index.root}: split '{cfg['data']['train_split']}' has {len(train_ds)} frames, fewer than train.batch_size {t['batch_size']}")
    torch.manual_seed(t["seed"])
    model = build_model(cfg, index.rig, len(index.class_names)).to(device)
    if world > 1 and cfg["model"]["norm"] == "batch" and device.type == "cuda":
        # batch statistics over the global batch (on CPU, BatchNorm stays per process; GroupNorm,
        # the default, needs neither)
        model = torch.nn.SyncBatchNorm.convert_sync_batchnorm(model)
    opt = torch.optim.Adam(model.parameters(), lr=t["lr"], weight_decay=t["weight_decay"])
    return Run(cfg, out, rank, world, device, index, train_ds, val_ds, model, opt, quiet)


def checkpoint_state(run: Run) -> dict:
    return {"config": run.cfg, "rig": run.index.rig.to_dict(), "num_classes": len(run.index.class_names),
            "model": run.model.state_dict(), "optimizer": run.opt.state_dict(), "step": run.step, "epoch": run.epoch,
            "step_in_epoch": run.step_in_epoch, "best": run.best, "rng": torch.get_rng_state(),
            "cuda_rng": torch.cuda.get_rng_state(run.device) if run.device.type == "cuda" else None}


def resume(run: Run) -> None:
    """Continue from latest.pt if there is one: weights, optimiser, counters and RNG."""
    clean_stale_temps(run.out, recursive=False)  # a kill during a save leaves .latest.pt.<pid>.tmp.pt
    if not run.latest.is_file():
        return
    try:
        ckpt = torch.load(run.latest, map_location="cpu", weights_only=False)
    except Exception as exc:  # a truncated or foreign file; ours are written atomically
        raise CheckpointError(f"{run.latest}: cannot read checkpoint ({type(exc).__name__}); move it away to start afresh") from None
    keys = ("config", "rig", "model", "optimizer", "step", "epoch", "step_in_epoch", "best", "rng")
    if not isinstance(ckpt, dict) or any(k not in ckpt for k in keys):
        raise CheckpointError(f"{run.latest}: not a checkpoint of train.py; move it away to start afresh")
    if model_part(ckpt["config"]) != model_part(run.cfg) or ckpt["rig"] != run.index.rig.to_dict():
        raise CheckpointError(f"{run.latest}: checkpoint is from another config or rig; use another --out")
    try:
        run.model.load_state_dict(ckpt["model"])
        run.opt.load_state_dict(ckpt["optimizer"])
        torch.set_rng_state(ckpt["rng"])
    except (RuntimeError, ValueError, KeyError, TypeError) as exc:
        raise CheckpointError(f"{run.latest}: does not fit this model ({str(exc).splitlines()[0][:120]})") from None
    for g in run.opt.param_groups:  # the config's learning rate, also when changed for the resume (--set)
        g["lr"], g["weight_decay"] = run.cfg["train"]["lr"], run.cfg["train"]["weight_decay"]
    run.step, run.epoch, run.step_in_epoch, run.best = ckpt["step"], ckpt["epoch"], ckpt["step_in_epoch"], ckpt["best"]
    if run.device.type == "cuda" and ckpt.get("cuda_rng") is not None:
        torch.cuda.set_rng_state(ckpt["cuda_rng"], run.device)
    if run.main and not run.quiet:
        print(f"resuming from {run.latest} at step {run.step} (epoch {run.epoch})", file=sys.stderr)


@torch.no_grad()
def evaluate(model, ds, cfg, device, rank: int = 0, world: int = 1) -> dict:
    """Validation metrics of `model` on `ds` (each process scores its share, then all-reduce)."""
    model.eval()
    metrics = BevMetrics(ds.class_names)
    n = len(ds) if not cfg["train"]["val_max_frames"] else min(len(ds), cfg["train"]["val_max_frames"])
    loader = DataLoader(torch.utils.data.Subset(ds, list(range(n))[rank::world]), batch_size=max(1, cfg["train"]["batch_size"] // world),
                        num_workers=cfg["data"]["num_workers"], generator=torch.Generator())
    for batch in loader:
        batch = to_device(batch, device)
        metrics.update(forward(model, batch), batch)
    if world > 1:
        for t in (metrics.cm, metrics.occ, metrics.tol):
            dist.all_reduce(t)
    model.train()
    return metrics.compute()


def validate(run: Run) -> dict | None:
    """Score the validation split; keep best.pt when mIoU improves."""
    if run.val_ds is None:
        return None
    res = evaluate(run.model, run.val_ds, run.cfg, run.device, run.rank, run.world)
    if run.main:
        for k, v in res.items():
            if not math.isnan(v):
                run.writer.add_scalar(f"val/{k}", v, run.step)
        if res["miou"] > run.best:
            run.best = res["miou"]
            save_checkpoint(run.out / "best.pt", checkpoint_state(run))
    run.last_val = res
    return res


def log_step(run: Run, loss, parts: dict, out: dict, batch: dict, samples_per_s: float) -> None:
    t = run.cfg["train"]
    if run.step % t["log_every"] == 0 or run.step == 1:
        run.writer.add_scalar("train/loss", float(loss), run.step)
        run.writer.add_scalar("train/semantic", float(parts["semantic"]), run.step)
        run.writer.add_scalar("train/occlusion", float(parts["occlusion"]), run.step)
        for k in ("depth", "camera_semantic"):  # present when their loss weight is > 0
            if k in parts:
                run.writer.add_scalar(f"train/{k}", float(parts[k]), run.step)
        run.writer.add_scalar("train/samples_per_s", samples_per_s, run.step)
    if t["image_every"] and run.step % t["image_every"] == 0:
        pred = (out["semantic"][0].argmax(0) + 1).cpu().numpy()
        truth, vis = batch["semantic"][0].cpu().numpy(), batch["visibility"][0].cpu().numpy()
        pic = torch.from_numpy(colorize_train(pred)), torch.ones(truth.shape[0], 4, 3, dtype=torch.uint8) * 255, \
            torch.from_numpy(colorize_train(truth, vis))
        run.writer.add_image("bev/prediction_truth", torch.cat(pic, 1).permute(2, 0, 1).float() / 255.0, run.step)


def train_one_epoch(run: Run, bar, alpha: torch.Tensor, max_steps: int | None) -> bool:
    """Train from run.step_in_epoch to the end of run.epoch (or max_steps, or a stop request);
    returns True when training is finished."""
    cfg, t = run.cfg, run.cfg["train"]
    loss_cfg = cfg["loss"]
    run.train_ds.set_epoch(run.epoch)
    sampler = EpochBatches(len(run.train_ds), t["batch_size"], t["seed"], run.epoch, run.rank, run.world, run.step_in_epoch)
    # own generator: creating an iterator must not draw from the global RNG (dropout), or a
    # resumed run would diverge from an uninterrupted one
    loader = DataLoader(run.train_ds, batch_sampler=sampler, num_workers=cfg["data"]["num_workers"],
                        generator=torch.Generator().manual_seed(t["seed"] + run.epoch))
    batches = iter(loader)
    t0, samples = time.time(), 0
    while True:
        try:
            batch = next(batches)
        except StopIteration:
            return False
        except Exception:
            if run.stop.requested:  # data workers died of the same Ctrl-C: stop at the last whole step
                return False
            raise
        batch = to_device(batch, run.device)
        out = forward(run.ddp, batch)
        loss, parts = total_loss(out, batch, alpha, loss_cfg["occlusion_weight"], loss_cfg["visibility_weighting"],
                                 loss_cfg["occlusion_target"], loss_cfg["depth_weight"], loss_cfg["camera_seg_weight"])
        run.opt.zero_grad(set_to_none=True)
        loss.backward()
        if t["grad_clip"] > 0:
            torch.nn.utils.clip_grad_norm_(run.model.parameters(), t["grad_clip"])
        run.opt.step()
        run.step += 1
        run.step_in_epoch += 1
        samples += t["batch_size"]
        run.history.append(loss.item())
        if not math.isfinite(run.history[-1]):
            raise ConfigError(f"train: loss is {run.history[-1]} at step {run.step}; lower train.lr or check the data")
        if run.main:
            bar.update(1)
            bar.set_postfix(loss=f"{run.history[-1]:.3f}")
            log_step(run, run.history[-1], parts, out, batch, samples / max(time.time() - t0, 1e-9))
        if t["val_every"] and run.step % t["val_every"] == 0:
            validate(run)
        if run.main and run.step % t["checkpoint_every"] == 0:
            save_checkpoint(run.latest, checkpoint_state(run))
        if max_steps is not None and run.step >= max_steps:
            return True
        if run.stop.requested:
            return False


def train(cfg: dict, out_dir: Path, quiet: bool = False) -> dict:
    from torch.utils.tensorboard import SummaryWriter
    from tqdm import tqdm

    run = prepare(cfg, out_dir, quiet)
    resume(run)
    t = cfg["train"]
    run.ddp = torch.nn.parallel.DistributedDataParallel(run.model) if run.world > 1 else run.model
    alpha = class_weights(cfg["loss"]["class_weights"]).to(run.device)
    if run.main:
        run.writer = SummaryWriter(str(out_dir / "tb"))
    run.stop = GracefulStop(run.world)
    max_steps = t["max_steps"] or None
    total = min(max_steps or 10**12, len(run.train_ds) // t["batch_size"] * t["epochs"])
    bar = tqdm(total=total, initial=run.step, disable=not run.main or quiet, desc="train", dynamic_ncols=True)
    done = max_steps is not None and run.step >= max_steps
    while run.epoch < t["epochs"] and not done:
        done = train_one_epoch(run, bar, alpha, max_steps)
        if run.stop.requested:
            if run.main:
                save_checkpoint(run.latest, checkpoint_state(run))
            raise KeyboardInterrupt
        if not done:
            run.epoch, run.step_in_epoch = run.epoch + 1, 0
            if not t["val_every"]:
                validate(run)
        if run.main:
            save_checkpoint(run.latest, checkpoint_state(run))
    bar.close()
    if run.writer is not None:
        run.writer.close()
    if run.world > 1:
        dist.barrier()
        dist.destroy_process_group()
    return {"step": run.step, "losses": run.history, "val": run.last_val, "best": run.best}


def main(argv=None) -> int:
    p = ArgumentParser(prog="train.py", description="Train the LSS-fisheye BEV model.")
    p.add_argument("--config", default="configs/train/cpu_default.yaml")
    p.add_argument("--out", help="run directory (default runs/<config name>)")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.FIELD=VALUE", help="override a config field")
    p.add_argument("--quiet", action="store_true")
    a = p.parse_args(argv)
    cfg = load_config(a.config, parse_overrides(a.set))
    out = Path(a.out or Path("runs") / Path(a.config).stem)
    output_dir(out)
    # one training run per run folder (rank 0 holds the lock for its DDP peers)
    lock = hold_lock(out) if int(os.environ.get("RANK", "0")) == 0 else contextlib.nullcontext()
    try:
        with lock:
            res = train(cfg, out, a.quiet)
    except KeyboardInterrupt:
        print(f"\ninterrupted; {out / 'latest.pt'} holds the last whole step: run the same command to resume", file=sys.stderr)
        return EXIT_INTERRUPTED
    if int(os.environ.get("RANK", "0")) == 0 and not a.quiet:
        v = res["val"]
        print(f"done: step {res['step']}, last loss {res['losses'][-1] if res['losses'] else float('nan'):.4f}"
              + (f", val mIoU {v['miou']:.3f}" if v else ""), file=sys.stderr)
    return 0


if __name__ == "__main__":
    run_cli(main)
