"""Label fusion throughput on one core: a constructed 480x302 four-fisheye frame (default rig, a
400x400 label grid, plane + vehicles + a wall + a canopy), fused from passes in memory and from the
files on disk (EXR reads and label PNG writes included), and the line-of-sight audit of the fused
frame (dataset_tools.qa.audit). Ray tables are built once, outside the timing, as in a fusion run."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from bench import best_of

GOAL_FPS = 20.0


def scene_boxes():
    from testing.constructed import Box

    return [
        Box(6.0, 10.5, -3.2, -1.2, 0.0, 1.5, "vehicle", 3),
        Box(-9.0, -4.5, 1.0, 3.0, 0.0, 1.6, "vehicle", 4),
        Box(12.0, 17.0, 4.0, 6.5, 0.0, 3.2, "vehicle", 5),
        Box(-3.0, 3.0, 8.0, 9.0, 0.0, 4.0, "building", 6),
        Box(5.0, 12.0, -8.0, 8.0, 5.0, 7.0, "canopy", 7),
    ]


def run() -> dict:
    import cv2
    import torch

    cv2.setNumThreads(1)
    torch.set_num_threads(1)
    from dataset_tools.format.labels import write_labels
    from dataset_tools.format.passes import read_frame_passes
    from dataset_tools.labels.label_fusion import FusionConfig, fuse_frame, fuse_passes
    from testing.constructed import write_frame
    from geometry.bev import BevGrid
    from geometry.rig import load_rig

    rig = load_rig("configs/rigs/default.yaml")
    grid = BevGrid()
    cfg = FusionConfig()
    with tempfile.TemporaryDirectory() as tmp:
        frame = write_frame(Path(tmp) / "s/000000", rig, grid, scene_boxes())
        meta, frig, cams, td = read_frame_passes(frame)
        fuse_passes(frig, cams, td, grid, cfg)  # builds the ray tables
        t_mem = best_of(lambda: fuse_passes(frig, cams, td, grid, cfg))
        t_disk = best_of(lambda: write_labels(frame, fuse_frame(frame, cfg)))
        t_read = best_of(lambda: read_frame_passes(frame))
        write_labels(frame, fuse_frame(frame, cfg))
        from dataset_tools.qa.audit import audit_frame

        t_audit = best_of(lambda: audit_frame(frame, cfg))
    fps_mem, fps_disk = 1.0 / t_mem, 1.0 / t_disk
    return {
        "fusion frames/s, passes in memory (1 core)": {"value": round(fps_mem, 1), "unit": "frame/s",
                                                       "goal": f">= {GOAL_FPS:g}", "met": fps_mem >= GOAL_FPS},
        "fusion frames/s, from files (EXR read + PNG write, 1 core)": {"value": round(fps_disk, 1), "unit": "frame/s",
                                                                      "goal": None, "met": None},
        "fusion: reading one frame's 5 EXRs": {"value": round(t_read * 1e3, 1), "unit": "ms", "goal": None, "met": None},
        "line-of-sight audit, one frame (1 core)": {"value": round(t_audit, 2), "unit": "s", "goal": None, "met": None},
    }


if __name__ == "__main__":
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    for k, v in run().items():
        print(f"{k}: {v['value']} {v['unit']}" + (f" (goal {v['goal']}, met {v['met']})" if v["goal"] else ""))
