"""What the rectified baseline of the ablation loses and costs on a data set."""

from __future__ import annotations

import time

import numpy as np

from common.schema import deep_merge

from .rows import EVAL_SPLITS


def rectification_report(cfg: dict, frames: int = 12) -> dict:
    """What the rectified baseline loses and costs on this data set: the share of each fisheye's
    valid pixels the cylinder drops, the share of seen BEV cells (p(o) >= 0.5) no rectified image
    covers (mean over up to `frames` evaluation frames), and the remap time per four-camera frame."""
    from dataset_tools import DatasetIndex, read_frame
    from geometry.rectify import lost_fisheye_pixels, lost_visible_cells
    from model.rectified import rectifier

    index = DatasetIndex(cfg["data"]["root"])
    rect = rectifier(index.rig, deep_merge(cfg, {"data": {"rectify": "cylindrical"}}))
    refs = [r for s in EVAL_SPLITS for r in index.frames(s)] or index.frames(cfg["data"]["train_split"])
    refs = refs[:: max(1, len(refs) // frames)][:frames]
    lost_cells, ms = [], []
    for ref in refs:
        f = read_frame(ref, cameras=index.rig.names)
        t0 = time.perf_counter()
        for n, img in f["images"].items():
            rect(n, img)
        ms.append(1000 * (time.perf_counter() - t0))
        lost_cells.append(lost_visible_cells(index.rig, rect.rig, index.grid, f["visibility"]))
    c = cfg["data"]["cylinder"]
    return {"hfov_deg": c["hfov_deg"], "vfov_deg": c["vfov_deg"],
            "size": [[rc.camera.width, rc.camera.height] for rc in rect.rig][0],
            "lost_fisheye_pixels": {rc.name: lost_fisheye_pixels(rc, rect.rig[rc.name].camera) for rc in index.rig},
            "lost_seen_cells": float(np.mean(lost_cells)) if lost_cells else None, "frames": len(refs),
            "rectify_ms_per_frame": float(np.median(ms)) if ms else None}
