"""Bench: cost of the supersampled top-down label passes. One `small`-preset scene (urban_block,
400 x 400 label grid) is built in Blender once; both label renders of a frame (render_topdown, in
label_mode) are timed at 1 sample per cell and at the preset's supersampling, alternately, best of
a few, so that the ratio holds on a busy machine too. bench.scenes times whole frames.

    from bench.topdown import run; run()
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

REPEAT = 3


def run(repeat: int = REPEAT) -> dict:
    import bpy

    from blender_scripts.build_scene import build_scene, set_frame
    from blender_scripts.render_frame import configure_render, label_mode, render_topdown
    from common.resources import CODE_DIR as REPO
    from dataset_tools.generation.dataset_config import load_config
    from dataset_tools.generation.recipe import load_recipe
    from geometry.bev import BevGrid
    from geometry.rig import load_rig

    cfg = load_config(REPO / "configs" / "dataset" / "small.yaml")
    td = cfg["topdown"]
    n = td["supersample"]
    grid = BevGrid(-td["bound"], td["bound"], -td["bound"], td["bound"], 2 * td["bound"] / td["size"])
    rig = load_rig(REPO / "configs" / "rigs" / "default.yaml")
    with tempfile.TemporaryDirectory(prefix="bench_topdown_") as tmp:
        tmp = Path(tmp)
        built = build_scene(load_recipe(REPO / "scenes" / "urban_block.yaml"), rig, grid, td["height_m"], str(tmp / "osl"))
        scene = bpy.context.scene
        configure_render(scene, samples=1, denoise=False, threads=len(__import__("os").sched_getaffinity(0)))
        frame = set_frame(built, 1)
        best = {1: float("inf"), n: float("inf")}
        with label_mode(scene):
            render_topdown(scene, built.topdown, td["size"], built.occluders, frame["world_to_ego"], tmp, n)  # warm up
            for _ in range(repeat):
                for k in best:
                    t0 = time.perf_counter()
                    render_topdown(scene, built.topdown, td["size"], built.occluders, frame["world_to_ego"], tmp, k,
                                   td["marking_share"])
                    best[k] = min(best[k], time.perf_counter() - t0)
    return {
        "top-down label passes, 1 sample per cell": {"value": round(best[1], 3), "unit": "s/frame", "goal": None, "met": None},
        f"top-down label passes, {n}x{n} coverage": {"value": round(best[n], 3), "unit": "s/frame", "goal": None, "met": None},
        "top-down coverage cost ratio": {"value": round(best[n] / best[1], 2), "unit": "x", "goal": None, "met": None},
    }


if __name__ == "__main__":
    for k, v in run().items():
        print(f"{k}: {v['value']} {v['unit']}")
