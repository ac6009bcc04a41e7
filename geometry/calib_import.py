"""Calibrations other tools write, as our cameras (docs/geometry.md, "Importing calibrations").

    cam = opencv_fisheye_camera("front.yaml")              # cv2.fisheye K, D: exact (opencv_fisheye);
                                                           # cv2.omnidir K, D, xi: exact (mei)
    cams = kalibr_cameras("camchain.yaml")                 # name -> Imported (camera, T_cam_imu, residual)
    imp = ocamcalib_camera("calib_results.txt")            # Scaramuzza's polynomial: fitted, residual in px
    imp = import_calibration(path, fmt=None)               # any of these, format guessed from the file

Each importer returns an `Imported`: the camera, the source's own pose if it has one (`cam_to_ref`,
4x4, camera -> the file's reference frame: Kalibr's IMU, WoodScape's vehicle), and `residual_px`,
the largest distance in pixels between the source model and ours over the source's whole valid field
of view (0 where the models coincide exactly; `fitted` says which). Bad input is a
`CalibrationError` naming the file and the field: among others a principal point (or OCamCalib
centre) outside the image, an image size beyond MAX_IMAGE_SIDE, a pose that is not a rotation.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from common.errors import InputError
from common.files import SafeYamlLoader, read_json, read_text, read_yaml

from .cameras import Camera, CameraError, camera_from_dict


class CalibrationError(InputError):
    """A calibration file that cannot make a camera (names the file and the field)."""


@dataclass
class Imported:
    camera: Camera
    cam_to_ref: np.ndarray | None = None  # (4, 4) camera -> the file's reference frame, if it has one
    residual_px: float = 0.0  # max |source pixel - our pixel| over the source's valid field of view; 0: exact
    source: str = ""
    fitted: bool = False  # True: our camera is a fit of the source model (residual_px says how close)

    def describe(self) -> str:
        """What the calibration became, in a few words (printed by the commands that load a rig)."""
        how = f"fitted, residual {self.residual_px:.3g} px over its field of view" if self.fitted else "exact"
        return f"{self.camera.model} ({how})"


MAX_IMAGE_SIDE = 100_000  # pixels: a calibration's width or height beyond this is refused
MAX_SAMPLES = 250_000  # pixels a fit samples at most (the step grows with the image)


FORMATS = ("opencv_fisheye", "kalibr", "ocamcalib", "woodscape")
MAX_CALIBRATION_BYTES = 4 * 1024 * 1024  # as common.files.MAX_YAML_BYTES


# ---------------------------------------------------------------- OpenCV FileStorage


def _numbers(v, source, field, n=None) -> np.ndarray:
    try:
        a = np.asarray(v, dtype=np.float64).ravel()
    except (TypeError, ValueError):
        raise CalibrationError(f"{source}: {field}: must be numbers, got {str(v)[:60]!r}") from None
    if n is not None and a.size != n:
        raise CalibrationError(f"{source}: {field}: must have {n} numbers, has {a.size}")
    if not np.all(np.isfinite(a)):
        raise CalibrationError(f"{source}: {field}: must be finite")
    return a


def _opencv_matrix(node, source, field) -> np.ndarray:
    """An `opencv-matrix` node (YAML tag or JSON type_id) or a plain list, as a 2-D array."""
    if isinstance(node, dict) and "data" in node:
        data = _numbers(node["data"], source, f"{field}.data")
        try:
            rows, cols = node["rows"], node["cols"]
            whole = all(float(v).is_integer() and float(v) >= 1 for v in (rows, cols))
        except (KeyError, TypeError, ValueError):
            whole = False
        if not whole:
            raise CalibrationError(f"{source}: {field}: needs whole 'rows' and 'cols' >= 1, got "
                                   f"{str(node.get('rows'))[:20]} x {str(node.get('cols'))[:20]}")
        rows, cols = int(float(rows)), int(float(cols))
        if rows * cols != data.size:
            raise CalibrationError(f"{source}: {field}: rows x cols = {rows * cols}, but data has {data.size} numbers")
        return data.reshape(rows, cols)
    return np.atleast_2d(_numbers(node, source, field))


def read_opencv_storage(path) -> dict:
    """A file of OpenCV's FileStorage (YAML with `%YAML:1.0` and `!!opencv-matrix`, or JSON) as a dict
    whose matrices are numpy arrays."""
    import yaml

    path = Path(path)
    if path.suffix.lower() == ".json":
        read_text(path, CalibrationError, MAX_CALIBRATION_BYTES)  # size first
        d = read_json(path, CalibrationError)
    else:
        class _Loader(SafeYamlLoader):  # common.files' limits (no aliases, nesting) plus OpenCV's tags
            pass

        def matrix(loader, node):
            return {"__opencv_matrix__": True, **loader.construct_mapping(node, deep=True)}

        _Loader.add_constructor("tag:yaml.org,2002:opencv-matrix", matrix)
        _Loader.add_multi_constructor("tag:yaml.org,2002:", lambda loader, suffix, node: loader.construct_mapping(node, deep=True)
                                      if isinstance(node, yaml.MappingNode) else loader.construct_scalar(node))
        # OpenCV writes a YAML 1.0 directive PyYAML refuses
        d = read_yaml(path, CalibrationError, _Loader, lambda text: re.sub(r"^%YAML[: ]1\.\d\s*\n", "", text))
    if not isinstance(d, dict):
        raise CalibrationError(f"{path}: expected a mapping of named nodes")
    return {k: (_opencv_matrix(v, path, k) if isinstance(v, dict) and ("__opencv_matrix__" in v or v.get("type_id") == "opencv-matrix") else v)
            for k, v in d.items()}


def _first(d: dict, keys, source, what):
    for k in keys:
        if k in d:
            return k, d[k]
    raise CalibrationError(f"{source}: missing {what} (one of: {', '.join(keys)})")


def image_size(width, height, source, field="image size") -> tuple[int, int]:
    """(width, height) of a calibration: whole numbers of pixels in [1, MAX_IMAGE_SIDE]."""
    try:
        ok = all(float(v).is_integer() and 1 <= float(v) <= MAX_IMAGE_SIDE for v in (width, height))
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise CalibrationError(f"{source}: {field}: must be whole numbers of pixels in [1, {MAX_IMAGE_SIDE}], got {width} x {height}")
    return int(float(width)), int(float(height))


def check_principal_point(cx: float, cy: float, width: int, height: int, source, field="principal point") -> None:
    """A principal point (or OCamCalib centre) outside the image is a typing slip (a lost decimal point,
    a resolution that lost a digit): nothing measured would use it. Refused."""
    if not (-0.5 <= cx <= width - 0.5 and -0.5 <= cy <= height - 0.5):
        raise CalibrationError(f"{source}: {field}: ({cx:g}, {cy:g}) is outside the {width}x{height} image")


def opencv_fisheye_dict(K, D, width: int, height: int, source="opencv", field="K") -> dict:
    """cv2.fisheye's K (3x3) and D (4) as our `opencv_fisheye` camera dict (the same model: exact)."""
    K = np.asarray(K, dtype=np.float64).reshape(3, 3)
    D = np.asarray(D, dtype=np.float64).ravel()
    if D.size != 4:
        raise CalibrationError(f"{source}: D: cv2.fisheye has 4 coefficients k1..k4, got {D.size}")
    if abs(K[0, 1]) > 1e-9 * abs(K[0, 0]):
        raise CalibrationError(f"{source}: {field}: skew K[0][1] = {K[0, 1]} (cv2.fisheye alpha) is not supported")
    _check_camera_matrix(K, source, field)
    check_principal_point(K[0, 2], K[1, 2], width, height, source, f"{field} (cx, cy)")
    return {"model": "opencv_fisheye", "width": int(width), "height": int(height), "fx": float(K[0, 0]), "fy": float(K[1, 1]),
            "cx": float(K[0, 2]), "cy": float(K[1, 2]), "k": [float(v) for v in D]}


def _check_camera_matrix(K, source, field):
    if not np.allclose(K[2], [0, 0, 1]) or K[1, 0] != 0:
        raise CalibrationError(f"{source}: {field}: not a camera matrix [[fx, s, cx], [0, fy, cy], [0, 0, 1]]")


def omnidir_dict(K, D, xi: float, width: int, height: int, source="opencv", field="K") -> dict:
    """cv2.omnidir's K (3x3, with its skew s = K[0][1]), D (k1, k2, p1, p2) and xi as our `mei`
    camera dict (the same model: exact)."""
    K = np.asarray(K, dtype=np.float64).reshape(3, 3)
    D = np.asarray(D, dtype=np.float64).ravel()
    if D.size != 4:
        raise CalibrationError(f"{source}: D: cv2.omnidir has 4 coefficients k1, k2, p1, p2, got {D.size}")
    _check_camera_matrix(K, source, field)
    check_principal_point(K[0, 2], K[1, 2], width, height, source, f"{field} (cx, cy)")
    return {"model": "mei", "width": int(width), "height": int(height), "fx": float(K[0, 0]), "fy": float(K[1, 1]),
            "cx": float(K[0, 2]), "cy": float(K[1, 2]), "s": float(K[0, 1]), "xi": float(xi), "k": [float(v) for v in D]}


def opencv_fisheye_camera(path, width: int | None = None, height: int | None = None) -> Camera:
    """A cv2.fisheye calibration in a FileStorage file: K (`K`, `camera_matrix`), D (`D`,
    `dist_coeffs`, `distortion_coefficients`) and the image size (`resolution`/`image_size` [w, h],
    or `image_width` and `image_height`, or the arguments). A file that also holds `xi` is
    cv2.omnidir's (Mei's model): it becomes a `mei` camera, exactly."""
    d = read_opencv_storage(path)
    kk, K = _first(d, ("K", "camera_matrix", "cameraMatrix"), path, "the camera matrix")
    dk, D = _first(d, ("D", "dist_coeffs", "distortion_coefficients", "distCoeffs"), path, "the distortion coefficients")
    K = _opencv_matrix(K, path, kk)
    if K.size != 9:
        raise CalibrationError(f"{path}: {kk}: must be 3x3, is {K.shape[0]}x{K.shape[1]}")
    D = _opencv_matrix(D, path, dk)
    if width is None or height is None:
        if "image_width" in d and "image_height" in d:
            size = _numbers([d["image_width"], d["image_height"]], path, "image_width/image_height", 2)
            sk = "image_width/image_height"
        else:
            sk, size = _first(d, ("resolution", "image_size", "imageSize"), path, "the image size")
            size = _numbers(np.asarray(size, dtype=object).tolist() if not isinstance(size, np.ndarray) else size, path, sk, 2)
        width, height = image_size(size[0], size[1], path, sk)
    try:
        if "xi" in d:
            xi = _numbers(d["xi"].tolist() if isinstance(d["xi"], np.ndarray) else d["xi"], path, "xi", 1)[0]
            return camera_from_dict(omnidir_dict(K, D.ravel(), xi, width, height, path, kk))
        return camera_from_dict(opencv_fisheye_dict(K, D.ravel(), width, height, path, kk))
    except CameraError as exc:
        raise CalibrationError(f"{path}: {exc}") from None


def opencv_fisheye_yaml(camera: Camera) -> str:
    """An `opencv_fisheye` camera as the FileStorage YAML cv2 reads (`K`, `D`, `image_width`,
    `image_height`): the way back to cv2.fisheye (numbers written with 17 significant digits: exact)."""
    if camera.model != "opencv_fisheye":
        raise CalibrationError(f"{camera.model}: only an opencv_fisheye camera is cv2.fisheye's model")

    def matrix(name, rows, cols, data):
        return (f"{name}: !!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: d\n"
                f"   data: [ {', '.join(repr(float(v)) for v in data)} ]\n")

    p = camera.params
    k = [p["fx"], 0.0, p["cx"], 0.0, p["fy"], p["cy"], 0.0, 0.0, 1.0]
    return ("%YAML:1.0\n---\n" + matrix("K", 3, 3, k) + matrix("D", 4, 1, p["k"])
            + f"image_width: {camera.width}\nimage_height: {camera.height}\n")


# ---------------------------------------------------------------- fitting a source model we do not have


def _sample_pixels(width: int, height: int, step: int = 8) -> np.ndarray:
    """Pixel centres every `step` pixels, the last row and column included; the step grows so that
    at most about MAX_SAMPLES pixels are taken, whatever the image size."""
    step = max(int(step), math.ceil(math.sqrt(width * height / MAX_SAMPLES)))
    u = np.unique(np.append(np.arange(0, width, step, dtype=np.float64), width - 1.0))
    v = np.unique(np.append(np.arange(0, height, step, dtype=np.float64), height - 1.0))
    uu, vv = np.meshgrid(u, v)
    return np.stack([uu.ravel(), vv.ravel()], -1)


def fit_opencv_fisheye(uv: np.ndarray, rays: np.ndarray, width: int, height: int, fx: float, fy: float, cx: float, cy: float):
    """The `opencv_fisheye` camera (fx, fy, cx, cy given) whose k1..k4 best map `rays` to `uv` (linear
    least squares in theta_d / theta), and the largest pixel distance between its projection and uv."""
    rays = rays / np.linalg.norm(rays, axis=-1, keepdims=True)
    theta = np.arctan2(np.linalg.norm(rays[:, :2], axis=-1), rays[:, 2])
    rd = np.hypot((uv[:, 0] - cx) / fx, (uv[:, 1] - cy) / fy)
    keep = theta > 1e-6
    t = theta[keep]
    A = np.stack([t ** 3, t ** 5, t ** 7, t ** 9], -1)
    k, *_ = np.linalg.lstsq(A, rd[keep] - t, rcond=None)
    cam = camera_from_dict({"model": "opencv_fisheye", "width": width, "height": height, "fx": fx, "fy": fy, "cx": cx, "cy": cy,
                            "k": [float(x) for x in k]})
    return cam, _residual(cam, uv, rays)


def _residual(cam: Camera, uv: np.ndarray, rays: np.ndarray) -> float:
    back, valid = cam.project(rays)
    if not np.all(valid):
        return math.inf
    return float(np.max(np.linalg.norm(back - uv, axis=-1))) if len(uv) else 0.0


# ---------------------------------------------------------------- OCamCalib (Scaramuzza)


@dataclass
class OCamModel:
    """Scaramuzza's omnidirectional model as calib_results.txt stores it. Pixel (row, col) =
    A (xp, yp) + (xc, yc) with A = [[c, d], [e, 1]]; the ray of (xp, yp) is (xp, yp, pol(rho)),
    rho = |(xp, yp)|, in a frame whose z points backwards (pol < 0 in front of the lens)."""

    pol: np.ndarray
    invpol: np.ndarray
    xc: float  # row
    yc: float  # column
    c: float
    d: float
    e: float
    height: int
    width: int

    def _plane(self, uv: np.ndarray):
        row, col = uv[:, 1] - self.xc, uv[:, 0] - self.yc
        inv = 1.0 / (self.c - self.d * self.e)
        return inv * (row - self.d * col), inv * (-self.e * row + self.c * col)

    def cam2world(self, uv: np.ndarray) -> np.ndarray:
        """Our pixels (u = column, v = row) -> unit rays in our camera frame (x right, y down, z forward)."""
        xp, yp = self._plane(uv)
        zp = np.polynomial.polynomial.polyval(np.hypot(xp, yp), self.pol)
        rays = np.stack([yp, xp, -zp], -1)  # OCam (row, col, back) -> ours (right, down, forward)
        return rays / np.linalg.norm(rays, axis=-1, keepdims=True)

    def rho(self, uv: np.ndarray) -> np.ndarray:
        """The sensor-plane radius of pixels (after the affine part)."""
        return np.hypot(*self._plane(uv))

    def rho_max(self, rho_far: float) -> float:
        """The model's valid field of view as a radius: where the ray's angle from the axis,
        atan2(rho, -pol(rho)), stops increasing with rho (the polynomial folds back), at most rho_far."""
        r = np.linspace(0.0, rho_far, 20001)
        theta = np.arctan2(r, -np.polynomial.polynomial.polyval(r, self.pol))
        stops = np.nonzero(np.diff(theta) <= 0)[0]
        return float(r[stops[0]]) if len(stops) else float(rho_far) * (1 + 1e-9)


def _ocam_numbers(lines, i, source, field):
    try:
        vals = [float(x) for x in lines[i].split()]
    except (IndexError, ValueError):
        raise CalibrationError(f"{source}: {field}: expected a line of numbers") from None
    if not vals or not all(math.isfinite(v) for v in vals):
        raise CalibrationError(f"{source}: {field}: expected finite numbers")
    return vals


def read_ocamcalib(path) -> OCamModel:
    """calib_results.txt as the OCamCalib toolbox writes it: five blocks, each after a '#' comment:
    pol (length first), invpol (length first), center (row, column), affine c d e, size (height, width)."""
    path = Path(path)
    lines = [ln.strip() for ln in read_text(path, CalibrationError).splitlines()]
    lines = [ln for ln in lines if ln and not ln.startswith("#")]
    fields = ("pol", "invpol", "center", "affine", "image size")
    if len(lines) < 5:
        raise CalibrationError(f"{path}: {fields[len(lines)]}: missing (an OCamCalib calib_results.txt has 5 blocks)")
    blocks = {}
    for i, f in enumerate(fields):
        blocks[f] = _ocam_numbers(lines, i, path, f)
    for f in ("pol", "invpol"):
        n = blocks[f][0]
        if not float(n).is_integer() or n < 1 or len(blocks[f]) != n + 1:
            raise CalibrationError(f"{path}: {f}: the length {n:g} does not match the {len(blocks[f]) - 1} coefficients")
    for f, n in (("center", 2), ("affine", 3), ("image size", 2)):
        if len(blocks[f]) != n:
            raise CalibrationError(f"{path}: {f}: expected {n} numbers, got {len(blocks[f])}")
    h, w = blocks["image size"]
    w, h = image_size(w, h, path, "image size")
    h, w = float(h), float(w)
    check_principal_point(blocks["center"][1], blocks["center"][0], int(w), int(h), path, "center (row, column)")
    pol = np.asarray(blocks["pol"][1:])
    if pol[0] >= 0:
        raise CalibrationError(f"{path}: pol: the first coefficient a0 must be negative (the ray at the centre looks forward), got {pol[0]:g}")
    c, d, e = blocks["affine"]
    if abs(c - d * e) < 1e-12:
        raise CalibrationError(f"{path}: affine: c - d e must not be 0")
    return OCamModel(pol, np.asarray(blocks["invpol"][1:]), *blocks["center"], c, d, e, int(h), int(w))


def ocamcalib_camera(path, step: int = 8) -> Imported:
    """An OCamCalib calibration fitted by an `opencv_fisheye` camera: fx = fy = -a0 (the focal length at
    the centre), (cx, cy) = the centre, k1..k4 by least squares over the model's whole valid field of
    view (the image's pixels up to where the polynomial folds back); `residual_px` is the largest
    pixel distance between the two over that same field of view (the affine part c, d, e is not
    radial: it shows there). A fit that cannot reach every one of those pixels is refused."""
    m = read_ocamcalib(path)
    uv = _sample_pixels(m.width, m.height, step)
    rho = m.rho(uv)
    keep = rho < m.rho_max(float(rho.max()))
    uv, rays = uv[keep], m.cam2world(uv[keep])
    if len(uv) < 16:
        raise CalibrationError(f"{path}: pol: fewer than 16 pixels of the image have a ray (the field of view is empty)")
    f = -float(m.pol[0])
    try:
        cam, res = fit_opencv_fisheye(uv, rays, m.width, m.height, f, f, m.yc, m.xc)
    except CameraError as exc:
        raise CalibrationError(f"{path}: pol: no opencv_fisheye fits it ({exc})") from None
    if not math.isfinite(res):
        deg = math.degrees(float(np.arccos(np.clip(rays[:, 2], -1, 1)).max()))
        raise CalibrationError(f"{path}: pol: no opencv_fisheye fits its whole field of view ({deg:.0f} degrees from the axis)")
    return Imported(cam, None, res, str(path), fitted=True)


# ---------------------------------------------------------------- Kalibr camchain


def _kalibr_camera(c: dict, source: str, step: int) -> tuple[Camera, float]:
    """A Kalibr camera as ours, exactly: pinhole-equi = opencv_fisheye, pinhole = pinhole, pinhole-radtan
    = mei with xi = 0, omni = ucm, omni-radtan = mei, ds = double_sphere, eucm = eucm."""
    model = c.get("camera_model")
    dist = c.get("distortion_model", "none")
    w, h = image_size(*_numbers(c.get("resolution"), source, "resolution", 2), source, "resolution")
    k = _numbers(c.get("distortion_coeffs", []), source, "distortion_coeffs")
    if dist is None or (dist == "radtan" and not np.any(k)):  # radtan of zeros is no distortion; equidistant of zeros is not
        dist = "none"
    base = {"width": w, "height": h}

    def pp(cx, cy):
        check_principal_point(cx, cy, w, h, source, "intrinsics (cx, cy)")
        return {"cx": cx, "cy": cy}

    if model == "pinhole":
        fx, fy, cx, cy = _numbers(c.get("intrinsics"), source, "intrinsics", 4)
        base.update(fx=fx, fy=fy, **pp(cx, cy))
        if dist == "equidistant":
            return camera_from_dict({"model": "opencv_fisheye", **base, "k": list(_numbers(k, source, "distortion_coeffs", 4))}), 0.0
        if dist == "none":
            return camera_from_dict({"model": "pinhole", **base}), 0.0
        if dist == "radtan":
            return camera_from_dict({"model": "mei", **base, "s": 0.0, "xi": 0.0, "k": list(_numbers(k, source, "distortion_coeffs", 4))}), 0.0
    elif model == "omni":  # Mei: u = gamma x / (z + xi d) + c  ==  UCM with alpha = xi / (1 + xi), f = gamma / (1 + xi)
        xi, fx, fy, cx, cy = _numbers(c.get("intrinsics"), source, "intrinsics", 5)
        if dist == "none":
            return camera_from_dict({"model": "ucm", **base, "fx": fx / (1 + xi), "fy": fy / (1 + xi), **pp(cx, cy), "alpha": xi / (1 + xi)}), 0.0
        if dist == "radtan":
            return camera_from_dict({"model": "mei", **base, "fx": fx, "fy": fy, **pp(cx, cy), "s": 0.0, "xi": xi,
                                     "k": list(_numbers(k, source, "distortion_coeffs", 4))}), 0.0
    elif model == "ds":
        xi, alpha, fx, fy, cx, cy = _numbers(c.get("intrinsics"), source, "intrinsics", 6)
        if dist == "none":
            return camera_from_dict({"model": "double_sphere", **base, "fx": fx, "fy": fy, **pp(cx, cy), "xi": xi, "alpha": alpha}), 0.0
    elif model == "eucm":
        alpha, beta, fx, fy, cx, cy = _numbers(c.get("intrinsics"), source, "intrinsics", 6)
        if dist == "none":
            return camera_from_dict({"model": "eucm", **base, "fx": fx, "fy": fy, **pp(cx, cy), "alpha": alpha, "beta": beta}), 0.0
    else:
        raise CalibrationError(f"{source}: camera_model: {model!r} is not one of pinhole, omni, ds, eucm")
    raise CalibrationError(f"{source}: distortion_model: {dist!r} with {model} (supported: none; radtan with pinhole and omni; "
                           "equidistant with pinhole)")


def _matrix4(v, source, field) -> np.ndarray:
    m = _numbers(v, source, field, 16).reshape(4, 4)
    if not np.allclose(m[3], [0, 0, 0, 1]) or not np.allclose(m[:3, :3] @ m[:3, :3].T, np.eye(3), atol=1e-5):
        raise CalibrationError(f"{source}: {field}: not a rigid 4x4 transform")
    det = float(np.linalg.det(m[:3, :3]))
    if det < 0:  # orthonormal but a reflection: the camera would look backwards, mirrored
        raise CalibrationError(f"{source}: {field}: a reflection (determinant {det:.3g}), not a rotation")
    return m


def kalibr_cameras(path, step: int = 8) -> dict[str, Imported]:
    """A Kalibr camchain (cam0, cam1, ...): each camera as ours, exactly (pinhole-equi = opencv_fisheye,
    omni without distortion = ucm, pinhole-radtan and omni-radtan = mei, ds = double_sphere, eucm) and its pose in the IMU
    frame (`T_cam_imu` inverted), or, without IMU, in cam0's frame (the `T_cn_cnm1` chain)."""
    path = Path(path)
    d = read_yaml(path, CalibrationError)
    if not isinstance(d, dict) or not any(str(k).startswith("cam") for k in d):
        raise CalibrationError(f"{path}: not a Kalibr camchain (no cam0, cam1, ... entries)")
    out: dict[str, Imported] = {}
    prev = np.eye(4)  # cam_{n-1} -> cam0
    for name in sorted((k for k in d if re.fullmatch(r"cam\d+", str(k))), key=lambda s: int(s[3:])):
        c, where = d[name], f"{path}: {name}"
        if not isinstance(c, dict):
            raise CalibrationError(f"{where}: must be a mapping")
        try:
            cam, res = _kalibr_camera(c, where, step)
        except CameraError as exc:
            raise CalibrationError(f"{where}: {exc}") from None
        if "T_cam_imu" in c:
            pose = np.linalg.inv(_matrix4(c["T_cam_imu"], where, "T_cam_imu"))
        elif name == "cam0":
            pose = np.eye(4)
        elif "T_cn_cnm1" in c:  # x_cn = T x_cn-1
            pose = prev @ np.linalg.inv(_matrix4(c["T_cn_cnm1"], where, "T_cn_cnm1"))
        else:
            raise CalibrationError(f"{where}: needs T_cam_imu or T_cn_cnm1 (its pose)")
        prev = pose
        out[name] = Imported(cam, pose, res, str(path))
    return out


# ---------------------------------------------------------------- any of them


def guess_format(path) -> str:
    path = Path(path)
    if path.suffix.lower() == ".txt":
        return "ocamcalib"
    text = read_text(path, CalibrationError)[:4000]
    if path.suffix.lower() == ".json" and '"intrinsic"' in text and '"extrinsic"' in text:
        return "woodscape"
    if re.search(r"^cam\d+:", text, re.M) and "camera_model" in text:
        return "kalibr"
    if "opencv-matrix" in text or re.search(r'^\s*"?(K|camera_matrix)"?\s*:', text, re.M):
        return "opencv_fisheye"
    raise CalibrationError(f"{path}: cannot tell its format; say 'format:' (one of: {', '.join(FORMATS)})")


def import_calibration(path, fmt: str | None = None, camera: str | None = None) -> Imported:
    """One camera from a calibration file of any format but WoodScape's (geometry.rig reads those)
    (`camera`: which one of a Kalibr camchain)."""
    path = Path(path)
    fmt = fmt or guess_format(path)
    if fmt == "opencv_fisheye":
        return Imported(opencv_fisheye_camera(path), None, 0.0, str(path))
    if fmt == "ocamcalib":
        return ocamcalib_camera(path)
    if fmt == "kalibr":
        cams = kalibr_cameras(path)
        if camera is None and len(cams) == 1:
            camera = next(iter(cams))
        if camera not in cams:
            raise CalibrationError(f"{path}: camera: {camera!r} is not in the camchain (has: {', '.join(cams)})")
        return cams[camera]
    if fmt == "woodscape":
        raise CalibrationError(f"{path}: WoodScape calibrations are read by geometry.rig.load_rig (or a rig file's 'calibration:')")
    raise CalibrationError(f"{path}: format: {fmt!r} is not one of {', '.join(FORMATS)}")


# ---------------------------------------------------------------- a pose from a ground-plane homography


def pose_from_ground_homography(H_ground_to_normalised: np.ndarray) -> np.ndarray:
    """The camera -> ground-frame transform (4x4) of a camera whose normalised pinhole coordinates
    (x/z, y/z) are H (x, y, 1) for ground points (x, y, 0), H known up to scale (Zhang's
    decomposition: H ~ [r1 r2 t]; the rotation is the nearest one, the camera above the ground, z up)."""
    M = np.asarray(H_ground_to_normalised, dtype=np.float64)
    M = M / math.sqrt(np.linalg.norm(M[:, 0]) * np.linalg.norm(M[:, 1]))
    if np.cross(M[:, 0], M[:, 1]) @ M[:, 2] > 0:  # centre z = -r3 . t: the other sign puts it above the ground
        M = -M
    u, _, vt = np.linalg.svd(np.stack([M[:, 0], M[:, 1], np.cross(M[:, 0], M[:, 1])], -1))
    R, t = u @ vt, M[:, 2]
    ego_to_cam = np.eye(4)
    ego_to_cam[:3, :3], ego_to_cam[:3, 3] = R, t
    return np.linalg.inv(ego_to_cam)
