"""Bench: seconds per frame of the `small` preset, split into fisheye renders, top-down renders
(supersampled coverage labels, topdown.supersample per axis) and writing. Renders a few frames of two small-preset scenes with one worker using every core.

    from bench.scenes import run; run()  ->  {"fisheye_s_per_frame": ..., ...}
"""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

import numpy as np

from dataset_tools.format.meta import read_meta
from common.resources import CODE_DIR as REPO
from dataset_tools.generation.dataset_config import load_config
from dataset_tools.generation.driver import render as generate

SCENES = ("highway_straight", "urban_block")
FRAMES = 3


def run(frames: int = FRAMES, scenes=SCENES) -> dict:
    cfg = load_config(REPO / "configs" / "dataset" / "small.yaml")
    cfg["scenes"] = [s for s in cfg["scenes"] if s["name"] in scenes]
    for s in cfg["scenes"]:
        s["recipe"]["frames"]["count"] = frames
    with tempfile.TemporaryDirectory(prefix="bench_scenes_") as tmp:
        t0 = time.perf_counter()
        rc = generate(cfg, Path(tmp), workers=1, progress=False)
        wall = time.perf_counter() - t0
        if rc:
            raise RuntimeError("bench.scenes: generation failed")
        metas = [read_meta(p.parent) for p in sorted(Path(tmp).glob("*/*/meta.json"))]
    # the first frame of a scene also builds the BVH and compiles shaders: report it apart
    steady = [m.timings for m in metas if m.frame > 0]
    first = [m.timings for m in metas if m.frame == 0]
    mean = lambda rows, k: float(np.mean([r[k] for r in rows])) if rows else float("nan")  # noqa: E731
    return {
        "preset": "small",
        "topdown_supersample": cfg["topdown"]["supersample"],
        "scenes": list(scenes),
        "frames": len(metas),
        "fisheye_s_per_frame": mean(steady, "fisheye_s"),
        "topdown_s_per_frame": mean(steady, "topdown_s"),
        "write_s_per_frame": mean(steady, "write_s"),
        "total_s_per_frame": mean(steady, "frame_s"),
        "first_frame_s": mean(first, "frame_s"),
        "scene_build_s": mean(first, "build_s"),
        "wall_s_per_frame_incl_startup": wall / max(1, len(metas)),
        "goals": {"total_s_per_frame": "<= 4"},
    }


if __name__ == "__main__":
    print(json.dumps(run(), indent=1))
