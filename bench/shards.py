"""The training loader's samples/s, from a data set folder against its WebDataset shards (issue 35).

    PYTHONPATH=. python -m bench.shards --config configs/train/demo.yaml --data data/demo \
        --shards "data/demo_wds/train-{000000..000003}.tar" [--batches 7] [--rounds 5] [--workers 1]

Both loaders make the same samples (the config's augmentation and camera-view targets) and batches
as train.py does, without the model; the rounds alternate folder and shards so a busy machine
slows both alike. Prints samples/s per round and the median of each.
"""

from __future__ import annotations

import argparse
import statistics
import time

from torch.utils.data import DataLoader

from model.config import load_config
from model.data import BevDataset
from model.shards import shard_datasets
from model.training import EpochBatches, effective_batch


def _rate(loader, batches: int, per_batch: int) -> float:
    t0 = time.perf_counter()
    n = 0
    for n, _ in enumerate(loader, 1):
        if n >= batches:
            break
    return n * per_batch / (time.perf_counter() - t0)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default="configs/train/demo.yaml")
    ap.add_argument("--data", default="data/demo")
    ap.add_argument("--shards", required=True)
    ap.add_argument("--batches", type=int, default=7, help="batches per round (at most one epoch's)")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--workers", type=int, default=None, help="loader workers (default: the config's data.num_workers)")
    a = ap.parse_args(argv)
    over = {"data": {"root": a.data, "val_split": ""}}
    if a.workers is not None:
        over["data"]["num_workers"] = a.workers
    cfg = load_config(a.config, over)
    t = cfg["train"]
    eb, workers = effective_batch(t), cfg["data"]["num_workers"]
    folder = BevDataset(cfg["data"]["root"], cfg["data"]["train_split"], cfg, train=True)
    scfg = load_config(a.config, {**over, "data": {**over["data"], "shards": a.shards}})
    _, stream, _ = shard_datasets(scfg, 0, 1, eb)
    rates = {"folder": [], "shards": []}
    for r in range(a.rounds):
        folder.set_epoch(r)
        sampler = EpochBatches(len(folder), eb, t["seed"], r, 0, 1)
        stream.set_epoch(r)
        loaders = {"folder": DataLoader(folder, batch_sampler=sampler, num_workers=workers),
                   "shards": DataLoader(stream, batch_size=eb, num_workers=workers)}
        for name in ("folder", "shards") if r % 2 == 0 else ("shards", "folder"):
            rates[name].append(_rate(loaders[name], min(a.batches, len(folder) // eb), eb))
            print(f"round {r}: {name} {rates[name][-1]:.1f} samples/s", flush=True)
    for name, v in rates.items():
        print(f"{name}: median {statistics.median(v):.1f} samples/s over {len(v)} rounds ({workers} loader workers)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
