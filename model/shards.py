"""Training from WebDataset shards (`data.shards` in a training config): a stream of samples with a
shuffle buffer, for one process or DDP.

    data:
      shards: "exports/demo/train-{000000..000003}.tar"   # brace pattern; local paths, file: or pipe: URLs
      shuffle_buffer: 64

The shards' `shards.json` (beside them: the pattern's folder or URL prefix, or `data.shards_index`)
gives the class names, grid, rig and split sizes, so the model is built as from the folder. Each
epoch has the folder loader's steps (the split's frames // the effective batch); every process (DDP
rank) and loader worker reads its own shards (all shards, keeping every n-th sample, when there are
fewer shards than readers), cycling through them until it has its batches, so every rank makes the
same number of steps. Shard order and the shuffle buffer (drained at the end of each pass over a
reader's shards, so a pass never repeats a frame) are seeded by (seed, epoch, rank, worker);
a sample's augmentation by (seed, epoch, its place in the split), as the folder loader's. A resumed
run restarts the epoch's stream for the steps it has left (not bit for bit the uninterrupted run).
The validation split is read from its shards into memory (test splits are small).
"""

from __future__ import annotations

import random

from torch.utils.data import IterableDataset, get_worker_info

from common.errors import ConfigError
from dataset_tools.format.layout import DatasetError
from dataset_tools.format.reader import DatasetIndex
from dataset_tools.format.shards import SHARDS_INDEX, decode_sample, expand_urls, read_shard_index, shard_samples, shards_base

from .data import BevDataset


def shard_index(cfg: dict) -> tuple[dict, DatasetIndex, str]:
    """(shards.json, the data set's index from it, the shards' base) of `data.shards`."""
    d = cfg["data"]
    base = shards_base(d["shards"])
    where = d["shards_index"] or (base + SHARDS_INDEX if base else SHARDS_INDEX)
    shards = read_shard_index(where)
    return shards, DatasetIndex(base.rstrip("/") or ".", shards["index"]), base


class ShardStream(IterableDataset):
    """The training samples of `urls` (one split's shards), made by `ds` (a BevDataset of that
    split, which is never indexed); each process gets `batch` samples per step."""

    def __init__(self, urls: list[str], ds: BevDataset, batch: int, rank: int, world: int, seed: int, buffer: int):
        if not urls:
            raise ConfigError("data.shards: the pattern names no shard")
        self.urls, self.ds, self.batch, self.rank, self.world = list(urls), ds, batch, rank, world
        self.seed, self.buffer = seed, buffer
        self.epoch, self.start = 0, 0
        self.class_names = ds.class_names

    def __len__(self):
        return len(self.ds)

    def set_epoch(self, epoch: int, start: int = 0) -> None:
        """The epoch to stream and the step it starts at (a resumed run)."""
        self.epoch, self.start = int(epoch), int(start)
        self.ds.set_epoch(epoch)

    def steps(self) -> int:
        return len(self.ds) // (self.batch * self.world)

    def _share(self, worker: int, workers: int):
        """(this reader's shard URLs, keep every `stride`-th sample from offset `offset`)."""
        readers, me = self.world * workers, self.rank * workers + worker
        if len(self.urls) >= readers:
            return self.urls[me::readers], 1, 0
        return self.urls, readers, me

    def _samples(self, urls, stride, offset, rng):
        """Undecoded samples of `urls`, forever: a pass over them in a shuffled order, None, another pass, ..."""
        while True:
            order = list(urls)
            rng.shuffle(order)
            seen = 0
            for j, (url, key, members) in enumerate(shard_samples(order)):
                if j % stride == offset:
                    seen += 1
                    yield url, key, members
            if not seen:
                raise DatasetError(f"{', '.join(urls[:3])}: no samples in these shards")
            yield None

    INITIAL = 8  # samples the buffer holds before it starts to serve

    def _shuffled(self, source, rng):
        """`source` through a shuffle buffer of `self.buffer` samples, drained at the end of every
        pass, so a pass never repeats a frame. It serves from INITIAL samples on while it grows (two
        in for each one out) to `self.buffer`, as webdataset's shuffle does: waiting for a full
        buffer (with small passes, the whole pass) before the first sample cost every epoch the
        time of reading it."""
        buf: list = []
        it = iter(source)
        for item in it:
            if item is None:
                rng.shuffle(buf)
                yield from buf
                buf = []
                continue
            buf.append(item)
            if len(buf) < self.buffer:  # grow: take one more while serving one
                more = next(it, None)
                if more is None:  # the pass ended
                    rng.shuffle(buf)
                    yield from buf
                    buf = []
                    continue
                buf.append(more)
            if len(buf) >= min(self.INITIAL, self.buffer):
                k = rng.randrange(len(buf))
                buf[k], buf[-1] = buf[-1], buf[k]
                yield buf.pop()

    def __iter__(self):
        info = get_worker_info()
        worker, workers = (info.id, info.num_workers) if info else (0, 1)
        mine = sum(1 for k in range(self.start, self.steps()) if k % workers == worker)  # the DataLoader takes workers' batches in turn
        need = mine * self.batch
        if not need:
            return
        urls, stride, offset = self._share(worker, workers)
        rng = random.Random(f"{self.seed}/{self.epoch}/{self.rank}/{worker}/{self.start}")
        for made, item in enumerate(self._shuffled(self._samples(urls, stride, offset, rng), rng)):
            if made >= need:
                return
            yield self._sample(*item)

    def _sample(self, url: str, key: str, members: dict) -> dict:
        ds = self.ds
        f = decode_sample(url, key, members, ds.names, len(ds.class_names), targets=ds.camera_targets, instance=False)
        pos = f["frame"].get("position") if isinstance(f["frame"], dict) else None
        if not isinstance(pos, int) or not 0 <= pos < len(ds.refs) or ds.refs[pos].scene != f["frame"].get("scene"):
            raise DatasetError(f"{url}: sample {key}: frame.json does not match shards.json's split (export again)")
        return ds.make_sample(ds.refs[pos], f, pos)


def split_urls(shards: dict, base: str, split: str) -> list[str]:
    if split not in shards["splits"]:
        raise ConfigError(f"data: no split '{split}' in the shards (have: {', '.join(shards['splits'])})")
    return [base + s["file"] for s in shards["splits"][split]["shards"]]


def in_memory(index: DatasetIndex, urls: list[str], split: str, cfg: dict) -> BevDataset:
    """A split read from its shards into memory (validation), as a BevDataset."""
    ds = BevDataset(index, split, cfg, train=False, frames={})
    for url, key, members in shard_samples(urls):
        f = decode_sample(url, key, members, ds.names, len(ds.class_names), targets=False, instance=False)
        ds.frames[f["frame"]["position"]] = f
    if sorted(ds.frames) != list(range(len(ds.refs))):
        raise DatasetError(f"{urls[0]}: split '{split}' holds {len(ds.frames)} frames, shards.json lists {len(ds.refs)}")
    return ds


def shard_datasets(cfg: dict, rank: int, world: int, per_rank_batch: int):
    """(index, training stream, validation data set or None) of `data.shards`."""
    d, t = cfg["data"], cfg["train"]
    shards, index, base = shard_index(cfg)
    urls = expand_urls(d["shards"])
    train_ds = BevDataset(index, d["train_split"], cfg, train=True)
    stream = ShardStream(urls, train_ds, per_rank_batch, rank, world, t["seed"], d["shuffle_buffer"])
    val = None
    if d["val_split"] and d["val_split"] in shards["splits"]:
        val = in_memory(index, split_urls(shards, base, d["val_split"]), d["val_split"], cfg)
    elif d["val_split"] and d["val_split"] not in index.splits:
        raise ConfigError(f"data.val_split: no split '{d['val_split']}' in the shards (have: {', '.join(shards['splits'])}; '' for none)")
    return index, stream, val
