"""Fuse one rendered frame's passes into occlusion-corrected BEV labels (the library behind
`python -m dataset_tools fuse`).

Per frame, from the renders of dataset_tools.generate:
  semantic    top-down fine classes with overhead occluders hidden, mapped to the training classes;
              the ego's own footprint is invalid (0)
  instance    top-down instance id on vehicle cells, 0 elsewhere (uint16)
  visibility  p(o) from the fisheye distance passes (dataset_tools.labels.visibility), 16-bit PNG
"""

from __future__ import annotations

import copy
from dataclasses import asdict, dataclass, field, make_dataclass

import numpy as np

from common.errors import ConfigError
from common.schema import List, Mapping, Name, Num, Section, Str

from ..format.layout import DatasetError, FrameFiles
from ..format.meta import FrameMeta
from ..format.passes import read_frame_passes
from .classes import CLASS_IDS, DEFAULT_CLASS_MAP, NUM_FINE_CLASSES, TRAIN_CLASSES, class_lut
from .visibility import (RayTable, SurfaceRule, count_points, footprint_mask, hits, lift_points, ray_tables, seen_instances,
                         spread_counts, visibility_from_counts)

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
    # (0: count each pixel at its own point only); see spread_counts
    "spread_step_m": Num(0.0, 10.0, default=0.25),
    # when two neighbouring pixels are on one seen surface (SurfaceRule)
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


# FusionConfig's fields and defaults are FUSION_SCHEMA's (stated once, there)
_FusionFields = make_dataclass("_FusionFields", [
    (name, object, field(default_factory=lambda f=f: copy.deepcopy(f.default))) for name, f in FUSION_SCHEMA.fields.items()
])


@dataclass
class FusionConfig(_FusionFields):
    """Label fusion settings: a field per FUSION_SCHEMA entry (the `labels:` section of a dataset
    config), with its default. `from_dict` validates (a dataset config's file is read by
    generation.dataset_config: `load_config(p)["labels"]`, `load_labels(p)`); the constructor takes values as given."""

    def __post_init__(self):
        self.ground_classes, self.vehicle_classes = tuple(self.ground_classes), tuple(self.vehicle_classes)

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
        return cls(**cfg)

    def to_dict(self) -> dict:
        return asdict(self)

    def lut(self) -> np.ndarray:
        return class_lut(self.class_map, self.class_names)

    def fine_ids(self, names) -> np.ndarray:
        return np.array([CLASS_IDS[n] for n in names], np.int64)

    def surface_rule(self) -> SurfaceRule:
        return SurfaceRule(self.spread_z_tol_m, self.spread_max_grade, self.spread_min_grazing_deg)

    def group_lut(self) -> np.ndarray:
        """Fine class id -> 1 ground, 2 vehicle, 0 other (int8)."""
        lut = np.zeros(NUM_FINE_CLASSES, np.int8)
        lut[self.fine_ids(self.ground_classes)] = 1
        lut[self.fine_ids(self.vehicle_classes)] = 2
        return lut


# ---------------------------------------------------------------- the ego body


def ego_box(meta: FrameMeta, cfg: FusionConfig):
    """(x_min, x_max, y_min, y_max) of the ego body: the config's, else the rendered body's
    (meta.json `ego.box`), else the default."""
    if cfg.ego_box is not None:
        return tuple(float(v) for v in cfg.ego_box)
    return meta.ego_box or DEFAULT_EGO_BOX


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


def camera_counts(table: RayTable, passes: dict, grid, cfg: FusionConfig, min_pixels: int | None = None):
    """(rows, cols) pixel-occurrence counts of one camera's ground and vehicle hits, and the
    vehicle instances it sees with at least min_pixels (default: cfg.min_vehicle_pixels) pixels."""
    lut = cfg.group_lut()
    sem = np.clip(passes["semantic"], 0, len(lut) - 1)
    group = hits(table, passes["distance"], lut[sem])
    k = cfg.min_vehicle_pixels if min_pixels is None else min_pixels
    seen = seen_instances(passes["instance"], group == 2, k)
    points = lift_points(table, passes["distance"])
    if cfg.spread_step_m:
        paint = np.isin(sem, cfg.fine_ids([c for c in PAINT_CLASSES if c in cfg.ground_classes]))
        return spread_counts(grid, points, passes["distance"], group, passes["instance"], table.rays,
                               cfg.spread_step_m, paint, cfg.surface_rule()), seen
    return count_points(grid, points[..., :2][group > 0]), seen


def fuse_passes(rig, cameras: dict, topdown: dict, grid, cfg: FusionConfig, box=DEFAULT_EGO_BOX) -> dict:
    """Labels from passes already in memory.

    cameras: {name: {distance, semantic, instance}} (H, W) for the rig's cameras;
    topdown: {semantic, instance} with occluders hidden, (rows, cols) of `grid`.
    Returns semantic (uint8), instance (uint16), visibility (float32), counts {camera: (rows, cols)}.
    """
    if topdown["semantic"].shape != grid.shape:
        raise ValueError(f"top-down pass is {topdown['semantic'].shape}, the label grid is {grid.shape}")
    tables = ray_tables(rig)
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
    vis = visibility_from_counts(total, grid.res, cfg.kernel_radius_m, effective_tau(cfg, shapes))
    is_vehicle = np.isin(fine, vehicle_ids)
    seen_ids = np.unique(np.concatenate(seen)) if seen else np.zeros(0, np.int64)
    vis[footprint_mask(topdown["instance"], seen_ids) & is_vehicle] = 1.0
    ego = ego_mask(grid, box)
    semantic[ego] = 0
    vis[ego] = 0.0
    instance = np.where(is_vehicle & ~ego, topdown["instance"], 0)
    if instance.max(initial=0) > 65535:
        raise ValueError(f"instance id {instance.max()} does not fit the 16-bit instance PNG")
    return {"semantic": semantic.astype(np.uint8), "instance": instance.astype(np.uint16), "visibility": vis, "counts": counts}


# ---------------------------------------------------------------- one frame on disk


def fuse_frame(frame_dir, cfg: FusionConfig | None = None) -> dict:
    """Labels of one rendered frame (see fuse_passes), on the frame's top-down grid."""
    cfg = cfg or FusionConfig()
    meta, rig, cameras, topdown = read_frame_passes(frame_dir)
    grid = meta.grid()
    if topdown["semantic"].shape != grid.shape:
        raise DatasetError(f"{FrameFiles(frame_dir).topdown}: {topdown['semantic'].shape} pixels, the label grid is {grid.shape}")
    return fuse_passes(rig, cameras, topdown, grid, cfg, ego_box(meta, cfg))
