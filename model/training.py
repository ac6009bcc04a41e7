"""Training: the fit loop of train.py and the ablation, exact resume, and training to a time budget.

    res = train(cfg, Path("runs/x"))     # resumes from runs/x/latest.pt when there is one
    state = train_with_budget(cfg, Path("runs/x"), budget_s=600)   # the ablation's rows

Read it top to bottom: prepare -> resume -> (train_one_epoch, validate, save_checkpoint) per epoch.
A resumed run continues exactly as an uninterrupted one (same weights bit for bit): the data order
comes from (seed, epoch), augmentation from (seed, epoch, sample), and only the model's dropout
draws from the global RNG, whose state the checkpoint carries.
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

from common.errors import ConfigError, MachineError
from common.files import clean_stale_temps, read_json, write_json_atomic
from common.schema import deep_merge
from dataset_tools import DatasetIndex, colorize_train

from .checkpoint import CheckpointError, build_model, load_weights, read_checkpoint, save_checkpoint
from .cpu import native_bf16, resolve_precision, tune_cpu
from .data import BevDataset, DataError, DataWorker
from .evaluation import validation_scores
from .losses import class_weights, config_loss
from .inference import decode, forward, to_device
from .minutes import MinutesBudget, clock, describe
from .run_dir import RunDir
from .shards import ShardStream, shard_datasets


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


class RunBatches:
    """EpochBatches of every epoch from `epoch` (at batch `start`) up to `epochs`, each sample as
    (epoch, place in the split), which BevDataset augments as that epoch's: one DataLoader, and one
    start of its workers, for the whole run instead of one per epoch (the paper's configuration on a
    GPU, 5 steps an epoch on data/medium, waited 4-5 s at each epoch's first step for new workers:
    docs/benchmarks.md, "The paper configuration on one GPU")."""

    def __init__(self, n: int, batch: int, seed: int, epoch: int, epochs: int, rank: int, world: int, start: int = 0):
        self.n, self.batch, self.seed, self.epoch, self.epochs = n, batch, seed, epoch, epochs
        self.rank, self.world, self.start = rank, world, start

    def _epoch(self, e: int) -> EpochBatches:
        return EpochBatches(self.n, self.batch, self.seed, e, self.rank, self.world, self.start if e == self.epoch else 0)

    def __len__(self):
        return sum(len(self._epoch(e)) for e in range(self.epoch, self.epochs))

    def __iter__(self):
        for e in range(self.epoch, self.epochs):
            for b in self._epoch(e):
                yield [(e, i) for i in b]


class Pieces:
    """Each batch of `batches` (lists of sample indices, all one size) cut into `pieces` consecutive
    parts, so that the DataLoader's workers build one step's batch together: a worker builds whole
    loader batches, and a step of 64 samples from one worker costs 64 samples' time while the others
    wait (a GPU step of the paper configuration waited on it). `join_pieces` puts a step back together."""

    def __init__(self, batches, pieces: int, size: int):
        self.batches, self.per_step = batches, max(1, min(pieces, size))

    def __len__(self):
        return len(self.batches) * self.per_step

    def __iter__(self):
        p = self.per_step
        for b in self.batches:
            cuts = [round(i * len(b) / p) for i in range(p + 1)]
            yield from (b[cuts[i]:cuts[i + 1]] for i in range(p))


def join_pieces(parts: list[dict]) -> dict:
    """One batch of the loader batches `parts` (Pieces of one step), in order; entries that are not
    batched tensors are taken from the first."""
    if len(parts) == 1:
        return parts[0]
    return {k: torch.cat([p[k] for p in parts]) if isinstance(v, torch.Tensor) and v.dim() else v for k, v in parts[0].items()}


def loader_pieces(num_workers: int) -> int:
    """Loader batches per step: one per worker (data.num_workers), none split without workers."""
    return max(1, num_workers)


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
    train_ds: BevDataset | ShardStream
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
    ema: dict | None = None  # train.ema: the averaged weights (state_dict tensors)
    minutes: dict | None = None  # train.minutes: the decision (model.minutes), recorded in the checkpoints
    budget: MinutesBudget | None = None  # train.minutes before the decision

    @property
    def epoch_steps(self) -> int:
        """Optimiser steps of an epoch: its whole effective batches."""
        return len(self.train_ds) // effective_batch(self.cfg["train"])

    @property
    def total_steps(self) -> int:
        """Optimiser steps of the whole run: train.max_steps, or every epoch's steps."""
        t = self.cfg["train"]
        return min(t["max_steps"] or 10**12, self.epoch_steps * t["epochs"])

    @property
    def dir(self) -> RunDir:
        return RunDir(self.out)

    @property
    def latest(self) -> Path:
        return self.dir.latest

    @property
    def main(self) -> bool:
        return self.rank == 0


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


def decay_of_groups(t: dict) -> list[float]:
    """train.weight_decay of each of make_optimizer's parameter groups."""
    return [t["weight_decay"]] if t["decay_vectors"] else [t["weight_decay"], 0.0]


def make_optimizer(cfg: dict, model: torch.nn.Module) -> torch.optim.Optimizer:
    """Adam or AdamW over the model's weights; with train.decay_vectors false the weights of one
    dimension (biases, norms' scale and shift) in a second group that weight_decay leaves alone."""
    t = cfg["train"]
    kind = torch.optim.AdamW if t["optimizer"] == "adamw" else torch.optim.Adam
    params = list(model.parameters())
    groups = [params] if t["decay_vectors"] else [[p for p in params if p.ndim > 1], [p for p in params if p.ndim <= 1]]
    return kind([{"params": g, "weight_decay": wd} for g, wd in zip(groups, decay_of_groups(t))], lr=t["lr"])


def run_precision(cfg: dict, device: torch.device, latest: Path, quiet: bool = True) -> dict:
    """The config with model.precision `auto` decided (a run records what it trains in, so its
    checkpoints, validation and eval.py run the same): a resumed run keeps its checkpoint's, a new
    one takes bf16 where `device` computes it natively, fp32 elsewhere."""
    if cfg["model"]["precision"] != "auto":
        return cfg
    if latest.is_file():
        chosen, why = read_checkpoint(latest)["config"]["model"]["precision"], f"as {latest} was trained"
    else:
        native = native_bf16(device)
        chosen = resolve_precision("auto", device)
        why = f"this {device.type.upper()} computes bf16 natively ({native})" if native else f"no native bf16 on this {device.type.upper()}"
    if not quiet:
        print(f"model.precision auto: {chosen} ({why})", file=sys.stderr)
    return {**cfg, "model": {**cfg["model"], "precision": chosen}}


def prepare(cfg: dict, out: Path, quiet: bool = False) -> Run:
    """Data sets, model and optimiser of a fresh run (seeded)."""
    t = cfg["train"]
    rank, world, device = setup_distributed(t["device"])
    cfg = run_precision(cfg, device, RunDir(out).latest, quiet or rank != 0)
    if t["threads"] and device.type != "cpu":
        torch.set_num_threads(t["threads"])
    if t["batch_size"] % world:
        raise ConfigError(f"train.batch_size: {t['batch_size']} is not divisible by {world} processes")
    if cfg["data"]["shards"]:  # streamed from WebDataset shards (model.shards)
        index, train_ds, val_ds = shard_datasets(cfg, rank, world, effective_batch(t) // world)
    else:
        index = DatasetIndex(cfg["data"]["root"])
        train_ds = BevDataset(index, cfg["data"]["train_split"], cfg, train=True, device_images=device.type != "cpu")
        val_split = cfg["data"]["val_split"]
        if val_split and val_split not in index.splits:
            raise ConfigError(f"data.val_split: no split '{val_split}' in {index.root} (have: {', '.join(index.splits)}; '' for none)")
        val_ds = BevDataset(index, val_split, cfg, train=False) if val_split and index.splits[val_split] else None
    if len(train_ds) < effective_batch(t):
        raise DataError(f"{index.root}: split '{cfg['data']['train_split']}' has {len(train_ds)} frames, fewer than "
                        f"train.batch_size {t['batch_size']}" + (f" x train.accumulate {t['accumulate']}" if t["accumulate"] > 1 else ""))
    torch.manual_seed(t["seed"])
    model = build_model(cfg, index.rig, len(index.class_names)).to(device)
    tune_cpu(cfg, device, model, int(os.environ.get("LOCAL_WORLD_SIZE", world)))  # processes on this machine
    if world > 1 and cfg["model"]["norm"] == "batch" and device.type == "cuda":
        # batch statistics over the global batch (on CPU, BatchNorm stays per process; GroupNorm,
        # the default, needs neither)
        model = torch.nn.SyncBatchNorm.convert_sync_batchnorm(model)
    opt = make_optimizer(cfg, model)
    run = Run(cfg, out, rank, world, device, index, train_ds, val_ds, model, opt, quiet)
    if t["ema"]:
        run.ema = _copy_state(model)
    return run


def _copy_state(model: torch.nn.Module) -> dict:
    return {k: v.detach().clone() for k, v in model.state_dict().items()}


def update_ema(run: Run) -> None:
    """train.ema: after optimiser step `run.step`, average the weights (and BatchNorm's running
    statistics) in with decay min(ema, (1 + step) / (10 + step)), so the first steps are not
    averaged with the initial weights for long; integer buffers are copied."""
    d = min(run.cfg["train"]["ema"], (1 + run.step) / (10 + run.step))
    with torch.no_grad():
        for k, v in run.model.state_dict().items():
            e = run.ema[k]
            if e.dtype.is_floating_point:
                e.mul_(d).add_(v.detach().to(e.dtype), alpha=1 - d)
            else:
                e.copy_(v)


@contextlib.contextmanager
def averaged_weights(run: Run):
    """The model holds the averaged weights inside the block (train.ema; unchanged without it)."""
    if run.ema is None:
        yield
        return
    raw = _copy_state(run.model)
    run.model.load_state_dict(run.ema)
    try:
        yield
    finally:
        run.model.load_state_dict(raw)


def checkpoint_state(run: Run) -> dict:
    """With train.ema, `model` is the averaged weights (what eval and predict load) and `raw` the
    trained ones (what a resume continues)."""
    weights = {"model": run.model.state_dict()} if run.ema is None else {"model": run.ema, "raw": run.model.state_dict()}
    return {"config": run.cfg, "rig": run.index.rig.to_dict(), "num_classes": len(run.index.class_names),
            "class_names": list(run.index.class_names), **weights, "optimizer": run.opt.state_dict(), "step": run.step, "epoch": run.epoch,
            "step_in_epoch": run.step_in_epoch, "best": run.best, "minutes": run.minutes, "rng": torch.get_rng_state(),
            "cuda_rng": torch.cuda.get_rng_state(run.device) if run.device.type == "cuda" else None}


def resume(run: Run) -> None:
    """Continue from latest.pt if there is one: weights, optimiser, counters and RNG."""
    clean_stale_temps(run.out, recursive=False)  # a kill during a save leaves .latest.pt.<pid>.tmp.pt
    if not run.latest.is_file():
        return
    ckpt = read_checkpoint(run.latest, expect_config=run.cfg, expect_rig=run.index.rig, resume=True)
    load_weights(run.model, ckpt.get("raw", ckpt["model"]), run.latest)
    if run.ema is not None:  # the average goes on from the saved one (from the weights if it was off)
        run.ema = {k: v.to(run.device) for k, v in ckpt["model"].items()} if "raw" in ckpt else _copy_state(run.model)
    try:
        run.opt.load_state_dict(ckpt["optimizer"])
        torch.set_rng_state(ckpt["rng"])
    except (RuntimeError, ValueError, KeyError, TypeError) as exc:
        raise CheckpointError(f"{run.latest}: does not fit this model ({str(exc).splitlines()[0][:120]})") from None
    for g, decay in zip(run.opt.param_groups, decay_of_groups(run.cfg["train"])):  # the config's, also when changed for the resume (--set)
        g["lr"], g["weight_decay"] = run.cfg["train"]["lr"], decay
    run.step, run.epoch, run.step_in_epoch, run.best = ckpt["step"], ckpt["epoch"], ckpt["step_in_epoch"], ckpt["best"]
    if run.cfg["train"]["minutes"] and ckpt.get("minutes"):  # the epochs it decided (train.minutes 0 and train.epochs: more)
        decide_epochs(run, ckpt["minutes"])
    if run.device.type == "cuda" and ckpt["cuda_rng"] is not None:
        torch.cuda.set_rng_state(ckpt["cuda_rng"], run.device)
    if run.main and not run.quiet:
        print(f"resuming from {run.latest} at step {run.step} (epoch {run.epoch})", file=sys.stderr)


def decide_epochs(run: Run, record: dict) -> None:
    """train.minutes decided: the run trains record['epochs'] epochs (its config says so from here on)."""
    run.minutes, run.budget = record, None
    run.cfg = {**run.cfg, "train": {**run.cfg["train"], "epochs": record["epochs"]}}


def validate(run: Run) -> dict | None:
    """Score the validation split; keep best.pt when mIoU improves."""
    if run.val_ds is None:
        return None
    with averaged_weights(run):
        res = validation_scores(run.model, run.val_ds, run.cfg, run.device, run.rank, run.world)
    if run.main:
        for k, v in res.items():
            if not math.isnan(v):
                run.writer.add_scalar(f"val/{k}", v, run.step)
        run.writer.flush()  # on disk now (the writer's own flush waits up to 2 min): experiments.tta watches it
        if res["miou"] > run.best:
            run.best = res["miou"]
            save_checkpoint(run.dir.best, checkpoint_state(run))
    run.last_val = res
    return res


def log_step(run: Run, loss, parts: dict, out: dict, batch: dict, samples_per_s: float) -> None:
    t = run.cfg["train"]
    if t["log_every"] and (run.step % t["log_every"] == 0 or run.step == 1):
        run.writer.add_scalar("train/loss", float(loss), run.step)
        run.writer.add_scalar("train/semantic", float(parts["semantic"]), run.step)
        run.writer.add_scalar("train/occlusion", float(parts["occlusion"]), run.step)
        run.writer.add_scalar("train/lr", run.opt.param_groups[0]["lr"], run.step)
        for k in ("depth", "camera_semantic", "dice"):  # present when their loss weight is > 0
            if k in parts:
                run.writer.add_scalar(f"train/{k}", float(parts[k]), run.step)
        run.writer.add_scalar("train/samples_per_s", samples_per_s, run.step)
    if t["image_every"] and run.step % t["image_every"] == 0:
        pred = decode(out).classes[0].cpu().numpy()
        truth, vis = batch["semantic"][0].cpu().numpy(), batch["visibility"][0].cpu().numpy()
        pic = torch.from_numpy(colorize_train(pred)), torch.ones(truth.shape[0], 4, 3, dtype=torch.uint8) * 255, \
            torch.from_numpy(colorize_train(truth, vis))
        run.writer.add_image("bev/prediction_truth", torch.cat(pic, 1).permute(2, 0, 1).float() / 255.0, run.step)


def effective_batch(t: dict) -> int:
    """Samples per optimiser step: train.batch_size x train.accumulate."""
    return t["batch_size"] * t["accumulate"]


def micro_batches(batch: dict, k: int) -> list[dict]:
    """A batch cut into `k` equal micro-batches along the sample axis (its non-tensor entries shared)."""
    if k == 1:
        return [batch]
    n = batch["images"].shape[0]
    size = n // k
    return [{key: v[i * size:(i + 1) * size] if isinstance(v, torch.Tensor) and v.dim() and v.shape[0] == n else v
             for key, v in batch.items()} for i in range(k)]


def learning_rate(t: dict, step: int, total: int) -> float:
    """train.lr at optimiser step `step` (0-based) of `total`: a linear warm-up over
    train.warmup_steps, then constant or a cosine decay to 0 at the last step."""
    lr = t["lr"]
    if t["warmup_steps"] and step < t["warmup_steps"]:
        return lr * (step + 1) / t["warmup_steps"]
    if t["lr_schedule"] == "cosine":
        done = (step - t["warmup_steps"]) / max(1, total - t["warmup_steps"])
        lr *= 0.5 * (1 + math.cos(math.pi * min(1.0, done)))
    return lr


def _loader_options(run: Run) -> dict:
    """The training DataLoader's workers; its own generator: creating an iterator must not draw
    from the global RNG (dropout), or a resumed run would diverge from an uninterrupted one."""
    return dict(num_workers=run.cfg["data"]["num_workers"], worker_init_fn=DataWorker(),
                generator=torch.Generator().manual_seed(run.cfg["train"]["seed"] + run.epoch))


class RunFeed:
    """The folder data set's training batches from the run's (epoch, step_in_epoch) to its last
    epoch (RunBatches), cut into Pieces for the loader's workers, from one DataLoader."""

    def __init__(self, run: Run):
        t = run.cfg["train"]
        share = len(range(run.rank, effective_batch(t), run.world))
        sampler = Pieces(RunBatches(len(run.train_ds), effective_batch(t), t["seed"], run.epoch, t["epochs"], run.rank,
                                    run.world, run.step_in_epoch), loader_pieces(run.cfg["data"]["num_workers"]), share)
        self.per_step = sampler.per_step
        self.batches = iter(DataLoader(run.train_ds, batch_sampler=sampler, **_loader_options(run)))

    def close(self) -> None:
        self.batches = None  # the workers stop with their iterator


def train_one_epoch(run: Run, bar, alpha: torch.Tensor, max_steps: int | None, feed: RunFeed | None = None) -> bool:
    """Train from run.step_in_epoch to the end of run.epoch (or max_steps, or a stop request), from
    `feed` (a folder data set) or an epoch's stream of shards; returns True when training is finished."""
    cfg, t = run.cfg, run.cfg["train"]
    loss_cfg = cfg["loss"]
    k = t["accumulate"]  # each optimiser step: one loader batch of batch_size x k samples, k forward/backward passes
    epoch_steps = None  # a stream ends its epoch itself
    if isinstance(run.train_ds, ShardStream):  # this process's share of each batch, streamed
        run.train_ds.set_epoch(run.epoch, run.step_in_epoch)
        batches = iter(DataLoader(run.train_ds, batch_size=effective_batch(t) // run.world, **_loader_options(run)))
        per_step = 1
    else:
        batches, per_step = feed.batches, feed.per_step
        epoch_steps = run.epoch_steps
    t0, samples = time.time(), 0
    while True:
        if epoch_steps is not None and run.step_in_epoch >= epoch_steps:
            return False
        try:
            batch = join_pieces([next(batches) for _ in range(per_step)])
        except StopIteration:
            return False
        except Exception:
            if run.stop.requested:  # data workers died of the same Ctrl-C: stop at the last whole step
                return False
            raise
        run.opt.zero_grad(set_to_none=True)
        step_loss = 0.0
        batch = to_device(batch, run.device)
        if isinstance(run.train_ds, BevDataset):
            batch = run.train_ds.finish(batch)  # a GPU's images: 8 bits and jitter draws until here
        for i, batch in enumerate(micro_batches(batch, k)):
            # DDP averages gradients once, on the last micro-batch
            with run.ddp.no_sync() if run.world > 1 and i < k - 1 else contextlib.nullcontext():
                out = forward(run.ddp, batch)
                loss, parts = config_loss(out, batch, alpha, loss_cfg)
                (loss / k if k > 1 else loss).backward()  # per-sample means: k micro-batch means average to the batch's
            step_loss += loss.item() / k
        if t["grad_clip"] > 0:
            torch.nn.utils.clip_grad_norm_(run.model.parameters(), t["grad_clip"])
        for g in run.opt.param_groups:
            g["lr"] = learning_rate(t, run.step, run.total_steps)
        run.opt.step()
        run.step += 1
        if run.ema is not None:
            update_ema(run)
        run.step_in_epoch += 1
        if run.budget is not None and (record := run.budget.after_step(run.step, run.epoch_steps, run.world, run.device)):
            decide_epochs(run, record)
            bar.total = run.total_steps
            bar.refresh()
            if run.main and not run.quiet:
                bar.write(describe(record, run.total_steps), file=sys.stderr)
        samples += effective_batch(t)
        run.history.append(step_loss)
        if not math.isfinite(run.history[-1]):
            raise ConfigError(f"train: loss is {run.history[-1]} at step {run.step}; lower train.lr or check the data")
        if run.main:
            bar.update(1)
            bar.set_postfix(loss=f"{run.history[-1]:.3f}")
            log_step(run, run.history[-1], parts, out, batch, samples / max(time.time() - t0, 1e-9))
        if t["val_every"] and run.step % t["val_every"] == 0:
            validate(run)
        if run.main and t["checkpoint_every"] and run.step % t["checkpoint_every"] == 0:
            save_checkpoint(run.latest, checkpoint_state(run))
        if max_steps is not None and run.step >= max_steps:
            return True
        if run.stop.requested:
            return False


def train(cfg: dict, out_dir: Path, quiet: bool = False) -> dict:
    """Train a validated config in the run folder `out_dir` (resuming from its latest.pt), to
    train.epochs (or the epochs train.minutes decides: model.minutes) or train.max_steps.
    -> {'step', 'losses' (this call's), 'val' (the last validation metrics or None), 'best' (best
    validation mIoU)}. A stop request (Ctrl-C, SIGTERM) saves latest.pt and raises KeyboardInterrupt."""
    from tqdm import tqdm

    from .tensorboard_log import TensorBoardLog

    started = clock()
    run = prepare(cfg, out_dir, quiet)
    if run.main and not quiet:  # once: what each camera of the rig the model is built on became
        run.index.rig.print_description(run.index.root)
    resume(run)
    t = cfg["train"]
    if t["minutes"] and run.minutes is None:
        run.budget = MinutesBudget(run.cfg, run.step, started)
    elif run.minutes is not None and run.main and not quiet:
        print(f"{describe(run.minutes, run.total_steps)} (as {run.latest} decided)", file=sys.stderr)
    run.ddp = torch.nn.parallel.DistributedDataParallel(run.model) if run.world > 1 else run.model
    alpha = class_weights(cfg["loss"]["class_weights"]).to(run.device)
    if run.main:
        run.writer = TensorBoardLog(run.dir.tb)  # a write error: one line naming tb/, exit 1
    run.stop = GracefulStop(run.world)
    max_steps = t["max_steps"] or None
    bar = tqdm(total=run.total_steps, initial=run.step, disable=not run.main or quiet, desc="train", dynamic_ncols=True)
    done = max_steps is not None and run.step >= max_steps
    feed = None if done or run.epoch >= run.cfg["train"]["epochs"] or isinstance(run.train_ds, ShardStream) else RunFeed(run)
    try:
        while run.epoch < run.cfg["train"]["epochs"] and not done:  # train.minutes may decide fewer epochs on the way
            done = train_one_epoch(run, bar, alpha, max_steps, feed)
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
    finally:
        if feed is not None:
            feed.close()
    bar.close()
    if run.writer is not None:
        run.writer.close()
    if run.world > 1:
        dist.barrier()
        dist.destroy_process_group()
    return {"step": run.step, "losses": run.history, "val": run.last_val, "best": run.best}


def train_with_budget(cfg: dict, out_dir: Path, budget_s: float | None = None, steps: int | None = None, quiet: bool = False) -> dict:
    """Train to `steps`, or for `budget_s` seconds of training in chunks (`train` resumes exactly
    between them); the training time so far is kept in budget.json, so a killed run resumes with
    the time it had left. -> {'seconds': training time so far, 'step': steps done}."""
    state_path = RunDir(out_dir).budget
    state = read_json(state_path) if state_path.is_file() else {"seconds": 0.0, "step": 0}
    if steps is not None:
        t0 = time.perf_counter()
        res = train(deep_merge(cfg, {"train": {"max_steps": steps}}), out_dir, quiet=quiet)
        state = {"seconds": state["seconds"] + time.perf_counter() - t0, "step": res["step"]}
        write_json_atomic(state_path, state)
        return state
    chunk = 1  # first chunk: time one step (and the run's set-up)
    while state["seconds"] < budget_s:
        target = state["step"] + chunk
        t0 = time.perf_counter()
        res = train(deep_merge(cfg, {"train": {"max_steps": target, "checkpoint_every": max(1, chunk)}}), out_dir, quiet=True)
        spent = time.perf_counter() - t0
        state = {"seconds": state["seconds"] + spent, "step": res["step"]}
        write_json_atomic(state_path, state)
        per_step = spent / max(chunk, 1)
        left = budget_s - state["seconds"]
        chunk = max(1, min(int(left / per_step / 2) if left > 4 * per_step else int(math.ceil(left / per_step)), 10**6))
        if not quiet:
            print(f"  {out_dir}: step {state['step']}, {state['seconds']:.0f}/{budget_s:.0f} s", flush=True)
    return state
