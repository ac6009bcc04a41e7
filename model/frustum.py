"""The frustum: every feature pixel's ray (from geometry) times ray-distance bins -> BEV cells.

`Frustum` is the one owner of this geometry: the data set asks it for the point cells of augmented
cameras, the model for the nominal ones (computed once and cached with the splat index).

Depth in a fisheye is the distance along the ray (z-depth is meaningless past 90 degrees off axis),
so bin k puts a feature pixel's point at origin + d_k * ray, with the unit ray from `geometry`.

Feature-map pixel convention: a stride-s feature pixel (i, j) covers image pixel centre
(s j + (s - 1) / 2, s i + (s - 1) / 2); that is exactly the pixel grid of `camera.resized(W/s, H/s)`
(geometry's resize keeps pixel centres: u' = (u + 0.5) / s - 0.5), so the lift unprojects the
pixel grid of that camera. The image encoder is built so its feature pixels are centred there
(see `model.encoder`).

Mirrored samples (`augment.mirror`): every image flipped left-right is what a mirrored camera sees
of the world mirrored about the ego's x axis (y -> -y), for any camera: the flipped image's pixel
(u, v) is the original's (W - 1 - u, v), whose point at bin k is p; in the mirrored world it lies at
(p_x, -p_y, p_z). So the mirrored geometry is the original's point cells flipped along the feature
columns with each cell's column mirrored (`mirrored_cells`; exact when the input width is a multiple
of the stride and the grid's y range is symmetric), and the intrinsics descriptor read to the left
of the principal point (`intrinsics_descriptor(camera, mirrored=True)`).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from functools import cached_property

from geometry.bev import BevGrid
from geometry.rig import Rig, RigCamera

from .augment import base_transform, move_pixels, transform_camera, view_matrix


def depth_edges(d_min: float, d_max: float, bins: int, spacing: str = "linear") -> np.ndarray:
    """The bins + 1 bin edges (metres along the ray): `linear` (uniform) or `log` (uniform in log distance)."""
    if not 0 < d_min < d_max or bins < 1:
        raise ValueError(f"depth bins: need 0 < min < max and bins >= 1, got {d_min}, {d_max}, {bins}")
    if spacing == "linear":
        return np.linspace(d_min, d_max, bins + 1)
    if spacing == "log":
        return np.geomspace(d_min, d_max, bins + 1)
    raise ValueError(f"depth bins: spacing must be 'linear' or 'log', got {spacing!r}")


def depth_bins(d_min: float, d_max: float, bins: int, spacing: str = "linear") -> np.ndarray:
    """Bin centres (metres along the ray): the middle of each bin's edges (geometric for `log`)."""
    edges = depth_edges(d_min, d_max, bins, spacing)
    return (edges[:-1] + edges[1:]) / 2 if spacing == "linear" else np.sqrt(edges[:-1] * edges[1:])


def feature_camera(camera, stride: int, image_size: tuple[int, int]):
    """The camera of the stride-s feature map of a (W, H) image padded at right/bottom to a
    multiple of the stride (padding keeps the principal point)."""
    w, h = image_size
    wp, hp = math.ceil(w / stride) * stride, math.ceil(h / stride) * stride
    return camera.cropped(0, 0, wp, hp).resized(wp // stride, hp // stride)


def camera_point_cells(rc: RigCamera, stride: int, image_size, bins: np.ndarray, grid: BevGrid, z_range) -> np.ndarray:
    """(D, h, w) int64 BEV cell index (row * cols + col) of every lifted point of one camera whose
    image is `image_size` (rc.camera must be that image's camera); -1 outside the grid, outside the
    z range, on padding, or where the ray is invalid."""
    fcam = feature_camera(rc.camera, stride, image_size)
    origin, rays, valid = RigCamera(rc.name, fcam, rc.cam_to_ego).rays_ego()
    origin, rays, valid = np.asarray(origin), np.asarray(rays), np.asarray(valid)
    # feature pixels whose centre lies on the real image, not on the padding
    w, h = image_size
    uv = fcam.pixel_grid().numpy()
    centre_u, centre_v = stride * uv[..., 0] + (stride - 1) / 2, stride * uv[..., 1] + (stride - 1) / 2
    valid = valid & (centre_u <= w - 0.5) & (centre_v <= h - 0.5)
    pts = origin + bins[:, None, None, None] * rays[None]  # (D, h, w, 3)
    row, col, inside = grid.cell_of(pts)
    ok = inside & valid[None] & (pts[..., 2] >= z_range[0]) & (pts[..., 2] <= z_range[1])
    return np.where(ok, row * grid.cols + col, -1).astype(np.int64)


INTRINSIC_RADII = (0.25, 0.5, 0.75, 1.0)
INTRINSICS_DIM = 4 + 2 * len(INTRINSIC_RADII)


def mirrored_cells(point_cell: np.ndarray, grid: BevGrid) -> np.ndarray:
    """Point cells (..., h, w) of the images flipped left-right in the world mirrored about the ego x
    axis: the feature columns reversed and each cell's column j -> cols - 1 - j (-1 stays -1)."""
    if grid.y_min != -grid.y_max:
        raise ValueError(f"BEV grid: y range [{grid.y_min}, {grid.y_max}] is not symmetric, so it has no mirror image")
    pc = point_cell[..., ::-1]
    row, col = np.divmod(pc, grid.cols)
    return np.where(pc >= 0, row * grid.cols + (grid.cols - 1 - col), -1).astype(np.int64)


def intrinsics_descriptor(camera, mirrored: bool = False) -> np.ndarray:
    """A fixed-length description of a camera's intrinsics that means the same for every model
    (for the intrinsics-embedding pooling): the effective focal lengths at the principal point
    (one pixel over the angle it spans, right and down) over W and H, cx/W, cy/H (together the
    normalised 3x3 matrix), and the angle off the optical axis, in radians, of the pixels at 1/4 ..
    4/4 of the half width right of the principal point and of the half height below it (how the
    lens maps radius to angle). `mirrored`: the descriptor of the camera whose image is this one's
    flipped left-right (principal point at W - 1 - cx; what lies right of it is what lay left)."""
    w, h = camera.width, camera.height
    cx, cy = camera.cx, camera.cy
    right = -1.0 if mirrored else 1.0
    uv = [(cx + right, cy), (cx, cy + 1.0)]
    uv += [(cx + right * t * w / 2, cy) for t in INTRINSIC_RADII] + [(cx, cy + t * h / 2) for t in INTRINSIC_RADII]
    rays, valid = camera.unproject(np.asarray(uv, dtype=np.float64))
    theta = np.where(valid, np.arccos(np.clip(rays[:, 2], -1, 1)), math.pi)
    fx, fy = 1.0 / max(theta[0], 1e-9), 1.0 / max(theta[1], 1e-9)
    cx_seen = (w - 1 - cx) if mirrored else cx
    return np.concatenate([[fx / w, fy / h, cx_seen / w, cy / h], theta[2:]]).astype(np.float32)


class Frustum:
    """The lift geometry of a model config for a rig: which BEV cell each (camera, bin, feature
    pixel) lands in, and each camera's intrinsics descriptor, for the cameras as the model sees
    them (`transforms`: one view transform per camera from model.augment; None: the nominal ones)."""

    def __init__(self, rig: Rig, cfg: dict):
        m = cfg["model"]
        self.rig = rig  # cameras at their native (rendered) size
        self.input_size = tuple(cfg["data"]["input_size"])
        self.grid = BevGrid.from_dict(cfg["data"]["grid"])
        self.stride, self.z_range = m["stride"], tuple(m["z_range"])
        d = m["depth"]
        # float32-rounded, so the data set and the model's float32 buffer agree exactly
        self.bins = depth_bins(d["min"], d["max"], d["bins"], d["spacing"]).astype(np.float32).astype(np.float64)
        self.edges = depth_edges(d["min"], d["max"], d["bins"], d["spacing"])  # of the depth targets
        # only the intrinsics-embedding pooling reads a sample's intrinsics descriptors (a tenth of a
        # training sample's loading time, 2.4 of 24.5 ms, when every pooling had them computed)
        self.reads_intrinsics = m["pooling"] == "intrinsics_embedding"
        # the ground image (model.ground_channels > 0): the input images sampled at each cell's ground point
        self.ground = m["ground_channels"] > 0

    def nominal_transforms(self) -> list:
        return [base_transform(rc.camera, self.input_size) for rc in self.rig]

    def input_rig(self, transforms=None) -> Rig:
        """The rig as the model sees it: each camera resized/cropped/rotated to the input size."""
        transforms = self.nominal_transforms() if transforms is None else transforms
        return Rig([transform_camera(rc, t) for rc, t in zip(self.rig, transforms)], self.rig.name)

    def geometry(self, transforms=None, mirrored: bool = False, intrinsics: bool = True,
                 yaw: float = 0.0) -> tuple[torch.Tensor, torch.Tensor | None]:
        """(point_cell (N, D, h, w) int64, intrinsics (N, INTRINSICS_DIM) float32, None unless
        `intrinsics`); `yaw`: in the world turned by `yaw` radians about the ego z axis (the rig
        turned with it, geometry.rig.Rig.turned); `mirrored`: of the images flipped left-right, in
        the world (turned, then) mirrored about the ego x axis (module docstring)."""
        rig = self.input_rig(transforms)
        if yaw:
            rig = rig.turned(yaw)
        pc = np.stack([camera_point_cells(rc, self.stride, self.input_size, self.bins, self.grid, self.z_range) for rc in rig])
        if mirrored:
            if self.input_size[0] % self.stride:
                raise ValueError(f"input width {self.input_size[0]} is not a multiple of the stride {self.stride}: no exact mirror")
            pc = mirrored_cells(pc, self.grid)
        if not intrinsics:
            return torch.from_numpy(pc), None
        intr = np.stack([intrinsics_descriptor(rc.camera, mirrored) for rc in rig])
        return torch.from_numpy(pc), torch.from_numpy(intr)

    @cached_property
    def nominal(self) -> tuple[torch.Tensor, torch.Tensor]:
        return self.geometry(None)

    @cached_property
    def ground_native(self) -> tuple[np.ndarray, np.ndarray]:
        """(uv (N, X, Y, 2), on (N, X, Y) bool): where each BEV cell centre's ground point (ego z = 0)
        projects in each camera's native image, and whether that is on the image."""
        return ground_projection(self.rig, self.grid)

    def ground_grid(self, transforms=None, yaw: float = 0.0) -> torch.Tensor:
        """(N, X, Y, 2) float32: where each BEV cell's ground point lies in each camera's input image
        (the cameras as `geometry` takes them; no mirrored form: the config refuses the mirror with a
        ground image), as torch's grid_sample reads positions (x, y in
        [-1, 1] across the image, align_corners=False); GROUND_OFF where the camera does not see it.
        The native projection (of the turned rig, with a turn: turning moves the poses only, so it
        commutes with the view transforms) is moved by each view transform's affine map of pixels
        (model.augment.view_matrix: what warp_image applies), so the crop's padding is never seen."""
        transforms = self.nominal_transforms() if transforms is None else transforms
        w, h = self.input_size
        uv, on = ground_projection(self.rig.turned(yaw), self.grid) if yaw else self.ground_native
        a = np.stack([view_matrix(rc.camera, t) for rc, t in zip(self.rig, transforms)])[:, None, None]  # (N, 1, 1, 3, 3)
        uv = np.stack(move_pixels(a, uv[..., 0], uv[..., 1]), -1)
        on = on & (uv[..., 0] >= -0.5) & (uv[..., 0] <= w - 0.5) & (uv[..., 1] >= -0.5) & (uv[..., 1] <= h - 0.5)
        g = np.stack([(uv[..., 0] + 0.5) / w * 2 - 1, (uv[..., 1] + 0.5) / h * 2 - 1], -1)
        return torch.from_numpy(np.where(on[..., None], g, GROUND_OFF).astype(np.float32))

    @cached_property
    def nominal_ground(self) -> torch.Tensor:
        return self.ground_grid(None)


GROUND_OFF = -2.0  # a ground_grid position no camera pixel has: grid_sample reads zeros there


def ground_projection(rig: Rig, grid: BevGrid) -> tuple[np.ndarray, np.ndarray]:
    """(uv (N, X, Y, 2) float64, on (N, X, Y) bool): each cell centre's ground point (ego z = 0) in
    each camera of `rig`, and whether the camera model maps it onto the image."""
    xy = grid.cell_centres()
    pts = np.concatenate([xy, np.zeros(xy.shape[:2] + (1,))], -1)
    uvs, ons = [], []
    for rc in rig:
        uv, valid = rc.project_ego(pts)
        uv = np.nan_to_num(np.asarray(uv, dtype=np.float64), nan=-1e9, posinf=-1e9, neginf=-1e9)
        uvs.append(uv)
        ons.append(np.asarray(valid, dtype=bool) & np.asarray(rc.camera.inside(uv), dtype=bool))
    return np.stack(uvs), np.stack(ons)
