"""Cylindrical rectification of fisheye images (the paper's LSS baseline).

A rectified camera keeps the fisheye's centre and axes (same extrinsics): azimuth about the
camera's y axis is spread linearly over the width (`hfov_deg`), and height over the cylinder is
spread as tan(elevation) over the height (`vfov_deg`), so vertical lines stay vertical. The image
has the fisheye's pixel count by default. The remap tables are computed once per camera from the
cameras' own `unproject` (cylindrical) and `project` (fisheye): no projection is re-derived here.

Defaults (hfov 180, vfov 90 degrees, the fisheye's size): a half-cylinder in front of each camera,
as wide as a fisheye sensibly rectifies; a 480x302 fisheye gives fx = 152.8, fy = 151 px/rad at
the horizon (nearly square pixels there).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from .cameras import Camera, camera_from_dict
from .rig import Rig, RigCamera

DEFAULT_HFOV_DEG, DEFAULT_VFOV_DEG = 180.0, 90.0


def cylindrical_camera(width: int, height: int, hfov_deg: float = DEFAULT_HFOV_DEG, vfov_deg: float = DEFAULT_VFOV_DEG) -> Camera:
    """The cylindrical camera whose width x height image spans hfov (azimuth) x vfov (elevation)."""
    if not 0 < hfov_deg < 360 or not 0 < vfov_deg < 180:
        raise ValueError(f"cylinder: need 0 < hfov < 360 and 0 < vfov < 180 degrees, got {hfov_deg}, {vfov_deg}")
    fx = width / math.radians(hfov_deg)
    fy = (height / 2) / math.tan(math.radians(vfov_deg) / 2)
    return camera_from_dict({"model": "cylindrical", "width": int(width), "height": int(height),
                             "fx": fx, "fy": fy, "cx": (width - 1) / 2, "cy": (height - 1) / 2})


def cylindrical_rig(rig: Rig, hfov_deg: float = DEFAULT_HFOV_DEG, vfov_deg: float = DEFAULT_VFOV_DEG, size=None) -> Rig:
    """Each fisheye of `rig` replaced by its cylindrical camera (same extrinsics); `size` (W, H)
    defaults to each fisheye's own size."""
    def cyl(c):
        w, h = size if size else (c.width, c.height)
        return cylindrical_camera(w, h, hfov_deg, vfov_deg)

    return rig.map_cameras(cyl)


def remap_tables(source: Camera, target: Camera) -> tuple[np.ndarray, np.ndarray]:
    """float32 (H, W) maps for cv2.remap: the source-image position of every target pixel centre
    (-1 where the target ray has no source pixel)."""
    rays, ok = target.unproject(target.pixel_grid().numpy())
    uv, ok2 = source.project(rays)
    good = ok & ok2 & source.inside(uv)
    uv = np.where(good[..., None], uv, -1.0)
    return uv[..., 0].astype(np.float32), uv[..., 1].astype(np.float32)


class Rectifier:
    """Remaps the images of a fisheye rig to its cylindrical rig; tables built once per camera."""

    def __init__(self, rig: Rig, hfov_deg: float = DEFAULT_HFOV_DEG, vfov_deg: float = DEFAULT_VFOV_DEG, size=None):
        self.source = rig
        self.rig = cylindrical_rig(rig, hfov_deg, vfov_deg, size)
        self.maps = {rc.name: cv2.convertMaps(*remap_tables(rc.camera, self.rig[rc.name].camera), cv2.CV_16SC2)
                     for rc in rig}

    def __call__(self, name: str, image: np.ndarray) -> np.ndarray:
        """The fisheye image of camera `name` (H, W[, C]) -> its cylindrical image (bilinear; 0 outside)."""
        m1, m2 = self.maps[name]
        return cv2.remap(image, m1, m2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def lost_fisheye_pixels(source: RigCamera | Camera, target: Camera) -> float:
    """Share of the fisheye's valid pixels (those with a ray) that the cylindrical image does not cover."""
    cam = source.camera if isinstance(source, RigCamera) else source
    rays, ok = cam.unproject(cam.pixel_grid().numpy())
    uv, ok2 = target.project(rays)
    covered = ok & ok2 & target.inside(uv)
    return float(1.0 - covered.sum() / max(ok.sum(), 1))


def covered_cells(rig: Rig, grid, z: float = 0.0) -> np.ndarray:
    """(rows, cols) bool: BEV cells whose centre at height z projects inside some camera image of `rig`."""
    xy = grid.cell_centres()
    pts = np.concatenate([xy, np.full(xy.shape[:2] + (1,), z)], -1)
    out = np.zeros(xy.shape[:2], bool)
    for rc in rig:
        uv, ok = rc.project_ego(pts)
        out |= ok & rc.camera.inside(uv)
    return out


def lost_visible_cells(rig: Rig, cylinders: Rig, grid, visibility: np.ndarray) -> float:
    """Share of the BEV cells seen (p(o) >= 0.5) whose ground point the fisheye rig covers but the
    cylindrical rig does not."""
    seen = (visibility >= 0.5) & covered_cells(rig, grid)
    return float((seen & ~covered_cells(cylinders, grid)).sum() / max(seen.sum(), 1))
