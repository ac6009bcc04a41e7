"""The camera behind the lens: what a real automotive fisheye camera does to the light the renderer
computes, applied to the 8-bit camera image (`cam_<name>.png`; the EXR's R, G, B stay the scene light).

Each effect has a switch (`render.sensor.<effect>` in a dataset config) and a seeded distribution,
drawn once per frame and camera from the frame's seed (so a frame renders to the same bytes again):

| effect | what | distribution |
|---|---|---|
| exposure | auto-exposure: the scene's log-average luminance brought to 0.18 (beyond 4x daylight's exposure, the square root of what is missing: night stays darker than day) by the exposure time (0.1-33 ms), then by analog gain (1-8x), then an error in stops | error normal, sd 0.2 (clipped to +-0.5) |
| hdr | the high-dynamic-range sensor's local tone mapping: the image's large-scale log luminance above 0.18 compressed by a factor, its detail kept (what keeps a car lit by headlights, or a lamp, from clipping to white) | compression uniform 0.25-0.4 |
| white_balance | the auto white balance: red and blue gains that make the image's near-grey pixels grey on average (grey world over unsaturated, unclipped pixels; each gain within 0.75-1.33), times an error | error gains normal around 1, sd 0.03 each |
| vignetting | light falloff, 1 - s (theta / theta_max)^2 by ray angle | s uniform 0.2-0.45 |
| chromatic_aberration | lateral: red and blue scaled about the principal point | +-k, k uniform 0.0005-0.002 |
| sharpen | the camera's edge enhancement (unsharp mask, radius 1 px) | amount uniform 0.6-1.2 |
| noise | shot and read noise, in linear light, amplified by the analog gain (a longer exposure gathers more light, a gain only amplifies: grainy at night) | shot gain uniform 0.0001-0.0004 (a full well of 2,500-10,000 electrons), read sd uniform 0.0005-0.0015 |
| noise_reduction | the ISP's spatial noise reduction after the sensor: an edge-preserving (bilateral) filter in the 8-bit image's gamma, whose grey-level threshold is a multiple of the noise the analog gain gives a mid-grey (what a camera's ISP is tuned to per gain) | multiple uniform 1.5-3, over 1 px (5 x 5) |
| jpeg | JPEG compression of the stream | quality uniform 70-95 (off unless asked) |
| motion_blur | the ego's and the traffic's motion during the exposure, which the auto-exposure lengthens in the dark | the exposure's time (none drawn) |

Motion blur: every pixel's scene point (the render's position pass) is moved as the ego and the
vehicle it lies on move over the exposure (from the scene's own poses a little before and after the
frame, `motion_flow`), projected by the camera model at both ends, and the image is averaged along
that path. By day (under 1 ms) nothing moves a pixel; at night (15-33 ms) the road beside a car at
50 km/h smears by tens of pixels in the side cameras.

Exposure and the HDR tone mapping act on the scene's light, not on the 8-bit image: the renderer
meters its linear image (`meter`), compresses it (`local_tone`) and writes the PNG through its view
transform at that exposure (a night frame brought up 30-100x from 8 bits would band), then `apply`
adds the rest. Called on an 8-bit image alone, `apply` meters, scales and compresses that image
instead.

The local tone mapping is what an automotive HDR camera's ISP does (a 120 dB sensor shown on 8
bits): the log luminance is split into a base, smoothed with an edge-preserving (guided) filter
over 3 % of the image, and the detail around it; the base above the key (0.18) is scaled by the
drawn compression, the detail is left. Without it a car 4 m ahead in the ego's headlights, or a
tail lamp, sits 6-8 stops above a night street's mean and the view transform paints it flat white.

The geometry (ray angles, principal point) comes from the camera model (`geometry`), so a camera
with another model gets its own falloff; the green channel is never moved.
"""

from __future__ import annotations

import numpy as np

from common.schema import Bool, Section

EFFECTS = ("exposure", "hdr", "white_balance", "vignetting", "chromatic_aberration", "sharpen", "noise", "noise_reduction", "jpeg",
           "motion_blur")
EXPOSURE_MS = (0.1, 33.0)  # the auto-exposure's exposure times: 1 ms at a log-average of 0.18, 1/30 s at most
ANALOG_GAIN = (1.0, 8.0)  # the sensor's analog gain, raised only once the exposure is at its longest
KEY = 0.18  # the log-average luminance the auto-exposure aims at in daylight
DIM = 4.0  # scenes that need more than DIM x daylight's exposure get the square root of the rest: dusk and
# night stay darker than day (a camera that brought a night street to a day's grey would show a lit day)
# the unsharp mask's amount: 0.6-1.2 since 2026-12-06 (0.2-0.6 before left our edges softer than a
# real automotive camera's; docs/rendering.md, "Kept: a stronger edge enhancement")
SHARPEN = (0.6, 1.2)
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
        "sharpen": float(SHARPEN[0] + (SHARPEN[1] - SHARPEN[0]) * u[3]),
        "shot_gain": float(0.0001 + 0.0003 * u[4]),
        "read_sd": float(0.0005 + 0.001 * u[5]),
        "jpeg_quality": int(70 + 25 * u[6]),
        "noise_seed": int(u[7] * 2**31),
        "hdr_compression": float(0.25 + 0.15 * u[8]),
    }
    keep = {"exposure": ["exposure_ev"], "hdr": ["hdr_compression"], "white_balance": ["wb_gains"], "vignetting": ["vignetting"],
            "chromatic_aberration": ["chromatic_aberration"], "sharpen": ["sharpen"],
            "noise": ["shot_gain", "read_sd", "noise_seed"], "jpeg": ["jpeg_quality"]}
    out = {k: p[k] for e, ks in keep.items() if switches.get(e) for k in ks}
    nr = float(1.5 + 1.5 * rng.random())  # drawn after the rest: adding it left their values as they were
    if switches.get("noise_reduction") and switches.get("noise"):
        out["nr_strength"] = nr
    if switches.get("motion_blur"):
        out["motion_blur"] = True  # the exposure time follows from the light (apply), nothing drawn
    return out


def motion_flow(camera, cam_to_ego: np.ndarray, position: np.ndarray, instance: np.ndarray, motion: dict,
                step: int = 2) -> np.ndarray:
    """(H, W, 2) image velocity (pixels per second) of every pixel's scene point, from its positions
    at the start and end of `motion["dt"]` seconds centred on the frame: `position` (H, W, 3) world points, `instance`
    (H, W) their object ids; `motion["world_to_ego"]` the ego's world-to-ego matrices at both ends,
    `motion["instances"]` {id: [start, end]} world motions of moving objects (from their pose at the
    frame). Background (instance 0: sky) and points the camera model cannot project get 0. Computed
    on every `step`-th pixel in each direction and spread to its neighbours (a blur's path need not
    be exact to the pixel; a quarter of the projections)."""
    if step > 1:
        coarse = motion_flow(camera, cam_to_ego, position[::step, ::step], instance[::step, ::step], motion, 1)
        return np.repeat(np.repeat(coarse, step, 0), step, 1)[: instance.shape[0], : instance.shape[1]]
    h, w = instance.shape
    pts = np.concatenate([position.reshape(-1, 3).astype(np.float64), np.ones((h * w, 1))], 1)
    inst = instance.reshape(-1)
    cam_from_ego = np.linalg.inv(np.asarray(cam_to_ego, np.float64))
    ends, ok = [], inst != 0
    for k in (0, 1):
        p = pts.copy()
        for iid, m in motion["instances"].items():
            sel = inst == int(iid)
            if sel.any():
                p[sel] = p[sel] @ np.asarray(m[k], np.float64).T
        cam = p @ (cam_from_ego @ np.asarray(motion["world_to_ego"][k], np.float64)).T
        uv, valid = camera.project(cam[:, :3])
        ends.append(np.asarray(uv, np.float64))
        ok &= np.asarray(valid, bool) & (cam[:, 2] > 0.05)
    flow = np.where(ok[:, None], (ends[1] - ends[0]) / float(motion["dt"]), 0.0)
    return np.nan_to_num(flow).reshape(h, w, 2).astype(np.float32)


def _motion_blur(lin: np.ndarray, flow: np.ndarray) -> np.ndarray:
    """The image averaged along each pixel's path (flow: the displacement over the exposure)."""
    import cv2

    n = int(np.clip(np.ceil(np.abs(flow).max()), 2, 16))
    h, w = flow.shape[:2]
    v, u = np.mgrid[0:h, 0:w].astype(np.float32)
    acc = np.zeros_like(lin)
    for t in np.linspace(-0.5, 0.5, n, dtype=np.float32):
        acc += cv2.remap(lin, u + t * flow[..., 0], v + t * flow[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    return acc / n


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


def _srgb_slope(x: float) -> float:
    """The slope of `_to_srgb` at a linear value x above its linear toe."""
    return 1.055 / 2.4 * x ** (1 / 2.4 - 1)


def meter(lin: np.ndarray, params: dict) -> float:
    """The auto-exposure of a linear image: sets `params["exposure_ms"]` (with motion blur or
    exposure) and `params["analog_gain"]` (with exposure), and returns the gain the image is to be
    taken at (1 without the exposure effect): the exposure time in ms (1 ms brings a log-average of
    KEY to KEY) times the analog gain times the drawn error."""
    if not (params.get("motion_blur") or "exposure_ev" in params):
        return 1.0
    need = KEY / float(log_average(lin))
    g = need if need <= DIM else float(np.sqrt(DIM * need))
    t = float(np.clip(g, *EXPOSURE_MS))
    params["exposure_ms"] = round(t, 3)
    if "exposure_ev" not in params:
        return 1.0
    a = float(np.clip(g / t, *ANALOG_GAIN))
    params["analog_gain"] = round(a, 3)
    return t * a * 2.0 ** params["exposure_ev"]


LUMA = np.array([0.2126, 0.7152, 0.0722], np.float32)
HDR_RADIUS = 0.03  # the base layer's smoothing radius, a share of the image's larger side
HDR_EPS = 0.25  # the guided filter's edge threshold (variance of log2 luminance, stops squared)


def local_tone(lin: np.ndarray, compression: float) -> np.ndarray:
    """The HDR camera's local tone mapping of an exposed linear image (H, W, 3): each pixel scaled
    so that the base layer of its log2 luminance (a self-guided filter) above log2(KEY) is
    multiplied by `compression` (1: unchanged); colour ratios and the detail around the base kept."""
    import cv2

    y = np.log2(np.clip(lin, 0, None) @ LUMA + 1e-5).astype(np.float32)
    r = max(2, round(HDR_RADIUS * max(y.shape)))
    mean = lambda x: cv2.boxFilter(x, -1, (2 * r + 1, 2 * r + 1), borderType=cv2.BORDER_REFLECT)  # noqa: E731
    m = mean(y)
    a = np.clip(mean(y * y) - m * m, 0, None)
    a = a / (a + HDR_EPS)
    base = mean(a) * y + mean(m - a * m)
    over = np.maximum(base - np.log2(KEY), 0)
    return lin * np.exp2((compression - 1.0) * over)[..., None]


NR_DIAMETER, NR_SIGMA_PX = 5, 1.0  # the noise reduction's window (pixels) and its spatial sigma


def noise_sd_srgb(params: dict, grey: float = KEY) -> float:
    """The sensor noise's standard deviation at a mid-grey (`grey`, linear) in the 8-bit image's
    gamma (0-1): shot and read noise at the analog gain, through the sRGB curve's slope there (in
    that gamma the shot noise is nearly the same at every grey, which is what lets one threshold
    serve the whole image)."""
    a = params.get("analog_gain", 1.0)
    sd = np.sqrt(params["shot_gain"] * a * grey + (params["read_sd"] * a) ** 2)
    return float(sd * _srgb_slope(grey))


AWB_GAINS = (0.75, 1.33)  # the auto white balance's range of red and blue gains


def grey_world(lin: np.ndarray) -> np.ndarray:
    """The auto white balance's gains (3,) for a linear image (H, W, 3): green over each channel's
    mean on the near-grey pixels (max - min under 30 % of max, neither black nor clipped), so that
    they come out grey on average; ones where fewer than 100 pixels qualify."""
    x = lin.reshape(-1, 3)
    mx, mn = x.max(1), x.min(1)
    ok = (mx > 0.01) & (mx < 0.9) & (mx - mn < 0.3 * mx)
    if ok.sum() < 100:
        return np.ones(3, np.float32)
    m = x[ok].mean(0)
    return np.clip(m[1] / np.maximum(m, 1e-6), *AWB_GAINS).astype(np.float32)


def log_average(lin: np.ndarray):
    """The log-average luminance of a linear image (what an auto-exposure meters)."""
    lum = lin @ LUMA
    return np.exp(np.mean(np.log(lum + 1e-4)))  # a float32 scalar; black (1e-4) weighs as 13 stops down


def apply(img: np.ndarray, params: dict, theta: np.ndarray, principal, flow: np.ndarray | None = None,
          exposed: bool = False) -> np.ndarray:
    """The camera's image (H, W, 3 uint8) from the rendered one; `params` from `draw` (an empty
    dict returns the image unchanged). `exposed`: the renderer already took `img` at `meter`'s gain
    (params hold its exposure_ms and analog_gain); otherwise `img` is metered and scaled here. With
    motion blur, `flow` is `motion_flow` (pixels per second) and the path is the exposure's
    (meta.json shows exposure_ms and analog_gain)."""
    import cv2

    if not params:
        return img
    lin = _to_linear(img.astype(np.float32) / 255.0)
    g = 1.0 if exposed else meter(lin, params)
    if params.get("motion_blur") and flow is not None:
        scaled = flow * (params["exposure_ms"] / 1000.0)
        if np.abs(scaled).max() >= 0.5:  # under half a pixel anywhere: nothing to see
            lin = _motion_blur(lin, scaled)
    lin = lin * g
    if "hdr_compression" in params and not exposed:  # the renderer compressed its light itself
        lin = local_tone(lin, params["hdr_compression"])
    if "wb_gains" in params:
        lin = lin * grey_world(lin) * np.asarray(params["wb_gains"], np.float32)
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
        a = params.get("analog_gain", 1.0)
        sd = np.sqrt(params["shot_gain"] * a * np.clip(lin, 0, None) + (params["read_sd"] * a) ** 2)
        lin = lin + sd * rng.standard_normal(lin.shape, dtype=np.float32)
    srgb = _to_srgb(lin).astype(np.float32)
    if "nr_strength" in params and "shot_gain" in params:
        srgb = cv2.bilateralFilter(srgb, NR_DIAMETER, params["nr_strength"] * noise_sd_srgb(params), NR_SIGMA_PX)
    out = np.rint(np.clip(srgb, 0, 1) * 255).astype(np.uint8)
    if "jpeg_quality" in params:
        ok, buf = cv2.imencode(".jpg", out[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, params["jpeg_quality"]])
        out = cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1].copy()
    return out
