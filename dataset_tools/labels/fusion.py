"""Fuse one rendered frame's passes into occlusion-corrected BEV labels (the library behind
`python -m dataset_tools.fuse`).

Per frame, from the renders of dataset_tools.generate:
  semantic    top-down fine classes with overhead occluders hidden, mapped to the training classes;
              the ego's own footprint is invalid (0)
  instance    top-down instance id on vehicle cells, 0 elsewhere (uint16)
  visibility  p(o) from the fisheye distance passes (dataset_tools.labels.visibility), 16-bit PNG
"""

from __future__ import annotations

import os
import sys
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from common.errors import ConfigError
from common.files import read_yaml, write_bytes_atomic
from common.schema import List, Mapping, Name, Num, Section, Str

from ..format.exr import encode_png, read_exr
from ..format.layout import VISIBILITY_SCALE, DatasetError, FrameFiles
from ..format.reader import read_meta
from . import visibility as V
from .classes import CLASS_IDS, DEFAULT_CLASS_MAP, NUM_FINE_CLASSES, TRAIN_CLASSES, class_lut

GROUND_CLASSES = ("road", "lane_marking", "crosswalk", "stop_line", "sidewalk", "curb", "parking", "terrain")
VEHICLE_CLASSES = ("vehicle",)
# Ego body in the ego frame (x forward from the rear axle, y left), metres, when meta.json has none:
# a 4.9 m x 2.0 m car around the default rig's mounts (front camera at x 3.75, rear at -1.05).
DEFAULT_EGO_BOX = (-1.10, 3.85, -1.00, 1.00)


_FINE = Str(choices=tuple(CLASS_IDS))
# the `labels:` section of a dataset config
FUSION_SCHEMA = Section({
    # points within the kernel for p(o) = 1, at the reference resolution (docs/labels.md, "tau")
    "tau": Num(above=0, default=8.0),
    "kernel_radius_m": Num(above=0, hi=10.0, default=0.5),
    # tau scales with the mean camera pixel count over this, so p(o) does not depend on the render
    # size (null: use tau as given)
    "reference_pixels": Num(above=0, integer=True, default=480 * 302, nullable=True),
    # spread each pixel's weight along the surface to its neighbours in sub-points this far apart
    # (0: count each pixel at its own point only); see visibility.spread_counts
    "spread_step_m": Num(0.0, 10.0, default=0.25),
    # when two neighbouring pixels are on one seen surface (visibility.SurfaceRule)
    "spread_z_tol_m": Num(0.0, 1.0, default=0.05),
    "spread_max_grade": Num(0.0, 1.0, default=0.02),
    "spread_min_grazing_deg": Num(above=0, hi=90.0, default=15.0),
    # k: pixels of a vehicle in one camera at the reference resolution (scaled like tau)
    "min_vehicle_pixels": Num(1, 10**6, integer=True, default=20),
    "class_map": Mapping(_FINE, Name(), default=dict(DEFAULT_CLASS_MAP)),
    "class_names": List(Name(), max_length=255, default=list(TRAIN_CLASSES)),
    "ground_classes": List(_FINE, default=list(GROUND_CLASSES)),
    "vehicle_classes": List(_FINE, default=list(VEHICLE_CLASSES)),
    # (x_min, x_max, y_min, y_max) of the ego body in the ego frame; null: the default box
    "ego_box": List(Num(-50.0, 50.0), length=4, default=None, nullable=True),
})


@dataclass
class FusionConfig:
    """Label fusion settings (FUSION_SCHEMA; the `labels:` section of a dataset config)."""

    tau: float = 8.0
    kernel_radius_m: float = 0.5
    reference_pixels: int | None = 480 * 302
    spread_step_m: float = 0.25
    spread_z_tol_m: float = 0.05
    spread_max_grade: float = 0.02
    spread_min_grazing_deg: float = 15.0
    min_vehicle_pixels: int = 20
    class_map: dict = field(default_factory=lambda: dict(DEFAULT_CLASS_MAP))
    class_names: list = field(default_factory=lambda: list(TRAIN_CLASSES))
    ground_classes: tuple = GROUND_CLASSES
    vehicle_classes: tuple = VEHICLE_CLASSES
    ego_box: tuple | None = None

    @classmethod
    def from_dict(cls, d: dict | None, source: str = "labels") -> "FusionConfig":
        cfg = FUSION_SCHEMA.validate(d or {}, source)
        box = cfg["ego_box"]
        if box is not None and not (box[0] < box[1] and box[2] < box[3]):
            raise ConfigError(f"{source}: ego_box: must be [x_min, x_max, y_min, y_max] with min < max, got {box}")
        try:
            class_lut(cfg["class_map"], cfg["class_names"])
        except ValueError as exc:
            raise ConfigError(f"{source}: class_map: {exc}") from None
        cfg["ground_classes"], cfg["vehicle_classes"] = tuple(cfg["ground_classes"]), tuple(cfg["vehicle_classes"])
        return cls(**cfg)

    @classmethod
    def load(cls, path) -> "FusionConfig":
        d = read_yaml(path) or {}
        return cls.from_dict(d.get("labels", {}) if isinstance(d, dict) else {}, f"{path}: labels")

    def to_dict(self) -> dict:
        return asdict(self)

    def lut(self) -> np.ndarray:
        return class_lut(self.class_map, self.class_names)

    def fine_ids(self, names) -> np.ndarray:
        return np.array([CLASS_IDS[n] for n in names], np.int64)

    def surface_rule(self) -> V.SurfaceRule:
        return V.SurfaceRule(self.spread_z_tol_m, self.spread_max_grade, self.spread_min_grazing_deg)

    def group_lut(self) -> np.ndarray:
        """Fine class id -> 1 ground, 2 vehicle, 0 other (int8)."""
        lut = np.zeros(NUM_FINE_CLASSES, np.int8)
        lut[self.fine_ids(self.ground_classes)] = 1
        lut[self.fine_ids(self.vehicle_classes)] = 2
        return lut


# ---------------------------------------------------------------- reading the passes


def find_channel(channels: dict, path, *names, required=True):
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


def read_exr_checked(path) -> dict:
    """Every channel of an EXR; a missing or damaged file is one DatasetError line."""
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
    ch = read_exr_checked(path)
    dist = find_channel(ch, path, "distance")
    if np.isnan(dist).any():
        raise DatasetError(f"{path}: channel 'distance' has NaN")
    return {
        "distance": np.asarray(dist, np.float32),
        "semantic": _labels_int(find_channel(ch, path, "semantic"), path, "semantic"),
        "instance": _labels_int(find_channel(ch, path, "instance"), path, "instance"),
    }


def read_topdown(frame_dir) -> dict:
    """Top-down passes: semantic/instance with overhead occluders hidden ('semantic', 'instance',
    from the 'ground.' layer) and as first seen from above ('semantic_all', 'instance_all', from
    'all.'), (rows, cols) int64; 'height' / 'height_all' float32 where present."""
    path = FrameFiles(frame_dir).topdown
    ch = read_exr_checked(path)
    out = {}
    for layer, suffix in (("all", "_all"), ("ground", "")):
        sub = {k.split(".", 1)[1]: v for k, v in ch.items() if k.lower().startswith(layer + ".")}
        if not sub:
            raise DatasetError(f"{path}: no '{layer}.' layer (has: {', '.join(sorted(ch))})")
        out["semantic" + suffix] = _labels_int(find_channel(sub, path, "semantic"), path, f"{layer}.semantic")
        out["instance" + suffix] = _labels_int(find_channel(sub, path, "instance"), path, f"{layer}.instance")
        h = find_channel(sub, path, "height", required=False)
        if h is not None:
            out["height" + suffix] = np.asarray(h, np.float32)
    return out


@lru_cache(maxsize=32)
def _rig_from_json(text: str, source: str):
    import json

    from geometry.rig import rig_from_dict

    return rig_from_dict(json.loads(text), source)


def rig_cached(d: dict, source: str):
    """rig_from_dict, cached by the calibration (building a camera checks its model, ~0.2 s)."""
    import json

    return _rig_from_json(json.dumps(d, sort_keys=True), source)


def frame_rig(meta: dict, frame_dir, fallback=None):
    """The rig a frame was rendered with: meta.json's calibration, else `fallback`."""
    from geometry.rig import RigError

    from ..format.index import meta_rig

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
    """(x_min, x_max, y_min, y_max) of the ego body: the config's, else the rendered body's
    (meta.json `ego.box`), else the default."""
    if cfg.ego_box is not None:
        return tuple(float(v) for v in cfg.ego_box)
    box = (meta.get("ego") or {}).get("box")
    return tuple(float(v) for v in box) if box is not None else DEFAULT_EGO_BOX


def ego_mask(grid, box) -> np.ndarray:
    c = grid.cell_centres()
    x0, x1, y0, y1 = box
    return (c[..., 0] >= x0) & (c[..., 0] <= x1) & (c[..., 1] >= y0) & (c[..., 1] <= y1)


# ---------------------------------------------------------------- fusion (pure)


def pixel_scale(cfg: FusionConfig, shapes) -> float:
    """The cameras' mean pixel count (shapes: their (H, W)) over cfg.reference_pixels (1 when None)."""
    if not cfg.reference_pixels:
        return 1.0
    return float(np.mean([h * w for h, w in shapes])) / float(cfg.reference_pixels)


def effective_tau(cfg: FusionConfig, shapes) -> float:
    """tau scaled by the cameras' mean pixel count over the reference: the points per cell grow
    with the image size, p(o) should not."""
    return float(cfg.tau) * pixel_scale(cfg, shapes)


def effective_min_pixels(cfg: FusionConfig, shapes) -> int:
    """k scaled like tau: the pixels a vehicle covers grow with the image size (at least 1)."""
    return max(1, int(round(cfg.min_vehicle_pixels * pixel_scale(cfg, shapes))))


PAINT_CLASSES = ("lane_marking", "crosswalk", "stop_line")


def camera_counts(table: V.RayTable, passes: dict, grid, cfg: FusionConfig, min_pixels: int | None = None):
    """(rows, cols) pixel-occurrence counts of one camera's ground and vehicle hits, and the
    vehicle instances it sees with at least min_pixels (default: cfg.min_vehicle_pixels) pixels."""
    lut = cfg.group_lut()
    sem = np.clip(passes["semantic"], 0, len(lut) - 1)
    group = V.hits(table, passes["distance"], lut[sem])
    k = cfg.min_vehicle_pixels if min_pixels is None else min_pixels
    seen = V.seen_instances(passes["instance"], group == 2, k)
    points = V.lift_points(table, passes["distance"])
    if cfg.spread_step_m:
        paint = np.isin(sem, cfg.fine_ids([c for c in PAINT_CLASSES if c in cfg.ground_classes]))
        return V.spread_counts(grid, points, passes["distance"], group, passes["instance"], table.rays,
                               cfg.spread_step_m, paint, cfg.surface_rule()), seen
    return V.count_points(grid, points[..., :2][group > 0]), seen


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
    shapes = [t.shape for t in tables.values()]
    k = effective_min_pixels(cfg, shapes)
    for name, table in tables.items():
        if name not in cameras:
            raise ValueError(f"no passes for rig camera '{name}'")
        counts[name], ids = camera_counts(table, cameras[name], grid, cfg, k)
        seen.append(ids)
    total = sum(counts.values())
    vis = V.visibility_from_counts(total, grid.res, cfg.kernel_radius_m, effective_tau(cfg, shapes))
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
    files = FrameFiles(frame_dir)
    meta = read_meta(files.dir)
    rig = frame_rig(meta, files.dir, rig_fallback)
    cameras = {rc.name: read_camera_passes(files.camera_exr(rc.name)) for rc in rig}
    sizes = {n: p["distance"].shape for n, p in cameras.items()}
    if any(sizes[rc.name] != (rc.camera.height, rc.camera.width) for rc in rig):
        from geometry.rig import Rig, RigCamera

        rig = Rig([RigCamera(rc.name, rc.camera.resized(sizes[rc.name][1], sizes[rc.name][0]), rc.cam_to_ego) for rc in rig], rig.name)
    return meta, rig, cameras, read_topdown(files.dir)


def frame_grid(meta: dict, frame_dir):
    """The label grid of a frame: meta.json's top-down grid, else the default 400 x 400 one."""
    from geometry.bev import BevGrid

    from ..format.index import meta_grid

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
        raise DatasetError(f"{FrameFiles(frame_dir).topdown}: {topdown['semantic'].shape} pixels, the label grid is {grid.shape}")
    return fuse_passes(rig, cameras, topdown, grid, cfg, ego_box(meta, cfg))


def write_labels(frame_dir, labels: dict) -> None:
    """labels/semantic.png (uint8), instance.png (uint16), visibility.png (uint16, p * 65535);
    each atomically, visibility last (its presence marks the frame done)."""
    files = FrameFiles(frame_dir)
    files.labels.mkdir(exist_ok=True)
    vis16 = np.rint(np.clip(labels["visibility"], 0, 1) * VISIBILITY_SCALE).astype(np.uint16)
    write_bytes_atomic(files.semantic, encode_png(labels["semantic"]))
    write_bytes_atomic(files.instance, encode_png(labels["instance"]))
    write_bytes_atomic(files.visibility, encode_png(vis16))
