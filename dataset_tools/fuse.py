"""Fuse one rendered frame's passes into occlusion-corrected BEV labels.

    python -m dataset_tools.fuse <dataset> [--workers N] [--config configs/dataset/small.yaml] [--force]

Per frame, from the renders of dataset_tools.generate:
  semantic    top-down fine classes with overhead occluders hidden, mapped to the training classes;
              the ego's own footprint is invalid (0)
  instance    top-down instance id on vehicle cells, 0 elsewhere (uint16)
  visibility  p(o) from the fisheye distance passes (dataset_tools.visibility), 16-bit PNG

Resumable: a frame whose three label PNGs exist is skipped (each PNG is written atomically, the
visibility last); `--force` redoes every frame. Ends by (re)writing index.json.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from contextlib import contextmanager
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from . import visibility as V
from .classes import CLASS_IDS, DEFAULT_CLASS_MAP, NUM_FINE_CLASSES, TRAIN_CLASSES, class_lut
from .reader import (INSTANCE_PNG, LABEL_DIR, SEMANTIC_PNG, VISIBILITY_PNG, VISIBILITY_SCALE, DatasetError,
                     _read_json)

GROUND_CLASSES = ("road", "lane_marking", "crosswalk", "stop_line", "sidewalk", "curb", "parking", "terrain")
VEHICLE_CLASSES = ("vehicle",)
# Ego body in the ego frame (x forward from the rear axle, y left), metres, when meta.json has none:
# a 4.9 m x 2.0 m car around the default rig's mounts (front camera at x 3.75, rear at -1.05).
DEFAULT_EGO_BOX = (-1.10, 3.85, -1.00, 1.00)


@dataclass
class FusionConfig:
    """Label fusion settings; the `labels:` section of a dataset config overrides these."""

    tau: float = 8.0  # points within the kernel for p(o) = 1, at the reference resolution (README.md, "tau = 8")
    kernel_radius_m: float = 0.5
    # tau scales with the mean camera pixel count over this, so p(o) does not depend on the render
    # size (None: use tau as given)
    reference_pixels: int | None = 480 * 302
    # spread each pixel's weight along the surface to its neighbours in sub-points this far apart
    # (0: count each pixel at its own point only); see visibility.spread_points
    spread_step_m: float = 0.25
    min_vehicle_pixels: int = 20  # k: pixels of a vehicle in one camera to make its footprint visible
    class_map: dict = field(default_factory=lambda: dict(DEFAULT_CLASS_MAP))
    class_names: list = field(default_factory=lambda: list(TRAIN_CLASSES))
    ground_classes: tuple = GROUND_CLASSES
    vehicle_classes: tuple = VEHICLE_CLASSES
    ego_box: tuple | None = None  # (x_min, x_max, y_min, y_max); None: from meta.json or the default

    @classmethod
    def from_dict(cls, d: dict | None, source: str = "labels") -> "FusionConfig":
        d = dict(d or {})
        names = {f.name for f in fields(cls)}
        for k in d:
            if k not in names:
                raise DatasetError(f"{source}: unknown field '{k}' (fields: {', '.join(sorted(names))})")
        cfg = cls(**d)
        for k in ("tau", "kernel_radius_m"):
            v = getattr(cfg, k)
            if not isinstance(v, (int, float)) or v <= 0:
                raise DatasetError(f"{source}: field '{k}' must be a positive number, got {v!r}")
        if not isinstance(cfg.spread_step_m, (int, float)) or cfg.spread_step_m < 0:
            raise DatasetError(f"{source}: field 'spread_step_m' must be a number >= 0, got {cfg.spread_step_m!r}")
        if cfg.reference_pixels is not None and not (isinstance(cfg.reference_pixels, (int, float)) and cfg.reference_pixels > 0):
            raise DatasetError(f"{source}: field 'reference_pixels' must be a positive number or null")
        if cfg.ego_box is not None:
            box = cfg.ego_box
            if not (isinstance(box, (list, tuple)) and len(box) == 4 and all(isinstance(v, (int, float)) for v in box)
                    and box[0] < box[1] and box[2] < box[3]):
                raise DatasetError(f"{source}: field 'ego_box' must be [x_min, x_max, y_min, y_max] with min < max")
        if not (isinstance(cfg.class_names, list) and cfg.class_names and all(isinstance(n, str) for n in cfg.class_names)):
            raise DatasetError(f"{source}: field 'class_names' must be a non-empty list of names")
        if not isinstance(cfg.min_vehicle_pixels, int) or cfg.min_vehicle_pixels < 1:
            raise DatasetError(f"{source}: field 'min_vehicle_pixels' must be a positive integer")
        for k in ("ground_classes", "vehicle_classes"):
            for n in getattr(cfg, k):
                if n not in CLASS_IDS:
                    raise DatasetError(f"{source}: field '{k}': unknown fine class '{n}'")
        try:
            class_lut(cfg.class_map, cfg.class_names)
        except ValueError as exc:
            raise DatasetError(f"{source}: field 'class_map': {exc}") from None
        return cfg

    @classmethod
    def load(cls, path) -> "FusionConfig":
        from .recipe import read_yaml

        d = read_yaml(path, DatasetError) or {}
        return cls.from_dict(d.get("labels", {}) if isinstance(d, dict) else {}, f"{path}: labels")

    def lut(self) -> np.ndarray:
        return class_lut(self.class_map, self.class_names)

    def fine_ids(self, names) -> np.ndarray:
        return np.array([CLASS_IDS[n] for n in names], np.int64)

    def group_lut(self) -> np.ndarray:
        """Fine class id -> 1 ground, 2 vehicle, 0 other (int8)."""
        lut = np.zeros(NUM_FINE_CLASSES, np.int8)
        lut[self.fine_ids(self.ground_classes)] = 1
        lut[self.fine_ids(self.vehicle_classes)] = 2
        return lut


# ---------------------------------------------------------------- reading the passes


def _find(channels: dict, path, *names, required=True):
    """The channel whose name (or its last dotted part, or its layer with one channel) is one of
    `names`, case-insensitively."""
    low = {k.lower(): k for k in channels}
    for n in names:
        n = n.lower()
        if n in low:
            return channels[low[n]]
        hits = [k for lk, k in low.items() if lk.rsplit(".", 1)[-1] == n or lk.split(".", 1)[0] == n]
        if len(hits) == 1:
            return channels[hits[0]]
    if required:
        raise DatasetError(f"{path}: no channel '{names[0]}' (has: {', '.join(sorted(channels))})")
    return None


@contextmanager
def _quiet_c_output():
    """Silence what the OpenEXR C++ library prints on a damaged file (its error comes back as an
    exception, which we report as one line)."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, 1)
        os.dup2(null, 2)
        yield
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, null):
            os.close(fd)


def _read_exr(path) -> dict:
    from .exr import read_exr

    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: missing")
    try:
        with _quiet_c_output():
            return read_exr(path)
    except Exception as exc:  # OpenEXR raises plain Exceptions on damaged files
        raise DatasetError(f"{path}: not a readable EXR (truncated or corrupt: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__})") from None


def _labels_int(a, path, what) -> np.ndarray:
    a = np.asarray(a)
    if a.dtype.kind == "f":
        if not np.all(np.isfinite(a)):
            raise DatasetError(f"{path}: channel '{what}' has NaN or inf")
        a = np.rint(a)
    return a.astype(np.int64)


def read_camera_passes(path) -> dict:
    """distance (H, W) float32, semantic and instance (H, W) int64 from a cam_<name>.exr."""
    ch = _read_exr(path)
    dist = _find(ch, path, "distance", "depth")
    return {
        "distance": np.asarray(dist, np.float32),
        "semantic": _labels_int(_find(ch, path, "semantic", "indexma"), path, "semantic"),
        "instance": _labels_int(_find(ch, path, "instance", "indexob"), path, "instance"),
    }


HIDDEN_LAYERS = ("hidden", "ground", "occluders_hidden", "no_occluders", "noocc")
HIDDEN_FILES = ("topdown_hidden.exr", "topdown_ground.exr", "topdown_occluders_hidden.exr", "topdown_noocc.exr")


def read_topdown(frame_dir) -> dict:
    """Top-down passes: semantic/instance with overhead occluders hidden ('semantic', 'instance')
    and as first seen from above ('semantic_all', 'instance_all'), (rows, cols) int64."""
    frame_dir = Path(frame_dir)
    path = frame_dir / "topdown.exr"
    ch = _read_exr(path)
    hidden = None
    for layer in HIDDEN_LAYERS:  # layers in topdown.exr, e.g. "hidden.semantic"
        sub = {k.split(".", 1)[1]: v for k, v in ch.items() if k.lower().startswith(layer + ".")}
        if sub:
            hidden, hpath = sub, path
            ch = {k: v for k, v in ch.items() if not k.lower().startswith(layer + ".")}
            break
    out = {
        "semantic_all": _labels_int(_find(ch, path, "semantic", "indexma"), path, "semantic"),
        "instance_all": _labels_int(_find(ch, path, "instance", "indexob"), path, "instance"),
    }
    h = _find(ch, path, "height", required=False)
    if h is not None:
        out["height_all"] = np.asarray(h, np.float32)
    if hidden is None:
        for name in HIDDEN_FILES:
            if (frame_dir / name).is_file():
                hpath = frame_dir / name
                hidden = _read_exr(hpath)
                break
    if hidden is None:
        raise DatasetError(f"{frame_dir}: no occluders-hidden top-down pass ({HIDDEN_FILES[0]}, or a 'hidden.' layer in topdown.exr)")
    out["semantic"] = _labels_int(_find(hidden, hpath, "semantic", "indexma"), hpath, "semantic")
    out["instance"] = _labels_int(_find(hidden, hpath, "instance", "indexob"), hpath, "instance")
    h = _find(hidden, hpath, "height", required=False)
    if h is not None:
        out["height"] = np.asarray(h, np.float32)
    return out


_RIGS: dict = {}


def rig_cached(d: dict, source: str):
    """rig_from_dict, cached by the calibration (building a camera checks its model, ~0.2 s)."""
    from geometry.rig import rig_from_dict

    key = json.dumps(d, sort_keys=True)
    if key not in _RIGS:
        if len(_RIGS) > 32:
            _RIGS.clear()
        _RIGS[key] = rig_from_dict(d, source)
    return _RIGS[key]


def frame_rig(meta: dict, frame_dir, fallback=None):
    """The rig a frame was rendered with: meta.json's calibration, else `fallback`."""
    from geometry.rig import RigError

    from .index import meta_rig

    d = meta_rig(meta)
    if d is None:
        if fallback is None:
            raise DatasetError(f"{Path(frame_dir) / 'meta.json'}: missing field 'rig' (the rig calibration)")
        return fallback
    try:
        return rig_cached(d, f"{Path(frame_dir) / 'meta.json'}: rig")
    except RigError as exc:
        raise DatasetError(str(exc)) from None


def ego_box(meta: dict, cfg: FusionConfig):
    """(x_min, x_max, y_min, y_max) of the ego body: config, else meta.json ego box, else default."""
    if cfg.ego_box is not None:
        return tuple(float(v) for v in cfg.ego_box)
    ego = meta.get("ego") if isinstance(meta.get("ego"), dict) else {}
    for key in ("footprint", "box"):
        b = ego.get(key)
        if isinstance(b, dict) and {"x_min", "x_max", "y_min", "y_max"} <= set(b):
            return tuple(float(b[k]) for k in ("x_min", "x_max", "y_min", "y_max"))
        if isinstance(b, (list, tuple)) and len(b) == 4:
            return tuple(float(v) for v in b)
    return DEFAULT_EGO_BOX


def ego_mask(grid, box) -> np.ndarray:
    c = grid.cell_centres()
    x0, x1, y0, y1 = box
    return (c[..., 0] >= x0) & (c[..., 0] <= x1) & (c[..., 1] >= y0) & (c[..., 1] <= y1)


# ---------------------------------------------------------------- fusion (pure)


def effective_tau(cfg: FusionConfig, shapes) -> float:
    """tau scaled by the cameras' mean pixel count (shapes: their (H, W)) over the reference: the
    points per cell grow with the image size, p(o) should not."""
    if not cfg.reference_pixels:
        return float(cfg.tau)
    mean_px = float(np.mean([h * w for h, w in shapes]))
    return float(cfg.tau) * mean_px / float(cfg.reference_pixels)


def camera_counts(table: V.RayTable, passes: dict, grid, cfg: FusionConfig):
    """(rows, cols) pixel-occurrence counts of one camera's ground and vehicle hits, and the
    vehicle instances it sees with at least cfg.min_vehicle_pixels pixels."""
    lut = cfg.group_lut()
    group = V.hits(table, passes["distance"], lut[np.clip(passes["semantic"], 0, len(lut) - 1)])
    seen = V.seen_instances(passes["instance"], group == 2, cfg.min_vehicle_pixels)
    xy = V.lift_xy(table, passes["distance"])
    if cfg.spread_step_m:
        return V.spread_counts(grid, xy, passes["distance"], group, cfg.spread_step_m), seen
    return V.count_points(grid, xy[group > 0]), seen


def fuse_passes(rig, cameras: dict, topdown: dict, grid, cfg: FusionConfig, box=DEFAULT_EGO_BOX) -> dict:
    """Labels from passes already in memory.

    cameras: {name: {distance, semantic, instance}} (H, W) for the rig's cameras;
    topdown: {semantic, instance} with occluders hidden, (rows, cols) of `grid`.
    Returns semantic (uint8), instance (uint16), visibility (float32), counts {camera: (rows, cols)}.
    """
    if topdown["semantic"].shape != grid.shape:
        raise ValueError(f"top-down pass is {topdown['semantic'].shape}, the label grid is {grid.shape}")
    tables = V.ray_tables(rig)
    vehicle_ids = cfg.fine_ids(cfg.vehicle_classes)
    lut = cfg.lut()
    fine = np.clip(topdown["semantic"], 0, len(lut) - 1)
    semantic = lut[fine]
    counts, seen = {}, []
    for name, table in tables.items():
        if name not in cameras:
            raise ValueError(f"no passes for rig camera '{name}'")
        counts[name], ids = camera_counts(table, cameras[name], grid, cfg)
        seen.append(ids)
    total = sum(counts.values())
    vis = V.visibility_from_counts(total, grid.res, cfg.kernel_radius_m, effective_tau(cfg, [t.shape for t in tables.values()]))
    is_vehicle = np.isin(fine, vehicle_ids)
    seen_ids = np.unique(np.concatenate(seen)) if seen else np.zeros(0, np.int64)
    vis[V.footprint_mask(topdown["instance"], seen_ids) & is_vehicle] = 1.0
    ego = ego_mask(grid, box)
    semantic[ego] = 0
    vis[ego] = 0.0
    instance = np.where(is_vehicle & ~ego, topdown["instance"], 0)
    if instance.max(initial=0) > 65535:
        raise ValueError(f"instance id {instance.max()} does not fit the 16-bit instance PNG")
    return {"semantic": semantic.astype(np.uint8), "instance": instance.astype(np.uint16), "visibility": vis, "counts": counts}


# ---------------------------------------------------------------- one frame on disk


def load_frame_passes(frame_dir, rig_fallback=None):
    """(meta, rig, cameras {name: passes}, topdown) of a rendered frame; the rig's cameras are
    resized to the rendered image size when they differ."""
    frame_dir = Path(frame_dir)
    meta_path = frame_dir / "meta.json"
    meta = _read_json(meta_path) if meta_path.is_file() else {}
    rig = frame_rig(meta, frame_dir, rig_fallback)
    cameras = {rc.name: read_camera_passes(frame_dir / f"cam_{rc.name}.exr") for rc in rig}
    sizes = {n: p["distance"].shape for n, p in cameras.items()}
    if any(sizes[rc.name] != (rc.camera.height, rc.camera.width) for rc in rig):
        from geometry.rig import Rig, RigCamera

        rig = Rig([RigCamera(rc.name, rc.camera.resized(sizes[rc.name][1], sizes[rc.name][0]), rc.cam_to_ego) for rc in rig], rig.name)
    return meta, rig, cameras, read_topdown(frame_dir)


def frame_grid(meta: dict, frame_dir):
    """The label grid of a frame: meta.json's top-down grid, else the default 400 x 400 one."""
    from geometry.bev import BevGrid

    from .index import meta_grid

    g = meta_grid(meta)
    if g is None:
        return BevGrid()
    try:
        return BevGrid.from_dict(g)
    except (TypeError, ValueError) as exc:
        raise DatasetError(f"{Path(frame_dir) / 'meta.json'}: topdown.grid: {exc}") from None


def fuse_frame(frame_dir, cfg: FusionConfig | None = None, rig_fallback=None) -> dict:
    """Labels of one rendered frame (see fuse_passes), on the frame's top-down grid."""
    cfg = cfg or FusionConfig()
    meta, rig, cameras, topdown = load_frame_passes(frame_dir, rig_fallback)
    grid = frame_grid(meta, frame_dir)
    if topdown["semantic"].shape != grid.shape:
        raise DatasetError(f"{Path(frame_dir) / 'topdown.exr'}: {topdown['semantic'].shape} pixels, the label grid is {grid.shape}")
    return fuse_passes(rig, cameras, topdown, grid, cfg, ego_box(meta, cfg))


def encode_png(a: np.ndarray) -> bytes:
    import cv2

    ok, buf = cv2.imencode(".png", np.ascontiguousarray(a))
    if not ok:
        raise OSError("PNG encoding failed")
    return buf.tobytes()


def write_labels(frame_dir, labels: dict) -> None:
    """labels/semantic.png (uint8), instance.png (uint16), visibility.png (uint16, p * 65535);
    each atomically, visibility last (its presence marks the frame done)."""
    from .exr import write_bytes_atomic

    d = Path(frame_dir) / LABEL_DIR
    d.mkdir(exist_ok=True)
    vis16 = np.rint(np.clip(labels["visibility"], 0, 1) * VISIBILITY_SCALE).astype(np.uint16)
    write_bytes_atomic(d / SEMANTIC_PNG, encode_png(labels["semantic"]))
    write_bytes_atomic(d / INSTANCE_PNG, encode_png(labels["instance"]))
    write_bytes_atomic(d / VISIBILITY_PNG, encode_png(vis16))


def labels_done(frame_dir) -> bool:
    d = Path(frame_dir) / LABEL_DIR
    return all((d / n).is_file() for n in (SEMANTIC_PNG, INSTANCE_PNG, VISIBILITY_PNG))


# ---------------------------------------------------------------- the command

_WORKER_CFG: FusionConfig | None = None


def _init_worker(cfg_dict):
    global _WORKER_CFG
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    _WORKER_CFG = FusionConfig(**cfg_dict)


def _fuse_one(frame_dir: str):
    try:
        write_labels(frame_dir, fuse_frame(frame_dir, _WORKER_CFG))
        return frame_dir, None
    except (DatasetError, ValueError, OSError) as exc:
        return frame_dir, str(exc)


def fuse_dataset(root, cfg: FusionConfig, workers: int = 1, force: bool = False, progress: bool = True) -> list[str]:
    """Fuse every manifest frame that has no labels yet; returns the problems (one line each)."""
    from tqdm import tqdm

    from .index import build_index, read_manifest, write_index

    root = Path(root)
    todo = [str(root / e["dir"]) for e in read_manifest(root)]
    if not force:
        todo = [d for d in todo if not labels_done(d)]
    problems = []
    bar = tqdm(total=len(todo), desc="fuse", unit="frame", disable=not progress)
    cfg_dict = {f.name: getattr(cfg, f.name) for f in fields(cfg)}
    if workers <= 1:
        _init_worker(cfg_dict)
        results = map(_fuse_one, todo)
        pool = None
    else:
        import multiprocessing as mp

        pool = mp.get_context("spawn").Pool(workers, _init_worker, (cfg_dict,))
        results = pool.imap_unordered(_fuse_one, todo)
    try:
        for frame_dir, err in results:
            if err:
                problems.append(err)
            bar.update(1)
    finally:
        bar.close()
        if pool is not None:
            pool.terminate()
    write_index(root, build_index(root, cfg.class_names))
    return problems


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="Fuse rendered frames into BEV labels (semantic, instance, visibility).")
    ap.add_argument("dataset")
    ap.add_argument("--workers", type=int, default=1, help="processes (default 1)")
    ap.add_argument("--config", help="dataset config YAML whose 'labels:' section sets the fusion")
    ap.add_argument("--force", action="store_true", help="redo frames that already have labels")
    args = ap.parse_args(argv)
    try:
        cfg = FusionConfig.load(args.config) if args.config else FusionConfig()
        problems = fuse_dataset(args.dataset, cfg, args.workers, args.force)
    except DatasetError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted: finished frames are kept; run again to resume", file=sys.stderr)
        return 130
    for p in problems:
        print(f"error: {p}", file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
