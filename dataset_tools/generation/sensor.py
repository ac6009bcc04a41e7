"""The camera behind the lens: what a real automotive fisheye camera does to the light the renderer
computes, applied to the 8-bit camera image (`cam_<name>.png`; the EXR's R, G, B stay the scene light).

Each effect has a switch (`render.sensor.<effect>` in a dataset config) and a seeded distribution,
drawn once per frame and camera from the frame's seed (so a frame renders to the same bytes again):

| effect | what | distribution |
|---|---|---|
| exposure | auto-exposure: the image's log-average luminance brought to 0.18 (gain 0.5-4x), then an error in stops | error normal, sd 0.2 (clipped to +-0.5) |
| white_balance | red and blue gains against green | normal around 1, sd 0.03 each |
| vignetting | light falloff, 1 - s (theta / theta_max)^2 by ray angle | s uniform 0.2-0.45 |
| chromatic_aberration | lateral: red and blue scaled about the principal point | +-k, k uniform 0.0005-0.002 |
| sharpen | the camera's edge enhancement (unsharp mask, radius 1 px) | amount uniform 0.2-0.6 |
| noise | shot and read noise, in linear light, amplified with the exposure gain (grainy at night) | shot gain uniform 0.0005-0.002, read sd uniform 0.001-0.003 |
| jpeg | JPEG compression of the stream | quality uniform 70-95 (off unless asked) |

The geometry (ray angles, principal point) comes from the camera model (`geometry`), so a camera
with another model gets its own falloff; the green channel is never moved.
"""

from __future__ import annotations

import numpy as np

from common.schema import Bool, Section

EFFECTS = ("exposure", "white_balance", "vignetting", "chromatic_aberration", "sharpen", "noise", "jpeg")
SENSOR = Section({e: Bool(default=e != "jpeg") for e in EFFECTS})
OFF = {e: False for e in EFFECTS}


def draw(switches: dict, rng: np.random.Generator) -> dict:
    """One camera's parameters for one frame (a fixed number of draws whatever is switched on, so
    turning one effect off leaves the others' values unchanged)."""
    u = rng.random(9)
    z = rng.standard_normal(3)
    p = {
        "exposure_ev": float(np.clip(0.2 * z[0], -0.5, 0.5)),
        "wb_gains": [float(1 + 0.03 * z[1]), 1.0, float(1 + 0.03 * z[2])],
        "vignetting": float(0.2 + 0.25 * u[0]),
        "chromatic_aberration": float((0.0005 + 0.0015 * u[1]) * (1 if u[2] < 0.5 else -1)),
        "sharpen": float(0.2 + 0.4 * u[3]),
        "shot_gain": float(0.0005 + 0.0015 * u[4]),
        "read_sd": float(0.001 + 0.002 * u[5]),
        "jpeg_quality": int(70 + 25 * u[6]),
        "noise_seed": int(u[7] * 2**31),
    }
    keep = {"exposure": ["exposure_ev"], "white_balance": ["wb_gains"], "vignetting": ["vignetting"],
            "chromatic_aberration": ["chromatic_aberration"], "sharpen": ["sharpen"],
            "noise": ["shot_gain", "read_sd", "noise_seed"], "jpeg": ["jpeg_quality"]}
    return {k: p[k] for e, ks in keep.items() if switches.get(e) for k in ks}


def camera_geometry(camera) -> tuple[np.ndarray, tuple[float, float]]:
    """(H, W) ray angle from the optical axis (radians, NaN outside the model's field) and the
    principal point (u, v) in pixels, from the camera model."""
    rays, valid = camera.unproject(camera.pixel_grid().numpy())
    rays = np.asarray(rays, np.float64)
    theta = np.arccos(np.clip(rays[..., 2] / np.linalg.norm(rays, axis=-1), -1, 1))
    theta[~np.asarray(valid, bool)] = np.nan
    uv, _ = camera.project(np.array([[0.0, 0.0, 1.0]]))
    return theta.astype(np.float32), (float(uv[0, 0]), float(uv[0, 1]))


def _to_linear(x):
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def _to_srgb(x):
    x = np.clip(x, 0, 1)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def auto_exposure(lin: np.ndarray, key: float = 0.18, lo: float = 0.5, hi: float = 4.0) -> float:
    """The gain that brings the log-average luminance of a linear image to `key`, within [lo, hi]."""
    lum = lin @ np.array([0.2126, 0.7152, 0.0722], np.float32)
    return float(np.clip(key / np.exp(np.mean(np.log(lum + 1e-3))), lo, hi))


def apply(img: np.ndarray, params: dict, theta: np.ndarray, principal) -> np.ndarray:
    """The camera's image (H, W, 3 uint8) from the rendered one; `params` from `draw` (an empty
    dict returns the image unchanged)."""
    import cv2

    if not params:
        return img
    lin = _to_linear(img.astype(np.float32) / 255.0)
    g = 1.0
    if "exposure_ev" in params:
        g = auto_exposure(lin) * 2.0 ** params["exposure_ev"]
    lin = lin * (g * np.asarray(params.get("wb_gains", [1, 1, 1]), np.float32))
    if "vignetting" in params:
        t = np.nan_to_num(theta / np.nanmax(theta), nan=1.0)
        lin = lin * (1 - params["vignetting"] * t * t)[..., None]
    if "chromatic_aberration" in params:
        k = params["chromatic_aberration"]
        h, w = theta.shape
        cx, cy = principal
        v, u = np.mgrid[0:h, 0:w].astype(np.float32)
        for c, s in ((0, 1 + k), (2, 1 - k)):  # red outward, blue inward (or the reverse)
            lin[..., c] = cv2.remap(lin[..., c], (cx + (u - cx) / s).astype(np.float32),
                                    (cy + (v - cy) / s).astype(np.float32), cv2.INTER_LINEAR,
                                    borderMode=cv2.BORDER_REFLECT)
    if "sharpen" in params:
        blur = cv2.GaussianBlur(lin, (0, 0), 1.0)
        lin = lin + params["sharpen"] * (lin - blur)
    if "shot_gain" in params:
        rng = np.random.default_rng(params["noise_seed"])
        sd = np.sqrt(params["shot_gain"] * g * np.clip(lin, 0, None) + (params["read_sd"] * g) ** 2)
        lin = lin + sd * rng.standard_normal(lin.shape, dtype=np.float32)
    out = np.rint(_to_srgb(lin) * 255).astype(np.uint8)
    if "jpeg_quality" in params:
        ok, buf = cv2.imencode(".jpg", out[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, params["jpeg_quality"]])
        out = cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1].copy()
    return out
