"""How Blender renders our cameras: frame conversion, OSL camera shaders, lens-polynomial fit,
top-down orthographic camera. Pure Python (numpy, torch through geometry): no bpy here.

- Frames: Blender's camera looks down its -z with +y up; ours (OpenCV) looks down +z with +y down.
  The two differ by a half turn about x: p_blender = diag(1, -1, -1) p_opencv.
- OSL: one shader template per model in ``geometry/osl/<model>.osl``, filled with the camera's
  parameters (``osl_shader_source``); Cycles runs it as a Custom camera, exact for every model.
- Fallback for devices without OSL cameras: the built-in ``FISHEYE_LENS_POLYNOMIAL``, fitted by
  least squares (``fit_lens_polynomial``), with its worst reprojection error recorded.
"""

from __future__ import annotations

import hashlib
import math
import os
import string
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from common.files import write_text_atomic

from .bev import BevGrid
from .cameras import Camera, CameraError, Cylindrical, KBTheta, RadialPoly, camera_from_dict
from .shapes import check_shape

OSL_DIR = Path(__file__).parent / "osl"

# Blender camera axes expressed in OpenCV camera axes (and back: the matrix is its own inverse).
BLENDER_FROM_OPENCV = np.diag([1.0, -1.0, -1.0])


class BlenderFitError(ValueError):
    """The lens polynomial cannot render this camera within the tolerance (one line, says why)."""


# ---------------------------------------------------------------- frames


def blender_camera_matrix(cam_to_ego, ego_pose=None) -> np.ndarray:
    """The Blender camera object's matrix from our camera-to-ego transform.

    Without ``ego_pose`` it is the camera's local matrix under an ego empty (parent); with
    ``ego_pose`` (ego -> world, 4x4) it is the camera's world matrix.
    """
    m = check_shape(np.asarray(cam_to_ego, dtype=np.float64), (4, 4), "cam_to_ego").copy()
    m[:3, :3] = m[:3, :3] @ BLENDER_FROM_OPENCV
    if ego_pose is not None:
        m = check_shape(np.asarray(ego_pose, dtype=np.float64), (4, 4), "ego_pose") @ m
    return m


def opencv_camera_matrix(blender_matrix) -> np.ndarray:
    """Inverse of ``blender_camera_matrix`` (without ego pose): Blender camera matrix -> cam_to_ego."""
    m = check_shape(np.asarray(blender_matrix, dtype=np.float64), (4, 4), "blender_matrix").copy()
    m[:3, :3] = m[:3, :3] @ BLENDER_FROM_OPENCV
    return m


# ---------------------------------------------------------------- OSL shaders


def _osl_float(x: float) -> str:
    x = float(x)
    if not math.isfinite(x):
        raise ValueError(f"cannot write {x} into an OSL shader")
    return repr(x)


def _osl_values(camera: Camera) -> dict[str, str]:
    """Template values for a camera: its parameters plus the domain limits the model derives."""
    d = camera.to_dict()
    values = {"width": _osl_float(camera.width), "height": _osl_float(camera.height)}
    for k, v in d.items():
        if k in ("model", "width", "height"):
            continue
        if isinstance(v, list):
            for i, x in enumerate(v):
                values[f"{k}{i + 1}"] = _osl_float(x)
        else:
            values[k] = _osl_float(v)
    if isinstance(camera, KBTheta):
        p = list(camera.params["p"]) + [0.0] * (9 - len(camera.params["p"]))
        values["p"] = ", ".join(_osl_float(x) for x in p)
    if camera.model == "mei":  # the disc where the distortion is one-to-one (finite stand-ins for inf)
        r2_hi = min(camera.r2_radial, camera.r2_max)
        values["r2_max"] = _osl_float(min(camera.r2_max, 1e30))
        values["r_hi"] = _osl_float(math.sqrt(r2_hi) if math.isfinite(r2_hi) else 1e6)
    for attr in ("theta_max", "rho_max"):
        if attr in values:
            continue
        v = getattr(type(camera), attr, None)
        if v is None:
            continue
        v = getattr(camera, attr)
        if math.isfinite(v):
            values[attr] = _osl_float(v)
    return values


def osl_template_path(model: str) -> Path:
    return OSL_DIR / f"{model}.osl"


def osl_shader_source(camera: Camera) -> str:
    """OSL source of a Custom camera shader that renders exactly ``camera`` (pixel -> ray)."""
    path = osl_template_path(camera.model)
    if not path.is_file():
        raise ValueError(f"no OSL template for camera model '{camera.model}' (expected {path})")
    try:
        return string.Template(path.read_text()).substitute(_osl_values(camera))
    except KeyError as exc:
        raise ValueError(f"{path}: template names ${exc.args[0]}, which {camera.model} does not give") from None


def default_osl_workdir() -> Path:
    """Per-user directory for generated shaders (outside the repo; Cycles writes .oso beside them)."""
    return Path(tempfile.gettempdir()) / f"fisheye_bev_osl_{os.getuid() if hasattr(os, 'getuid') else 'user'}"


def write_osl_shader(camera: Camera, workdir=None) -> Path:
    """Write the camera's shader to ``workdir`` as ``<model>_<hash>.osl`` (atomic; the same camera
    gives the same file, so parallel workers share it) and return its path."""
    src = osl_shader_source(camera)
    workdir = Path(workdir) if workdir is not None else default_osl_workdir()
    workdir.mkdir(parents=True, exist_ok=True)
    path = workdir / f"{camera.model}_{hashlib.sha1(src.encode()).hexdigest()[:16]}.osl"
    if not path.is_file() or path.read_text() != src:
        write_text_atomic(path, src)
    return path


# ---------------------------------------------------------------- lens-polynomial fallback


@dataclass
class LensPolynomial:
    """Blender ``FISHEYE_LENS_POLYNOMIAL`` settings: theta = -(k0 + k1 r + ... + k4 r^4), r in mm
    on a sensor whose ``sensor_width`` spans max(width, height) (``sensor_fit='AUTO'``)."""

    width: int
    height: int
    k: list[float]  # k0..k4 (Blender's signs)
    sensor_width: float  # mm
    shift_x: float
    shift_y: float
    fov: float  # rad; rays with theta > fov / 2 are black
    fit_error_px: float  # worst reprojection error over the image's valid pixels
    valid_mismatch: int = 0  # pixels where the fitted lens and the model disagree on validity
    model: str = field(default="")

    @property
    def px_per_mm(self) -> float:
        return max(self.width, self.height) / self.sensor_width

    def as_camera(self) -> Camera:
        """What Blender renders, as one of our cameras (kb_theta in pixels / px_per_mm)."""
        f = self.px_per_mm
        cx = self.width * (0.5 - self.shift_x) - 0.5
        cy = self.height * (0.5 + self.shift_y) - 0.5
        return camera_from_dict(
            {"model": "kb_theta", "width": self.width, "height": self.height, "fx": f, "fy": f,
             "cx": cx, "cy": cy, "p": [-float(c) for c in self.k[1:]]}
        )

    def theta_of_pixels(self, uv) -> np.ndarray:
        """theta of Blender's ray for pixel positions (..., 2)."""
        kb = self.as_camera()
        r = np.hypot(uv[..., 0] - kb.cx, uv[..., 1] - kb.cy) / self.px_per_mm
        return -(self.k[0] + r * (self.k[1] + r * (self.k[2] + r * (self.k[3] + r * self.k[4]))))

    def valid_pixels(self, uv) -> np.ndarray:
        """Where Blender renders a ray (its FOV test: |theta| <= fov / 2)."""
        return np.abs(self.theta_of_pixels(uv)) <= 0.5 * self.fov

    def to_dict(self) -> dict:
        return {"k": [float(c) for c in self.k], "sensor_width": self.sensor_width, "shift_x": self.shift_x,
                "shift_y": self.shift_y, "fov": self.fov, "fit_error_px": self.fit_error_px}


def _radial_focal(camera: Camera) -> float:
    """fx (== fy) of a radially symmetric camera, or BlenderFitError."""
    if isinstance(camera, Cylindrical) or "cx" not in camera.params:
        raise BlenderFitError(f"{camera.model}: not radially symmetric, the lens polynomial cannot render it")
    if isinstance(camera, RadialPoly):
        if abs(camera.params["aspect_ratio"] - 1.0) > 1e-12:
            raise BlenderFitError(f"radial_poly: aspect_ratio {camera.params['aspect_ratio']} != 1, "
                                  "the lens polynomial needs square pixels (use the OSL camera)")
        return 1.0
    fx, fy = camera.params["fx"], camera.params["fy"]
    if abs(fx - fy) > 1e-12 * max(fx, fy):
        raise BlenderFitError(f"{camera.model}: fx {fx} != fy {fy}, the lens polynomial needs square pixels "
                              "(use the OSL camera)")
    return fx


def _theta_of_radius(camera: Camera, r_px: np.ndarray):
    """theta of the model's ray at r_px pixels from the principal point (along +u), and validity."""
    cx, cy = camera.params["cx"], camera.params["cy"]
    uv = np.stack([cx + r_px, np.full_like(r_px, cy)], -1)
    rays, valid = camera.unproject(uv)
    return np.arctan2(np.hypot(rays[..., 0], rays[..., 1]), rays[..., 2]), valid


def _minimax_fit(a: np.ndarray, b: np.ndarray, iters: int = 200) -> np.ndarray:
    """min_c max_i |a_i c - b_i|: least squares, then Lawson's reweighting towards the minimax
    solution (the worst pixel is what the fallback is judged by). Keeps the best iterate."""
    w = np.full(len(b), 1.0 / len(b))
    best, best_err = None, math.inf
    for _ in range(iters):
        sw = np.sqrt(w)
        c, *_ = np.linalg.lstsq(a * sw[:, None], b * sw, rcond=None)
        e = np.abs(a @ c - b)
        if e.max() < best_err:
            best, best_err = c, float(e.max())
        w = w * e
        if w.sum() <= 0:
            break
        w /= w.sum()
    return best


def fit_lens_polynomial(camera: Camera, tol_px: float = 0.05) -> LensPolynomial:
    """Least-squares ``FISHEYE_LENS_POLYNOMIAL`` for a radially symmetric camera with fx == fy.

    Fits theta(r) = c1 r + ... + c4 r^4 over the radii of the image's valid pixels, weighted so that
    the residual is in pixels, then measures the worst reprojection error over every valid pixel
    centre of the image (Blender's ray projected through our model). Raises BlenderFitError where
    the camera is not radially symmetric or the error exceeds ``tol_px``.
    """
    _radial_focal(camera)
    w, h = camera.width, camera.height
    cx, cy = camera.params["cx"], camera.params["cy"]
    grid = camera.pixel_grid().numpy()
    _, valid = camera.unproject(grid)
    if not valid.any():
        raise BlenderFitError(f"{camera.model}: no pixel of the image has a ray")
    r_img = np.hypot(grid[..., 0] - cx, grid[..., 1] - cy)
    r_far = float(r_img[valid].max())
    # r_edge: the model's validity radius when it is inside the image (a fisheye circle), else None
    r_edge = float(r_img[~valid].min()) if (~valid).any() else None

    # dense samples of theta(r) on [0, r_far], weighted by dr/dtheta (so residuals are in pixels)
    r = np.linspace(0.0, r_far, 2000)
    theta, ok = _theta_of_radius(camera, r)
    r, theta = r[ok], theta[ok]
    dtheta_dr = np.gradient(theta, r)
    if np.any(dtheta_dr <= 0):
        raise BlenderFitError(f"{camera.model}: theta does not increase with radius over the image")
    s = 1.0 / dtheta_dr[0]  # px per radian at the centre: fit in x = r / s (about radians)
    x = r / s
    a = np.stack([x, x**2, x**3, x**4], -1)
    wgt = 1.0 / dtheta_dr  # px per radian: theta residual * wgt = pixel residual
    c = _minimax_fit(a * wgt[:, None], theta * wgt)

    # Blender units: r_mm = r_px / px_per_mm; choose 1 mm = s px (coefficients near 1, well scaled)
    sensor_width = max(w, h) / s
    if sensor_width < 1.0:  # Blender's minimum sensor width
        sensor_width = 1.0
    px_per_mm = max(w, h) / sensor_width
    scale = px_per_mm / s  # x = r_mm * scale
    k = [0.0] + [-float(ci * scale ** (i + 1)) for i, ci in enumerate(c)]
    poly = lambda r_px: -(k[1] * (r_px / px_per_mm) + k[2] * (r_px / px_per_mm) ** 2 +  # noqa: E731
                          k[3] * (r_px / px_per_mm) ** 3 + k[4] * (r_px / px_per_mm) ** 4)
    if r_edge is not None:
        # Blender blacks out theta > fov / 2: put that edge between the last valid and first invalid radius
        fov = float(poly(np.array([0.5 * (r_far + r_edge)]))[0]) * 2
    else:
        fov = float(poly(np.array([r_far]))[0]) * 2 + 1e-3
    fov = min(fov, 2 * math.pi)
    fit = LensPolynomial(
        width=w, height=h, k=k, sensor_width=float(sensor_width),
        shift_x=0.5 - (cx + 0.5) / w, shift_y=(cy + 0.5) / h - 0.5, fov=fov, fit_error_px=math.nan,
        model=camera.model,
    )
    try:
        fit.fit_error_px, fit.valid_mismatch = lens_polynomial_error(camera, fit, valid)
    except CameraError:  # the fitted polynomial does not start increasing: no lens
        raise BlenderFitError(f"{camera.model}: the fitted lens polynomial is not increasing at the centre") from None
    if fit.valid_mismatch:
        raise BlenderFitError(f"{camera.model}: the fitted lens polynomial disagrees with the model's valid "
                              f"region on {fit.valid_mismatch} pixels")
    if not fit.fit_error_px <= tol_px:
        raise BlenderFitError(f"{camera.model}: lens polynomial reprojection error {fit.fit_error_px:.4g} px "
                              f"exceeds the tolerance {tol_px} px (use the OSL camera)")
    return fit


def lens_polynomial_error(camera: Camera, fit: LensPolynomial, valid=None) -> tuple[float, int]:
    """(worst reprojection error in px over pixels valid in both, pixels whose validity differs):
    each pixel's Blender ray projected through our camera, against the pixel centre.
    valid: the camera's (H, W) valid mask when the caller has it already."""
    grid = camera.pixel_grid().numpy()
    ours = camera.unproject(grid)[1] if valid is None else valid
    theirs = fit.valid_pixels(grid)
    rays, ok = fit.as_camera().unproject(grid)
    both = ours & theirs
    uv, proj_ok = camera.project(rays)
    err = np.linalg.norm(uv - grid, axis=-1)
    bad = both & ~(ok & proj_ok)  # the fitted polynomial stops increasing, or a ray leaves our model
    worst = math.inf if bad.any() else (float(err[both].max()) if both.any() else 0.0)
    return worst, int((ours != theirs).sum())


# ---------------------------------------------------------------- top-down orthographic camera


@dataclass
class TopdownCamera:
    """An orthographic camera looking straight down whose pixel (row i, col j) is BEV cell (i, j)."""

    width: int  # grid.cols
    height: int  # grid.rows
    ortho_scale: float  # metres spanned by max(width, height) (sensor_fit AUTO)
    cam_to_ego: np.ndarray  # OpenCV camera frame -> ego: x right = -y ego, y down = -x ego, z = -z ego
    clip_end: float

    @property
    def blender_matrix(self) -> np.ndarray:
        return blender_camera_matrix(self.cam_to_ego)


def topdown_camera(grid: BevGrid, height_m: float) -> TopdownCamera:
    if not height_m > 0:
        raise ValueError(f"top-down camera height must be positive, got {height_m}")
    rot = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # columns: cam x, y, z in ego
    m = np.eye(4)
    m[:3, :3] = rot
    m[:3, 3] = [0.5 * (grid.x_min + grid.x_max), 0.5 * (grid.y_min + grid.y_max), float(height_m)]
    return TopdownCamera(
        width=grid.cols, height=grid.rows, ortho_scale=max(grid.rows, grid.cols) * grid.res,
        cam_to_ego=m, clip_end=2.0 * float(height_m) + 1000.0,
    )
