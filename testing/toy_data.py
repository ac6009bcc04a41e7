"""A small constructed data set in the real layout (images + label PNGs + index.json), for tests
and benchmarks before real renders exist or where Blender would be too slow.

Each frame has a random road layout on the ground plane (street band, lane markings, vehicle boxes,
background); every camera image is "rendered" by intersecting each pixel's ray (from geometry) with
the ground plane and colouring it by the class there, so images and labels agree geometrically.

    python -m testing.toy_data OUT --frames 8 [--rig configs/rigs/default.yaml]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from dataset_tools.format.index import build_index, write_index
from dataset_tools.format.labels import write_labels
from dataset_tools.format.layout import FrameFiles, Manifest, frame_dir_name
from dataset_tools.format.meta import FrameMeta, write_meta
from dataset_tools.format.png import write_png_atomic
from dataset_tools.labels.classes import TRAIN_CLASSES
from geometry.bev import BevGrid
from geometry.rig import load_rig

COLOURS = np.array([[20, 20, 20], [200, 30, 30], [240, 240, 240], [90, 90, 100], [60, 140, 60]], np.uint8)
SKY = np.array([150, 190, 230], np.uint8)


def toy_labels(rng: np.random.Generator, grid: BevGrid):
    """(semantic uint8, visibility float32) on the label grid."""
    xy = grid.cell_centres()
    x, y = xy[..., 0], xy[..., 1]
    ang = rng.uniform(-0.3, 0.3)
    off = rng.uniform(-4, 4)
    across = -np.sin(ang) * x + np.cos(ang) * y - off  # lateral distance from the road axis
    half = rng.uniform(4, 7)
    sem = np.full(grid.shape, 4, np.uint8)
    sem[np.abs(across) < half] = 3
    sem[(np.abs(np.abs(across) - half / 2) < 0.15) & (np.abs(across) < half)] = 2
    for _ in range(rng.integers(1, 4)):
        cx, cy = rng.uniform(-15, 15), off + rng.choice([-1, 1]) * half / 2 + rng.uniform(-0.5, 0.5)
        box = (np.abs(x - cx) < 2.2) & (np.abs(y - cy) < 0.9)
        if not ((np.abs(cx) < 5) and (np.abs(cy) < 2)):
            sem[box] = 1
    dist = np.hypot(x - 1.3, y)
    vis = np.clip(1.4 - dist / 20, 0, 1).astype(np.float32)
    sem[dist > 30] = 0
    return sem, vis


def render_camera(rc, sem: np.ndarray, grid: BevGrid, rng) -> np.ndarray:
    origin, rays, valid = rc.rays_ego()
    origin, rays, valid = np.asarray(origin), np.asarray(rays), np.asarray(valid)
    down = rays[..., 2] < -1e-6
    t = np.where(down, -origin[2] / np.minimum(rays[..., 2], -1e-6), 0.0)
    pts = origin + t[..., None] * rays
    row, col, inside = grid.cell_of(pts)
    ok = valid & down & inside
    img = np.broadcast_to(SKY, rays.shape).copy()
    cls = sem[np.clip(row, 0, grid.rows - 1), np.clip(col, 0, grid.cols - 1)]
    img[ok] = COLOURS[cls[ok]]
    noise = rng.normal(0, 6, img.shape)
    return np.clip(img + noise, 0, 255).astype(np.uint8)


def write_toy_dataset(out, frames: int = 8, rig_path="configs/rigs/default.yaml", seed: int = 0,
                      splits=("train",), image_scale: float = 1.0) -> Path:
    """Frames are dealt to `splits` round-robin. image_scale < 1 writes smaller camera images."""
    out = Path(out)
    rig = load_rig(rig_path)
    if image_scale != 1.0:
        rig = rig.map_cameras(lambda c: c.resized(int(round(c.width * image_scale)), int(round(c.height * image_scale))))
    grid = BevGrid()
    rng = np.random.default_rng(seed)
    manifest = Manifest(out)
    for n in range(frames):
        split = splits[n % len(splits)]
        rel = frame_dir_name("toy", n)
        f = FrameFiles(out / rel)
        f.labels.mkdir(parents=True, exist_ok=True)
        sem, vis = toy_labels(rng, grid)
        for rc in rig:
            write_png_atomic(f.camera_png(rc.name), render_camera(rc, sem, grid, rng))
        write_labels(f.dir, {"semantic": sem, "instance": (sem == 1).astype(np.uint16), "visibility": vis})
        write_meta(f.dir, FrameMeta(scene="toy", frame=n, split=split, rig=rig.to_dict(), topdown={"grid": grid.to_dict()}))
        manifest.append({"scene": "toy", "frame": n, "split": split, "dir": rel})
    write_index(out, build_index(out, TRAIN_CLASSES))
    return out


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("out")
    p.add_argument("--frames", type=int, default=8)
    p.add_argument("--rig", default="configs/rigs/default.yaml")
    p.add_argument("--seed", type=int, default=0)
    a = p.parse_args(argv)
    write_toy_dataset(a.out, a.frames, a.rig, a.seed, ("train", "easy"))


if __name__ == "__main__":
    main()
