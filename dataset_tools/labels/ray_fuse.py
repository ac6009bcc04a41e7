"""Fusion on a Ray cluster (`fuse --backend ray`): frames as Ray tasks in batches.

A batch is one task (one CPU) that fuses its frames with `fuse.fuse_one` and writes their labels
into the shared data set; results stream back per batch for the driver's progress bar. Fusion is
idempotent (atomic writes), so a batch lost with its node is simply run again (Ray's task
retries).
"""

from __future__ import annotations

from common.raycluster import connect

from ..generation.config import REPO


def _fuse_batch(dirs: list[str], cfg: dict) -> list:
    from dataset_tools.fuse import fuse_one
    from dataset_tools.labels.fusion import FusionConfig

    c = FusionConfig(**cfg)
    return [fuse_one(d, c) for d in dirs]


def fuse_on_ray(frame_dirs: list[str], cfg, address: str | None = None, batch: int | None = None):
    """Yield (frame_dir, problem or None) for every frame, batch by batch as they finish."""
    ray = connect(address, code_dir=REPO)
    if not frame_dirs:
        return
    cpus = max(1, int(ray.cluster_resources().get("CPU", 1)))
    # a few batches per CPU balance the load; batches of a few frames keep scheduling cheap
    batch = batch or max(1, min(16, -(-len(frame_dirs) // (4 * cpus))))
    task = ray.remote(num_cpus=1, max_retries=3)(_fuse_batch)
    cfg_dict = cfg.to_dict()
    pending = [task.remote(frame_dirs[i:i + batch], cfg_dict) for i in range(0, len(frame_dirs), batch)]
    while pending:
        ready, pending = ray.wait(pending, num_returns=1)
        yield from ray.get(ready[0])
