"""Bench: the HTML QA report (dataset_tools.qa.html_report) at the `small` preset's sizes (480x302 fisheye,
400x400 label grid). Renders and fuses a few frames of one small-preset scene, builds the report
from nothing, then again with nothing to redo, and scales the per-frame time and size to a
200-frame data set (the whole small preset; goal: under ~100 MB).

    from bench.report import run; run()  ->  {"report_s_per_frame": ..., ...}
"""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

SCENE = "urban_block"
FRAMES = 3
DATASET_FRAMES = 200


def run(frames: int = FRAMES, scene: str = SCENE) -> dict:
    from dataset_tools.fuse import fuse_dataset
    from common.resources import CODE_DIR as REPO
    from dataset_tools.generation.dataset_config import load_config
    from dataset_tools.generation.driver import render as generate
    from dataset_tools.labels.label_fusion import FusionConfig
    from dataset_tools.qa.html_report import build_report, report_size

    cfg = load_config(REPO / "configs" / "dataset" / "small.yaml")
    cfg["scenes"] = [s for s in cfg["scenes"] if s["name"] == scene]
    for s in cfg["scenes"]:
        s["recipe"]["frames"]["count"] = frames
    with tempfile.TemporaryDirectory(prefix="bench_report_") as tmp:
        data = Path(tmp) / "ds"
        if generate(cfg, data, workers=1, progress=False):
            raise RuntimeError("bench.report: generation failed")
        if fuse_dataset(data, FusionConfig(), progress=False):
            raise RuntimeError("bench.report: fusion failed")
        out = data / "report"
        t0 = time.perf_counter()
        build_report(data, out, progress=False)
        cold = time.perf_counter() - t0
        t0 = time.perf_counter()
        build_report(data, out, progress=False)
        warm = time.perf_counter() - t0
        frame_bytes = sum(p.stat().st_size for p in (out / "frames").rglob("*") if p.is_file()) / frames
        total = report_size(out)
        shared = total - frame_bytes * frames  # overview, scene pages, contact sheet, assets
    mb_200 = (frame_bytes * DATASET_FRAMES + shared) / 1e6
    per_frame = (cold - warm) / frames  # the rebuild with nothing to redo still draws the figures and pages
    return {
        "preset": "small (480x302 fisheye, 400x400 grid)",
        "scene": scene,
        "frames": frames,
        "report_s_per_frame": {"value": per_frame, "unit": "s", "goal": None, "met": None},
        "report_cold_s": {"value": cold, "unit": "s", "goal": None, "met": None},
        "report_nothing_to_redo_s": {"value": warm, "unit": "s", "goal": None, "met": None},
        "report_kb_per_frame": {"value": frame_bytes / 1e3, "unit": "KB", "goal": None, "met": None},
        "report_mb_for_200_frames": {"value": mb_200, "unit": "MB", "goal": "<= 100", "met": mb_200 <= 100},
        "report_min_for_200_frames": {"value": (per_frame * DATASET_FRAMES + warm) / 60, "unit": "min", "goal": None, "met": None},
    }


if __name__ == "__main__":
    print(json.dumps(run(), indent=1))
