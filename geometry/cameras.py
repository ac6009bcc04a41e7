"""Camera models: pixel <-> unit ray, batched, numpy or torch.

Frames and formulas are those of docs/geometry.md: camera frame OpenCV (x right, y down, z forward),
pixels (u right, v down) with the centre of the top-left pixel at (0, 0).

Every camera has

    project(points[..., 3]) -> (uv[..., 2], valid[...])
    unproject(uv[..., 2])   -> (rays[..., 3], valid[...])      unit rays

Numpy in gives numpy out; torch in gives torch out, differentiable. All the arithmetic is written
once, in torch; numpy arrays go through ``torch.from_numpy`` (no copy). ``valid`` says whether the
point (pixel) lies in the model's domain; where it is False the other output is finite but
meaningless. Whether a pixel lies inside the image is ``camera.inside(uv)``.

Models whose mapping has no closed-form inverse (``kb_theta`` projection, ``radial_poly`` and
``opencv_fisheye`` unprojection) invert a monotonic polynomial with safeguarded Newton iterations,
vectorised, to ``SOLVE_TOL`` (1e-13 rad or normalised units, float64). Gradients flow through one
final Newton step, which gives the implicit-function derivative.
"""

from __future__ import annotations

import functools
import math
from typing import Any, ClassVar

import numpy as np
import torch

from common.errors import InputError

from .shapes import check_shape

SOLVE_TOL = 1e-13
_EPS = 1e-12


class CameraError(InputError):
    """A calibration dictionary that cannot make a camera (names the field)."""


# ---------------------------------------------------------------- array plumbing


def _to_torch(x) -> tuple[torch.Tensor, bool]:
    if isinstance(x, torch.Tensor):
        return (x if x.is_floating_point() else x.double()), False
    a = np.asarray(x)
    if not np.issubdtype(a.dtype, np.floating):
        a = a.astype(np.float64)
    return torch.from_numpy(np.ascontiguousarray(a)), True


def _back(t: torch.Tensor, to_numpy: bool):
    return t.detach().cpu().numpy() if to_numpy else t


def _safe_div(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """a / b where b != 0, else 0, without NaN gradients."""
    nz = b.abs() > _EPS
    return torch.where(nz, a / torch.where(nz, b, torch.ones_like(b)), torch.zeros_like(a))


def _poly(coeffs: torch.Tensor, t: torch.Tensor, first_power: int = 1) -> torch.Tensor:
    """sum_i c_i t^(i + first_power), Horner."""
    return _horner(coeffs.unbind(-1), t, first_power)


def _horner(coeffs: tuple, t: torch.Tensor, first_power: int) -> torch.Tensor:
    acc = torch.zeros_like(t)
    for c in reversed(coeffs):
        acc = acc * t + c
    return acc * t**first_power if first_power else acc


class _Poly:
    """t -> sum_i c_i t^(i + first_power) (first_power >= 1) and its derivative, for a Newton solve
    (`_invert_monotonic`): the coefficients split, and the derivative's (c_i (i + first_power))
    formed, once rather than at each of the solve's ~7 steps (a lift's few hundred points per
    camera spend their time in per-operation overhead); the same arithmetic as `_poly`."""

    def __init__(self, coeffs: torch.Tensor, first_power: int = 1):
        n = coeffs.shape[-1]
        self.first_power = first_power
        self.coeffs = coeffs.unbind(-1)
        self.deriv_coeffs = (coeffs * torch.arange(first_power, first_power + n, dtype=coeffs.dtype, device=coeffs.device)).unbind(-1)

    def __call__(self, t: torch.Tensor) -> torch.Tensor:
        return _horner(self.coeffs, t, self.first_power)

    def deriv(self, t: torch.Tensor) -> torch.Tensor:
        return _horner(self.deriv_coeffs, t, self.first_power - 1)


def _invert_monotonic(f, df, y: torch.Tensor, t_max: float, guess: torch.Tensor) -> torch.Tensor:
    """Solve f(t) = y for t in [0, t_max], f increasing there. Safeguarded Newton, vectorised.

    Iterates without gradients, then takes one Newton step with them: at the root that step
    carries the implicit-function derivatives dt/dy = 1/f'(t) and dt/dp = -(df/dp)/f'(t).
    """
    with torch.no_grad():
        yd = y.detach()
        lo = torch.zeros_like(yd)
        hi = torch.full_like(yd, t_max)
        t = guess.detach().clamp(0.0, t_max)
        for _ in range(100):
            ft = f(t) - yd
            lo = torch.where(ft < 0, t, lo)
            hi = torch.where(ft > 0, t, hi)
            d = df(t)
            step = ft / torch.where(d > 0, d, torch.ones_like(d))
            t_new = t - step
            bad = (t_new <= lo) | (t_new >= hi) | (d <= 0)
            t_new = torch.where(bad, 0.5 * (lo + hi), t_new)
            delta = (t_new - t).abs().max() if t.numel() else torch.tensor(0.0)
            t = t_new
            if delta < SOLVE_TOL * 1e-2:
                break
    d = df(t)
    return t - (f(t) - y) / torch.where(d > 0, d, torch.ones_like(d))


def _monotonic_limit(coeffs, upper: float, cap: float = math.inf) -> float:
    """Largest T <= upper such that the polynomial (coefficients from power 0) increases on
    [0, T] and stays below cap there: the first positive real root of p' or of p - cap."""
    return _monotonic_limit_of(tuple(float(c) for c in np.asarray(coeffs, dtype=np.float64)), float(upper), float(cap))


@functools.lru_cache(maxsize=1024)
def _monotonic_limit_of(coeffs: tuple, upper: float, cap: float) -> float:
    """_monotonic_limit for a tuple of coefficients, kept: every resized, scaled or cropped copy of
    a camera checks the same polynomial again (28 copies per training sample)."""
    p = np.polynomial.Polynomial(np.asarray(coeffs, dtype=np.float64))
    limit = upper
    for q in (p.deriv(), p - cap if math.isfinite(cap) else None):
        if q is None or q.degree() < 1:
            continue
        r = q.roots()
        r = r.real[(np.abs(r.imag) <= 1e-12 * np.maximum(1.0, np.abs(r.real))) & (r.real > 0)]
        if len(r):
            limit = min(limit, float(r.min()))
    return limit


# ---------------------------------------------------------------- base class


class Camera:
    """Base: width, height and a model's parameters. Subclasses give `_project`/`_unproject`."""

    model: ClassVar[str]
    keys: ClassVar[tuple[str, ...]]
    list_keys: ClassVar[dict[str, tuple[int, int]]] = {}  # key -> (min, max) length

    def __init__(self, width: int, height: int, **params: Any):
        self.width = int(width)
        self.height = int(height)
        if self.width <= 0 or self.height <= 0:
            raise CameraError(f"{self.model}: width and height must be positive")
        missing = [k for k in self.keys if k not in params]
        if missing:
            raise CameraError(f"{self.model}: missing key '{missing[0]}'")
        extra = [k for k in params if k not in self.keys]
        if extra:
            raise CameraError(f"{self.model}: unknown key '{extra[0]}' (keys: {', '.join(self.keys)})")
        self.params: dict[str, Any] = {}
        for k in self.keys:
            v = params[k]
            if k in self.list_keys:
                lo, hi = self.list_keys[k]
                try:
                    v = [float(x) for x in v]
                except (TypeError, ValueError):
                    raise CameraError(f"{self.model}: '{k}' must be a list of numbers") from None
                if not lo <= len(v) <= hi:
                    raise CameraError(f"{self.model}: '{k}' must have {lo} to {hi} entries, has {len(v)}")
            else:
                try:
                    v = float(v)
                except (TypeError, ValueError):
                    raise CameraError(f"{self.model}: '{k}' must be a number, got {v!r}") from None
            if not np.all(np.isfinite(v)):
                raise CameraError(f"{self.model}: '{k}' must be finite")
            self.params[k] = v
        self._validate()

    def _validate(self) -> None:
        for k in ("fx", "fy"):
            if k in self.params and self.params[k] <= 0:
                raise CameraError(f"{self.model}: '{k}' must be positive")

    def __getattr__(self, name):
        params = self.__dict__.get("params")
        if params is not None and name in params:
            return params[name]
        raise AttributeError(name)

    def __repr__(self) -> str:
        p = ", ".join(f"{k}={v}" for k, v in self.params.items())
        return f"{type(self).__name__}({self.width}x{self.height}, {p})"

    def __eq__(self, other) -> bool:
        return isinstance(other, Camera) and self.to_dict() == other.to_dict()

    # -- dict I/O
    def to_dict(self) -> dict:
        d = {"model": self.model, "width": self.width, "height": self.height}
        for k, v in self.params.items():
            d[k] = list(v) if isinstance(v, list) else v
        return d

    def replace(self, **changes) -> "Camera":
        d = self.to_dict()
        d.update(changes)
        return camera_from_dict(d)

    # -- public API
    def project(self, points):
        p, to_np = _to_torch(points)
        check_shape(p, (..., 3), "points")
        uv, valid = self._project(p)
        return _back(uv, to_np), _back(valid, to_np)

    def unproject(self, uv):
        q, to_np = _to_torch(uv)
        check_shape(q, (..., 2), "uv")
        rays, valid = self._unproject(q)
        return _back(rays, to_np), _back(valid, to_np)

    def inside(self, uv):
        """True where a pixel position lies on the image (between the outer pixel edges)."""
        q, to_np = _to_torch(uv)
        check_shape(q, (..., 2), "uv")
        u, v = q[..., 0], q[..., 1]
        m = (u >= -0.5) & (u <= self.width - 0.5) & (v >= -0.5) & (v <= self.height - 0.5)
        return _back(m, to_np)

    def pixel_grid(self, dtype=torch.float64) -> torch.Tensor:
        """(H, W, 2) pixel centres (u, v)."""
        v, u = torch.meshgrid(
            torch.arange(self.height, dtype=dtype), torch.arange(self.width, dtype=dtype), indexing="ij"
        )
        return torch.stack([u, v], -1)

    # -- resize and crop (pixel centres: u' = s (u + 0.5) - 0.5)
    def scaled(self, sx: float, sy: float | None = None) -> "Camera":
        """The camera of this image resampled by (sx, sy): width' = round(width * sx)."""
        sy = sx if sy is None else sy
        d = self._scaled_params(float(sx), float(sy))
        d["width"] = int(round(self.width * sx))
        d["height"] = int(round(self.height * sy))
        return camera_from_dict(d)

    def resized(self, width: int, height: int) -> "Camera":
        """The camera of this image resized to exactly width x height."""
        d = self._scaled_params(width / self.width, height / self.height)
        d["width"], d["height"] = int(width), int(height)
        return camera_from_dict(d)

    MIN_IMAGE_SIDE: ClassVar[int] = 16  # pixels: an image smaller than this is no resize of a camera

    def for_image(self, width: int, height: int) -> "Camera":
        """The camera of a width x height image taken with this camera: itself at its own size, else
        resized, when the image is a resize of it (the same aspect ratio within the rounding of a
        resize, and at least MIN_IMAGE_SIDE pixels a side). Any other size is a CameraError (a 1 x 1
        image is no picture of a 960 x 640 camera)."""
        width, height = int(width), int(height)
        if (width, height) == (self.width, self.height):
            return self
        expect = self.height * width / self.width
        if min(width, height) < self.MIN_IMAGE_SIDE or abs(height - expect) > max(1.0, 0.005 * expect):
            raise CameraError(f"a {width}x{height} image is not a resize of the {self.width}x{self.height} camera "
                              f"(another aspect ratio, or under {self.MIN_IMAGE_SIDE} pixels a side)")
        return self.resized(width, height)

    def cropped(self, x0: int, y0: int, width: int, height: int) -> "Camera":
        """The camera of the sub-image whose top-left pixel is (x0, y0) in this image."""
        d = self.to_dict()
        d["cx"] -= x0
        d["cy"] -= y0
        d["width"], d["height"] = int(width), int(height)
        return camera_from_dict(d)

    def _scaled_params(self, sx: float, sy: float) -> dict:
        d = self.to_dict()
        d["fx"] *= sx
        d["fy"] *= sy
        d["cx"] = sx * (d["cx"] + 0.5) - 0.5
        d["cy"] = sy * (d["cy"] + 0.5) - 0.5
        return d

    # -- helpers for subclasses
    def _t(self, value, like: torch.Tensor) -> torch.Tensor:
        return torch.as_tensor(value, dtype=like.dtype, device=like.device)

    def _normalised(self, uv: torch.Tensor):
        return (uv[..., 0] - self.cx) / self.fx, (uv[..., 1] - self.cy) / self.fy

    def _to_pixels(self, mx: torch.Tensor, my: torch.Tensor) -> torch.Tensor:
        return torch.stack([self.fx * mx + self.cx, self.fy * my + self.cy], -1)

    def _project(self, p: torch.Tensor):
        raise NotImplementedError

    def _unproject(self, uv: torch.Tensor):
        raise NotImplementedError


# ---------------------------------------------------------------- radially symmetric models


class RadialCamera(Camera):
    """u = fx rho(theta) x/chi + cx, v = fy rho(theta) y/chi + cy.

    Subclasses give rho(theta) and its inverse; `theta_max` bounds the projection domain
    (theta < theta_max) and `rho_max` = rho(theta_max) the unprojection domain.
    """

    theta_max: float = math.pi

    def rho(self, theta: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def theta_of_rho(self, rho: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    @property
    def rho_max(self) -> float:
        return float(self.rho(torch.tensor(self.theta_max, dtype=torch.float64)))

    def _project(self, p):
        x, y, z = p.unbind(-1)
        chi = torch.sqrt(x * x + y * y)
        theta = torch.atan2(chi, z)
        r = self.rho(theta)
        scale = _safe_div(r, chi)
        valid = (theta < self.theta_max) & ((chi > 0) | (z > 0))
        return self._to_pixels(scale * x, scale * y), valid

    def _unproject(self, uv):
        mx, my = self._normalised(uv)
        r = torch.sqrt(mx * mx + my * my)
        theta = self.theta_of_rho(r)
        s = _safe_div(torch.sin(theta), r)
        rays = torch.stack([s * mx, s * my, torch.cos(theta)], -1)
        return rays, r < self.rho_max


class Equidistant(RadialCamera):
    model, keys = "equidistant", ("fx", "fy", "cx", "cy")

    def rho(self, theta):
        return theta

    def theta_of_rho(self, rho):
        return rho


class Equisolid(RadialCamera):
    model, keys = "equisolid", ("fx", "fy", "cx", "cy")

    def rho(self, theta):
        return 2 * torch.sin(theta / 2)

    def theta_of_rho(self, rho):
        return 2 * torch.asin((rho / 2).clamp(-1, 1))

    @property
    def rho_max(self):
        return 2.0


class Stereographic(RadialCamera):
    model, keys = "stereographic", ("fx", "fy", "cx", "cy")

    def rho(self, theta):
        return 2 * torch.tan(theta / 2)

    def theta_of_rho(self, rho):
        return 2 * torch.atan(rho / 2)

    @property
    def rho_max(self):
        return math.inf


class Pinhole(RadialCamera):
    """u = fx x/z + cx (z > 0); every pixel unprojects."""

    model, keys = "pinhole", ("fx", "fy", "cx", "cy")
    theta_max = math.pi / 2

    def rho(self, theta):
        return torch.tan(theta)

    def theta_of_rho(self, rho):
        return torch.atan(rho)

    @property
    def rho_max(self):
        return math.inf

    def _project(self, p):
        x, y, z = p.unbind(-1)
        valid = z > 0
        zs = torch.where(valid, z, torch.ones_like(z))
        return self._to_pixels(x / zs, y / zs), valid

    def _unproject(self, uv):
        mx, my = self._normalised(uv)
        rays = torch.stack([mx, my, torch.ones_like(mx)], -1)
        return rays / rays.norm(dim=-1, keepdim=True), torch.ones_like(mx, dtype=torch.bool)


class _PolyRadial(RadialCamera):
    """rho = poly(theta), inverted iteratively; domain limited to where poly increases."""

    coeff_key: ClassVar[str] = "k"
    first_power: ClassVar[int] = 1

    def _coeffs(self, like):
        return self._t(self._poly_coeffs(), like)

    def _poly_coeffs(self) -> list[float]:
        return self.params[self.coeff_key]

    def _validate(self):
        super()._validate()
        c = np.asarray([0.0] * self.first_power + list(self._poly_coeffs()), dtype=np.float64)
        if c[1] <= 0:
            raise CameraError(f"{self.model}: '{self.coeff_key}' must make rho increase from theta = 0")
        self.theta_max = _monotonic_limit(c, math.pi)
        self._rho_max = float(np.polynomial.polynomial.polyval(self.theta_max, c))

    @property
    def rho_max(self):
        return self._rho_max

    def rho(self, theta):
        return _poly(self._coeffs(theta), theta, self.first_power)

    def theta_of_rho(self, rho):
        p = _Poly(self._coeffs(rho), self.first_power)
        d0 = float(self._poly_coeffs()[0])  # rho'(0)
        return _invert_monotonic(p, p.deriv, rho, self.theta_max, rho / d0)


class OpenCVFisheye(_PolyRadial):
    """theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8) (cv2.fisheye)."""

    model, keys = "opencv_fisheye", ("fx", "fy", "cx", "cy", "k")
    list_keys = {"k": (4, 4)}

    def _poly_coeffs(self):
        k = self.params["k"]
        # theta + k1 theta^3 + ... as coefficients of theta^1..theta^9
        return [1.0, 0.0, k[0], 0.0, k[1], 0.0, k[2], 0.0, k[3]]


class RadialPoly(_PolyRadial):
    """WoodScape: rho = k1 theta + ... + k4 theta^4 in pixels; v is scaled by aspect_ratio."""

    model, keys = "radial_poly", ("cx", "cy", "aspect_ratio", "k")
    list_keys = {"k": (4, 4)}

    def _validate(self):
        if self.params["aspect_ratio"] <= 0:
            raise CameraError("radial_poly: 'aspect_ratio' must be positive")
        super()._validate()

    @property
    def fx(self):
        return 1.0

    @property
    def fy(self):
        return self.params["aspect_ratio"]

    def _scaled_params(self, sx, sy):
        d = self.to_dict()
        d["k"] = [sx * k for k in d["k"]]
        d["aspect_ratio"] *= sy / sx
        d["cx"] = sx * (d["cx"] + 0.5) - 0.5
        d["cy"] = sy * (d["cy"] + 0.5) - 0.5
        return d


class KBTheta(RadialCamera):
    """The paper's eq. 1: theta = p1 r + p2 r^2 + ... (r normalised by fx, fy). A radial model whose
    theta_of_rho is the polynomial; rho(theta), used by projection, inverts it."""

    model, keys = "kb_theta", ("fx", "fy", "cx", "cy", "p")
    list_keys = {"p": (1, 9)}

    def _validate(self):
        super()._validate()
        if self.params["p"][0] <= 0:
            raise CameraError("kb_theta: 'p' must start with a positive p1")
        c = np.asarray([0.0] + list(self.params["p"]), dtype=np.float64)
        # r where theta stops increasing or reaches pi (p1 > 0 makes one of them exist)
        self._rho_max = _monotonic_limit(c, 1e6, math.pi)
        self.theta_max = float(np.polynomial.polynomial.polyval(self._rho_max, c))

    @property
    def rho_max(self):
        return self._rho_max

    def rho(self, theta):
        c = self._t(self.params["p"], theta)
        p = _Poly(c)
        return _invert_monotonic(p, p.deriv, theta, self._rho_max, theta / c[0])

    def theta_of_rho(self, rho):
        return _poly(self._t(self.params["p"], rho), rho)


# ---------------------------------------------------------------- unified camera models (Usenko et al. 2018)


def _w1(alpha: float) -> float:
    return alpha / (1 - alpha) if alpha <= 0.5 else (1 - alpha) / alpha


class UCM(Camera):
    """u = fx x / (alpha d + (1 - alpha) z) + cx; alpha in [0, 1]."""

    model, keys = "ucm", ("fx", "fy", "cx", "cy", "alpha")
    beta = 1.0  # UCM is EUCM with beta = 1

    def _validate(self):
        super()._validate()
        if not 0 <= self.params["alpha"] <= 1:
            raise CameraError(f"{self.model}: 'alpha' must be in [0, 1]")

    def _d(self, x, y, z):
        return torch.sqrt(self.beta * (x * x + y * y) + z * z)

    def _project(self, p):
        x, y, z = p.unbind(-1)
        a = self.alpha
        d = self._d(x, y, z)
        den = a * d + (1 - a) * z
        valid = (z > -_w1(a) * d) & (den > 0)
        den = torch.where(den > 0, den, torch.ones_like(den))
        return self._to_pixels(x / den, y / den), valid

    def _unproject(self, uv):
        a, b = self.alpha, self.beta
        mx, my = self._normalised(uv)
        r2 = mx * mx + my * my
        valid = torch.ones_like(r2, dtype=torch.bool) if a <= 0.5 else r2 <= 1 / (b * (2 * a - 1))
        mz = (1 - b * a * a * r2) / (a * torch.sqrt((1 - (2 * a - 1) * b * r2).clamp(min=0)) + (1 - a))
        rays = torch.stack([mx, my, mz], -1)
        return rays / rays.norm(dim=-1, keepdim=True), valid


class EUCM(UCM):
    """UCM with d = sqrt(beta (x^2 + y^2) + z^2)."""

    model, keys = "eucm", ("fx", "fy", "cx", "cy", "alpha", "beta")

    def _validate(self):
        super()._validate()
        if self.params["beta"] <= 0:
            raise CameraError("eucm: 'beta' must be positive")

    @property
    def beta(self):
        return self.params["beta"]


class DoubleSphere(Camera):
    """d1 = |p|, d2 = |(x, y, xi d1 + z)|; u = fx x / (alpha d2 + (1 - alpha)(xi d1 + z)) + cx."""

    model, keys = "double_sphere", ("fx", "fy", "cx", "cy", "xi", "alpha")

    def _validate(self):
        super()._validate()
        if not 0 <= self.params["alpha"] <= 1:
            raise CameraError("double_sphere: 'alpha' must be in [0, 1]")
        if not -1 < self.params["xi"] <= 1:
            raise CameraError("double_sphere: 'xi' must be in (-1, 1]")
        # The paper's projection domain z > -w2 d1 is exact only for xi = 0 (measured: for xi = 0.3,
        # alpha = 0.6 it stops at 142.4 deg where the mapping folds at 144.7). Exact: for alpha > 0.5,
        # the angle of the ray at the unprojection boundary r^2 = 1 / (2 alpha - 1); else den > 0.
        a, xi = self.params["alpha"], self.params["xi"]
        self.theta_max = math.pi
        if a > 0.5:
            r2 = 1 / (2 * a - 1)
            mz = -(1 - a) / (2 * a - 1)
            k = (mz * xi + math.sqrt(mz * mz + (1 - xi * xi) * r2)) / (mz * mz + r2)
            self.theta_max = math.atan2(k * math.sqrt(r2), k * mz - xi)

    def _project(self, p):
        x, y, z = p.unbind(-1)
        a, xi = self.alpha, self.xi
        d1 = torch.sqrt(x * x + y * y + z * z)
        zx = xi * d1 + z
        d2 = torch.sqrt(x * x + y * y + zx * zx)
        den = a * d2 + (1 - a) * zx
        valid = (den > 0) & (torch.atan2(torch.sqrt(x * x + y * y), z) < self.theta_max)
        den = torch.where(den > 0, den, torch.ones_like(den))
        return self._to_pixels(x / den, y / den), valid

    def _unproject(self, uv):
        a, xi = self.alpha, self.xi
        mx, my = self._normalised(uv)
        r2 = mx * mx + my * my
        valid = torch.ones_like(r2, dtype=torch.bool) if a <= 0.5 else r2 <= 1 / (2 * a - 1)
        mz = (1 - a * a * r2) / (a * torch.sqrt((1 - (2 * a - 1) * r2).clamp(min=0)) + 1 - a)
        k = (mz * xi + torch.sqrt((mz * mz + (1 - xi * xi) * r2).clamp(min=0))) / (mz * mz + r2)
        rays = torch.stack([k * mx, k * my, k * mz - xi], -1)
        return rays / rays.norm(dim=-1, keepdim=True), valid


# ---------------------------------------------------------------- Mei's unified model with radtan (cv2.omnidir, Kalibr omni)


def _radtan_t(x, y, k1, k2, p1, p2):
    """The radial-tangential distortion of a unit-plane point (cv2.omnidir, Kalibr radtan)."""
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 * r2
    return (x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
            y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y)


class Mei(Camera):
    """Mei's unified model (cv2.omnidir, Kalibr `omni` + `radtan`): a point on the unit sphere
    shifted by xi, (x, y) = (X, Y) / (Z + xi), distorted by k = [k1, k2, p1, p2] (radial-tangential)
    to (xd, yd); u = fx xd + s yd + cx, v = fy yd + cy. xi = 0 is a pinhole with radtan distortion.

    Domain: the sphere shift sees Z > -xi (xi <= 1) or Z > -1/xi (xi > 1), and the distortion
    is kept where its radial part still increases (r < r_max, the first root of
    d(r (1 + k1 r^2 + k2 r^4))/dr); unprojection inverts the distortion by Newton's method (2-D),
    to SOLVE_TOL, with one last step carrying the gradients."""

    model, keys = "mei", ("fx", "fy", "cx", "cy", "s", "xi", "k")
    list_keys = {"k": (4, 4)}

    def _validate(self):
        super()._validate()
        if self.params["xi"] < 0:
            raise CameraError("mei: 'xi' must be >= 0")
        k1, k2 = self.params["k"][:2]
        # r_max: where r (1 + k1 r^2 + k2 r^4) stops increasing (roots of 1 + 3 k1 q + 5 k2 q^2, q = r^2)
        q = np.roots([5 * k2, 3 * k1, 1.0]) if k2 != 0 else (np.array([-1 / (3 * k1)]) if k1 != 0 else np.array([]))
        q = q.real[(np.abs(q.imag) < 1e-12) & (q.real > 0)]
        r2_max = float(q.min()) if len(q) else math.inf
        self.r2_radial = r2_max  # the radial part's own limit (the start of the inverse's search)
        if any(self.params["k"][2:]):  # tangential terms: the distortion folds where its Jacobian's
            # determinant first reaches 0 along some direction; keep to the disc inside (1e-3 margin)
            r_hi = math.sqrt(r2_max) if math.isfinite(r2_max) else 1e3
            r = np.linspace(0, r_hi, 4001)[1:, None]
            a = np.linspace(0, 2 * math.pi, 721)[None, :]
            det = self._jacobian_det(r * np.cos(a), r * np.sin(a))
            bad = (det <= 0).any(axis=1)
            if bad.any():
                r2_max = min(r2_max, float(r[np.argmax(bad) - 1, 0]) ** 2 * 0.999)
        xi = self.params["xi"]
        if xi > 1:  # the lift needs 1 + (1 - xi^2) r^2 >= 0
            r2_max = min(r2_max, 1 / (xi * xi - 1))
        self.r2_max = r2_max

    def _jacobian_det(self, x, y):
        k1, k2, p1, p2 = self.params["k"]
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2 * r2
        dradial = 2 * k1 + 4 * k2 * r2
        j11 = radial + x * dradial * x + 2 * p1 * y + 6 * p2 * x
        j12 = x * dradial * y + 2 * p1 * x + 2 * p2 * y
        j22 = radial + y * dradial * y + 6 * p1 * y + 2 * p2 * x
        return j11 * j22 - j12 * j12

    def _scaled_params(self, sx, sy):
        d = super()._scaled_params(sx, sy)
        d["s"] *= sx
        return d

    def _distort(self, x, y):
        return _radtan_t(x, y, *self.params["k"])

    def _project(self, p):
        x, y, z = p.unbind(-1)
        xi = self.xi
        d = torch.sqrt(x * x + y * y + z * z)
        den = z + xi * d
        limit = xi if xi <= 1 else 1 / xi
        ok = den > 0
        den = torch.where(ok, den, torch.ones_like(den))
        mx, my = x / den, y / den
        valid = ok & (z > -limit * d) & (mx * mx + my * my < self.r2_max)
        xd, yd = self._distort(mx, my)
        return torch.stack([self.fx * xd + self.s * yd + self.cx, self.fy * yd + self.cy], -1), valid

    def _undistort(self, xd, yd):
        k1, k2, p1, p2 = self.params["k"]

        def residual_and_jacobian(x, y):
            r2 = x * x + y * y
            radial = 1 + k1 * r2 + k2 * r2 * r2
            dradial = 2 * k1 + 4 * k2 * r2  # d radial / d x = dradial * x
            fx_, fy_ = _radtan_t(x, y, k1, k2, p1, p2)
            j11 = radial + x * dradial * x + 2 * p1 * y + 6 * p2 * x
            j12 = x * dradial * y + 2 * p1 * x + 2 * p2 * y
            j21 = y * dradial * x + 2 * p1 * x + 2 * p2 * y
            j22 = radial + y * dradial * y + 6 * p1 * y + 2 * p2 * x
            return fx_ - xd_, fy_ - yd_, j11, j12, j21, j22

        def newton(x, y):
            ex, ey, a, b, c, d = residual_and_jacobian(x, y)
            det = a * d - b * c
            det = torch.where(det.abs() > _EPS, det, torch.ones_like(det))
            return x - (d * ex - b * ey) / det, y - (-c * ex + a * ey) / det

        with torch.no_grad():
            xd_, yd_ = xd.detach(), yd.detach()
            # start from the radial part's exact inverse (monotonic in r below r_max), then Newton in 2-D
            rd = torch.sqrt(xd_ * xd_ + yd_ * yd_)
            c = torch.tensor([1.0, 0.0, k1, 0.0, k2], dtype=rd.dtype)
            r2_hi = min(self.r2_radial, self.r2_max)
            r_hi = math.sqrt(r2_hi) if math.isfinite(r2_hi) else 1e6
            p = _Poly(c)
            ru = _invert_monotonic(p, p.deriv, rd, r_hi, rd)
            scale = _safe_div(ru, rd) + (rd <= _EPS).to(rd.dtype)
            x, y = xd_ * scale, yd_ * scale
            for _ in range(100):
                nx, ny = newton(x, y)
                nx, ny = torch.nan_to_num(nx), torch.nan_to_num(ny)
                if math.isfinite(r2_hi):  # stay on the disc where the distortion is one-to-one
                    shrink = torch.clamp(r_hi / torch.sqrt(nx * nx + ny * ny).clamp(min=_EPS), max=1.0)
                    nx, ny = nx * shrink, ny * shrink
                delta = torch.maximum((nx - x).abs(), (ny - y).abs()).max() if x.numel() else torch.tensor(0.0)
                x, y = nx, ny
                if delta < SOLVE_TOL * 1e-2:
                    break
        xd_, yd_ = xd, yd  # the last step with gradients: the implicit-function derivative
        x, y = newton(x, y)
        ex, ey = _radtan_t(x.detach(), y.detach(), k1, k2, p1, p2)
        tol = 1e-9 * torch.clamp(torch.maximum(xd.detach().abs(), yd.detach().abs()), min=1.0)
        converged = ((ex - xd.detach()).abs() < tol) & ((ey - yd.detach()).abs() < tol)
        return x, y, converged

    def _unproject(self, uv):
        yd = (uv[..., 1] - self.cy) / self.fy
        xd = (uv[..., 0] - self.cx - self.s * yd) / self.fx
        mx, my, converged = self._undistort(xd, yd)
        r2 = mx * mx + my * my
        xi = self.xi
        valid = converged & (r2 < self.r2_max)
        root = torch.sqrt((1 + (1 - xi * xi) * r2).clamp(min=0))
        f = (xi + root) / (r2 + 1)
        rays = torch.stack([f * mx, f * my, f - xi], -1)
        return rays / rays.norm(dim=-1, keepdim=True), valid


# ---------------------------------------------------------------- cylindrical


class Cylindrical(Camera):
    """u = fx atan2(x, z) + cx, v = fy y / sqrt(x^2 + z^2) + cy; azimuth within (-pi, pi)."""

    model, keys = "cylindrical", ("fx", "fy", "cx", "cy")

    def _project(self, p):
        x, y, z = p.unbind(-1)
        rho = torch.sqrt(x * x + z * z)
        valid = rho > 0
        phi = torch.atan2(x, z)
        return self._to_pixels(phi, _safe_div(y, rho)), valid

    def _unproject(self, uv):
        phi, t = self._normalised(uv)
        rays = torch.stack([torch.sin(phi), t, torch.cos(phi)], -1)
        return rays / torch.sqrt(1 + t * t)[..., None], phi.abs() < math.pi


# ---------------------------------------------------------------- registry

MODELS: dict[str, type[Camera]] = {
    c.model: c
    for c in (
        Pinhole,
        Equidistant,
        Equisolid,
        Stereographic,
        KBTheta,
        RadialPoly,
        OpenCVFisheye,
        UCM,
        EUCM,
        DoubleSphere,
        Mei,
        Cylindrical,
    )
}


def camera_from_dict(d: dict) -> Camera:
    """A camera from a calibration dictionary: `model`, `width`, `height` and the model's keys."""
    if not isinstance(d, dict):
        raise CameraError(f"camera must be a mapping, got {type(d).__name__}")
    d = dict(d)
    name = d.pop("model", None)
    if name is None:
        raise CameraError("missing key 'model'")
    if name not in MODELS:
        raise CameraError(f"unknown model '{name}' (one of: {', '.join(MODELS)})")
    for k in ("width", "height"):
        if k not in d:
            raise CameraError(f"{name}: missing key '{k}'")
        try:
            whole = float(d[k]).is_integer()
        except (TypeError, ValueError):
            whole = False
        if not whole:
            raise CameraError(f"{name}: '{k}' must be a whole number of pixels")
    return MODELS[name](**d)
