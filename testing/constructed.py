"""Constructed frames with exact passes: a ground plane and axis-aligned boxes, ray-cast through the
rig's camera models (geometry), written in the renderer's file layout (real EXR and PNG files).

Used by the label tests and the fusion bench, where the answer must be known without Blender
(testing.blender_constructed renders the same geometry in Blender).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dataset_tools.format.exr import write_exr
from dataset_tools.format.layout import FrameFiles, Manifest, frame_dir_name
from dataset_tools.format.meta import FrameMeta, write_meta
from dataset_tools.format.png import write_png_atomic
from dataset_tools.labels.classes import CLASS_IDS, OVERHEAD_OCCLUDERS, colorize
from dataset_tools.labels.visibility import camera_table

NO_HIT = 1e10  # Cycles' background depth
GROUND_INSTANCE = 1


@dataclass(frozen=True)
class Box:
    """Axis-aligned box in the ego frame (metres) with a fine class and instance id."""

    x0: float
    x1: float
    y0: float
    y1: float
    z0: float
    z1: float
    fine: str = "vehicle"
    instance: int = 2


def ground_class_lanes(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Road with 0.15 m lane lines at y = +-1.75 m and +-5.25 m, terrain beyond |y| > 7 m."""
    cls = np.full(np.shape(x), CLASS_IDS["road"], np.int64)
    for yl in (-5.25, -1.75, 1.75, 5.25):
        cls[np.abs(y - yl) < 0.075] = CLASS_IDS["lane_marking"]
    cls[np.abs(y) > 7.0] = CLASS_IDS["terrain"]
    return cls


def cast(origin: np.ndarray, rays: np.ndarray, boxes, ground_fn=ground_class_lanes):
    """Nearest hit along rays (N, 3) from origin (3,): distance (N,), fine class, instance (N,)."""
    origin = np.asarray(origin, np.float64)
    rays = np.asarray(rays, np.float64)
    n = rays.shape[0]
    dist = np.full(n, np.inf)
    fine = np.zeros(n, np.int64)
    inst = np.zeros(n, np.int64)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -origin[2] / rays[:, 2]  # ground plane z = 0
    hit = (rays[:, 2] < 0) & (t > 0)
    dist[hit] = t[hit]
    p = origin + rays * np.where(hit, t, 0)[:, None]
    fine[hit] = ground_fn(p[hit, 0], p[hit, 1])
    inst[hit] = GROUND_INSTANCE
    for b in boxes:
        lo = np.array([b.x0, b.y0, b.z0])
        hi = np.array([b.x1, b.y1, b.z1])
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / rays
            t0 = (lo - origin) * inv
            t1 = (hi - origin) * inv
        tmin = np.nanmax(np.minimum(t0, t1), axis=1)
        tmax = np.nanmin(np.maximum(t0, t1), axis=1)
        tb = np.where(tmin > 0, tmin, tmax)
        h = (tmax >= tmin) & (tb > 0) & (tb < dist)
        dist[h] = tb[h]
        fine[h] = CLASS_IDS[b.fine]
        inst[h] = b.instance
    return dist, fine, inst


def render_camera(rc, boxes, ground_fn=ground_class_lanes) -> dict:
    """Exact passes of one rig camera: distance (float32, 1e10 where nothing is hit or the model is
    invalid), semantic and instance (uint32), position (float32 ego-frame xyz, (H, W, 3))."""
    t = camera_table(rc)
    h, w = t.shape
    px = np.flatnonzero(t.valid)
    rays = t.rays.reshape(-1, 3)[px]
    d = np.full(h * w, NO_HIT)
    f = np.zeros(h * w, np.int64)
    i = np.zeros(h * w, np.int64)
    pos = np.zeros((h * w, 3))
    dv, fv, iv = cast(t.origin, rays, boxes, ground_fn)
    ok = np.isfinite(dv)
    d[px[ok]], f[px[ok]], i[px[ok]] = dv[ok], fv[ok], iv[ok]
    pos[px[ok]] = t.origin + rays[ok].astype(np.float64) * dv[ok, None]
    return {
        "distance": d.reshape(h, w).astype(np.float32),
        "semantic": f.reshape(h, w).astype(np.uint32),
        "instance": i.reshape(h, w).astype(np.uint32),
        "position": pos.reshape(h, w, 3).astype(np.float32),
    }


def render_topdown(grid, boxes, hide_occluders: bool, ground_fn=ground_class_lanes) -> dict:
    """Top-down orthographic passes on the label grid (pixel (i, j) = cell (i, j))."""
    c = grid.cell_centres()
    x, y = c[..., 0], c[..., 1]
    sem = ground_fn(x, y)
    inst = np.full(x.shape, GROUND_INSTANCE, np.int64)
    height = np.zeros(x.shape)
    for b in boxes:
        if hide_occluders and CLASS_IDS[b.fine] in OVERHEAD_OCCLUDERS:
            continue
        m = (x >= b.x0) & (x <= b.x1) & (y >= b.y0) & (y <= b.y1) & (b.z1 > height)
        sem[m], inst[m], height[m] = CLASS_IDS[b.fine], b.instance, b.z1
    return {"semantic": sem.astype(np.uint32), "instance": inst.astype(np.uint32), "height": height.astype(np.float32)}


def write_frame(frame_dir, rig, grid, boxes, ground_fn=ground_class_lanes, meta: dict | None = None) -> Path:
    """A frame directory in the renderer's layout (blender_scripts/render_frame.py): cam_<name>.exr
    (R, G, B, distance, semantic, instance, position.X/Y/Z) and .png, topdown.exr ('all.' first hit
    and 'ground.' with overhead occluders hidden: semantic, instance, height), meta.json (`meta`:
    more FrameMeta fields)."""
    files = FrameFiles(frame_dir)
    files.dir.mkdir(parents=True, exist_ok=True)
    for rc in rig:
        p = render_camera(rc, boxes, ground_fn)
        rgb = colorize(p["semantic"]).astype(np.float32) / 255.0
        ch = {c: rgb[..., k].astype(np.float16) for k, c in enumerate("RGB")}
        ch.update(distance=p["distance"], semantic=p["semantic"], instance=p["instance"])
        ch.update({f"position.{c}": p["position"][..., k] for k, c in enumerate("XYZ")})
        write_exr(files.camera_exr(rc.name), ch)
        write_png_atomic(files.camera_png(rc.name), colorize(p["semantic"]))
    first = render_topdown(grid, boxes, False, ground_fn)
    hidden = render_topdown(grid, boxes, True, ground_fn)
    ch = {**{f"all.{k}": v for k, v in first.items()}, **{f"ground.{k}": v for k, v in hidden.items()}}
    write_exr(files.topdown, ch)
    m = {"rig": rig.to_dict(), "weather": {"preset": "clear_noon"}, "topdown": {"grid": grid.to_dict()}}
    m.update(meta or {})
    write_meta(files.dir, FrameMeta(**m))
    return files.dir


def write_dataset(root, rig, grid, frames) -> Path:
    """frames: list of (scene, frame, split, boxes). Writes the frames and manifest.jsonl."""
    root = Path(root)
    manifest = Manifest(root)
    for scene, frame, split, boxes in frames:
        rel = frame_dir_name(scene, frame)
        write_frame(root / rel, rig, grid, boxes)
        manifest.append({"scene": scene, "frame": frame, "split": split, "dir": rel})
    return root
