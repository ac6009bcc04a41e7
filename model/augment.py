"""Image transforms that move the camera with the image, so the lift stays exact.

One view transform per camera image: a uniform scale s (pixel centres: u' = s (u + 0.5) - 0.5, as
geometry's `camera.scaled`), a rotation by `angle` degrees about the principal point, then a crop
of the output size at integer offset (x0, y0) (zero padding where the crop leaves the image).

Rotating the image about the principal point is a rotation of the camera frame about its optical
axis only when the model is radially symmetric with square pixels (fx == fy); `can_rotate` says
whether a camera qualifies (cylindrical, radial_poly with aspect_ratio != 1 and fx != fy cameras do
not) and the augmentation leaves the others unrotated.

Colour jitter is the paper's (brightness 0.3, contrast 0.5, saturation 0.3, hue 0.05), with kornia
(its hue step through OpenCV's HSV: `adjust_hue`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import torch

from geometry.rig import RigCamera

RADIAL_MODELS = {"pinhole", "equidistant", "equisolid", "stereographic", "kb_theta", "opencv_fisheye",
                 "radial_poly", "ucm", "eucm", "double_sphere"}


@dataclass(frozen=True)
class ViewTransform:
    scale: float
    angle: float  # degrees, counter-clockwise on screen
    x0: int
    y0: int
    size: tuple[int, int]  # output (W, H)


def can_rotate(camera) -> bool:
    d = camera.to_dict()
    if d["model"] not in RADIAL_MODELS:
        return False
    if d["model"] == "radial_poly":
        return abs(d["aspect_ratio"] - 1.0) < 1e-9
    return abs(d["fx"] - d["fy"]) <= 1e-9 * d["fx"]


def base_transform(camera, size) -> ViewTransform:
    """Resize to cover `size` keeping square pixels, centre crop (no augmentation)."""
    w, h = size
    s = max(w / camera.width, h / camera.height)
    x0 = int(math.floor((camera.width * s - w) / 2))
    y0 = int(math.floor((camera.height * s - h) / 2))
    return ViewTransform(s, 0.0, x0, y0, (int(w), int(h)))


def random_transform(camera, size, rng: np.random.Generator, scale=(1.0, 1.0), rotation_deg: float = 0.0,
                     crop: bool = False) -> ViewTransform:
    """The base transform with a random extra scale, rotation (when exact) and crop offset."""
    w, h = size
    base = base_transform(camera, size)
    s = base.scale * float(rng.uniform(scale[0], scale[1]))
    angle = float(rng.uniform(-rotation_deg, rotation_deg)) if rotation_deg > 0 and can_rotate(camera) else 0.0
    sw, sh = camera.width * s, camera.height * s
    if crop:
        x0 = int(rng.integers(int(math.floor(min(0, sw - w))), int(math.floor(max(0, sw - w))) + 1))
        y0 = int(rng.integers(int(math.floor(min(0, sh - h))), int(math.floor(max(0, sh - h))) + 1))
    else:
        x0, y0 = int(math.floor((sw - w) / 2)), int(math.floor((sh - h) / 2))
    return ViewTransform(s, angle, x0, y0, (int(w), int(h)))


def _rot_z(angle_deg: float) -> np.ndarray:
    a = math.radians(angle_deg)
    c, s = math.cos(a), math.sin(a)
    # image rotated counter-clockwise on screen (v down): (x', y') = (c x + s y, -s x + c y)
    return np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


def transform_camera(rc: RigCamera, t: ViewTransform) -> RigCamera:
    """The rig camera of the transformed image."""
    cam = rc.camera.scaled(t.scale)
    cam_to_ego = rc.cam_to_ego.copy()
    if t.angle:
        if not can_rotate(rc.camera):
            raise ValueError(f"camera {rc.name}: a {rc.camera.model} camera cannot be rotated exactly")
        cam_to_ego[:3, :3] = cam_to_ego[:3, :3] @ _rot_z(t.angle).T
    return RigCamera(rc.name, cam.cropped(t.x0, t.y0, *t.size), cam_to_ego)


def view_matrix(camera, t: ViewTransform) -> np.ndarray:
    """3x3 affine map of pixel positions, `camera`'s image -> the transformed image (what
    warp_image applies): scale u' = s (u + 0.5) - 0.5, rotation about the scaled principal point, crop."""
    s = t.scale
    a = np.array([[s, 0.0, (s - 1) * 0.5], [0.0, s, (s - 1) * 0.5], [0.0, 0.0, 1.0]])
    if t.angle:
        cs = camera.scaled(s)
        a = np.vstack([cv2.getRotationMatrix2D((cs.cx, cs.cy), t.angle, 1.0), [0, 0, 1]]) @ a
    a[0, 2] -= t.x0
    a[1, 2] -= t.y0
    return a


def move_pixels(a: np.ndarray, u, v):
    """Pixel positions (u, v) through the affine map `a` (3x3, or (..., 3, 3) broadcast against u and
    v: one map per camera): a view_matrix or its inverse."""
    a = np.asarray(a)
    return a[..., 0, 0] * u + a[..., 0, 1] * v + a[..., 0, 2], a[..., 1, 0] * u + a[..., 1, 1] * v + a[..., 1, 2]


def warp_image(image: np.ndarray, camera, t: ViewTransform) -> np.ndarray:
    """(H, W, 3) uint8 image of `camera` -> the transformed (t.size) image."""
    s = t.scale
    interp = cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR
    if t.angle == 0.0:
        # cv2.resize with fx=fy=s maps pixel centres as u' = s (u + 0.5) - 0.5, like camera.scaled
        img = cv2.resize(image, None, fx=s, fy=s, interpolation=interp)
        w, h = t.size
        out = np.zeros((h, w, 3), np.uint8)
        xs, ys = max(t.x0, 0), max(t.y0, 0)
        xe, ye = min(t.x0 + w, img.shape[1]), min(t.y0 + h, img.shape[0])
        if xe > xs and ye > ys:
            out[ys - t.y0 : ye - t.y0, xs - t.x0 : xe - t.x0] = img[ys:ye, xs:xe]
        return out
    if s < 1:  # anti-alias before the bilinear warp
        image = cv2.resize(image, None, fx=s, fy=s, interpolation=cv2.INTER_AREA)
        pre = s
    else:
        pre = 1.0
    # remaining map, source (after pre-scale) -> output pixel centres
    cs = camera.scaled(s)
    m = cv2.getRotationMatrix2D((cs.cx, cs.cy), t.angle, 1.0)  # rotation about the scaled principal point
    r = s / pre
    a = np.array([[r, 0, (r - 1) * 0.5], [0, r, (r - 1) * 0.5], [0, 0, 1.0]])  # u' = r (u + 0.5) - 0.5
    full = np.vstack([m, [0, 0, 1]]) @ a
    full[0, 2] -= t.x0
    full[1, 2] -= t.y0
    return cv2.warpAffine(image, full[:2], t.size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def adjust_hue(images: torch.Tensor, radians: torch.Tensor) -> torch.Tensor:
    """kornia.enhance.adjust_hue of (N, 3, H, W) float32 RGB in [0, 1] on the CPU, each image's hue
    turned by its angle (`radians`: (N,) or one), through OpenCV's HSV conversion: the same HSV
    (equal to 2e-6) at a seventh of kornia's time, which was a third of the paper configuration's
    loading of a sample (docs/benchmarks.md, "The paper configuration on one GPU"). Other tensors
    go to kornia's."""
    from kornia.enhance import adjust_hue as kornia_hue

    if images.device.type != "cpu" or images.dtype != torch.float32 or images.ndim != 4 or images.shape[1] != 3:
        return kornia_hue(images, radians)
    n = images.shape[0]
    degrees = torch.as_tensor(radians, dtype=torch.float64).reshape(-1).expand(n).rad2deg().numpy()
    x = images.permute(0, 2, 3, 1).contiguous().numpy()
    out = np.empty_like(x)
    for i in range(n):
        hsv = cv2.cvtColor(x[i], cv2.COLOR_RGB2HSV)  # H in degrees [0, 360)
        hsv[..., 0] = np.mod(hsv[..., 0] + np.float32(degrees[i]), np.float32(360.0))
        out[i] = cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)
    return torch.from_numpy(out).permute(0, 3, 1, 2)


class ColorJitter:
    """The paper's colour jitter on (N, 3, H, W) float images in [0, 1], one draw per image:
    kornia's ColorJitter (its draws, order and clamping), its hue step through `adjust_hue`."""

    def __init__(self, brightness=0.3, contrast=0.5, saturation=0.3, hue=0.05):
        import kornia.augmentation as K

        self.op = K.ColorJitter(brightness, contrast, saturation, hue, p=1.0)
        if hasattr(self.op, "_hue_fn"):  # kornia 0.8+: the step's function is an attribute
            self.op._hue_fn = adjust_hue

    def __call__(self, images: torch.Tensor) -> torch.Tensor:
        return self.op(images).clamp(0, 1)

    def draw(self, n: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
        """The draws of this jitter on `n` images under torch seed `seed`, as `__call__` would make
        them: (factors (n, 4): brightness, contrast, saturation, hue; order of the steps (4,))."""
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            p = self.op.forward_parameters(torch.Size((n, 3, 1, 1)))
        keys = ("brightness_factor", "contrast_factor", "saturation_factor", "hue_factor")
        return torch.stack([p[k].float() for k in keys], 1), p["order"].long()

    def apply(self, images: torch.Tensor, factors: torch.Tensor, order: torch.Tensor) -> torch.Tensor:
        """Samples jittered with their own draws (`draw`), on any device: `images` (S, N, 3, H, W)
        in [0, 1], `factors` (S, N, 4), `order` (S, 4). Each sample's images come out as `__call__`
        makes them under the same seed (the same kornia steps, in each sample's order); a batch of
        them in one call, so that the jitter can run on a GPU after the loader instead of in its
        workers (the jitter was 40 % of a paper sample's loading on the H200)."""
        s, n = images.shape[:2]
        x = images.flatten(0, 1).clamp(0, 1)
        f = factors.reshape(s * n, 4).to(x.device)
        o = order.to(x.device).repeat_interleave(n, 0)  # (S * N, 4): each image its sample's order
        steps = (self.op._brightness_fn, self.op._contrast_fn, self.op._saturation_fn, self.op._adjust_hue_turns)
        for place in range(4):
            for k, step in enumerate(steps):
                sel = (o[:, place] == k).nonzero().squeeze(1)
                if len(sel) == len(x):
                    x = step(x, f[:, k])
                elif len(sel):
                    x = x.index_copy(0, sel, step(x[sel], f[sel, k]))
        return x.clamp(0, 1).view(images.shape)
