"""Bench: rendering throughput with the local pool and with Ray on this machine, and Ray's
start-up cost. Renders the same frames (two `small`-preset scenes) twice, both with one worker
per core and one thread each; Ray runs a local instance (loopback only) started before timing.

    from bench.ray_backend import run; run()  ->  {"local_frames_per_s": ..., "ray_overhead_ratio": ...}
"""

from __future__ import annotations

import json
import os
import tempfile
import time
from pathlib import Path

from common.resources import CODE_DIR as REPO
from dataset_tools.generation.dataset_config import load_config
from dataset_tools.generation.driver import render as generate

SCENES = ("highway_straight", "urban_block")
FRAMES = 4


def _config(frames: int, scenes) -> dict:
    cfg = load_config(REPO / "configs" / "dataset" / "small.yaml")
    cfg["scenes"] = [s for s in cfg["scenes"] if s["name"] in scenes]
    for s in cfg["scenes"]:
        s["recipe"]["frames"]["count"] = frames
    return cfg


def _render(cfg: dict, **kw) -> float:
    with tempfile.TemporaryDirectory(prefix="bench_ray_") as tmp:
        t0 = time.perf_counter()
        if generate(cfg, Path(tmp), progress=False, **kw):
            raise RuntimeError(f"bench.ray_backend: generation failed ({kw})")
        return time.perf_counter() - t0


def run(frames: int = FRAMES, scenes=SCENES) -> dict:
    from common.raycluster import connect

    cfg = _config(frames, scenes)
    n = frames * len(scenes)
    cores = len(os.sched_getaffinity(0))
    local_s = _render(cfg, workers=cores)
    t0 = time.perf_counter()
    ray = connect(None, num_cpus=cores, code_dir=REPO)
    startup_s = time.perf_counter() - t0
    try:
        ray_s = _render(cfg, backend="ray", threads=1)
    finally:
        ray.shutdown()
    return {
        "preset": "small",
        "frames": n,
        "workers": cores,
        "local_frames_per_s": n / local_s,
        "ray_frames_per_s": n / ray_s,
        "ray_overhead_ratio": ray_s / local_s,
        "ray_startup_s": startup_s,
        "goals": {"ray_overhead_ratio": "<= 1.1"},
    }


if __name__ == "__main__":
    print(json.dumps(run(), indent=1))
