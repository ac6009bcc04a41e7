"""Calibrations other tools write, as our cameras (docs/geometry.md, "Importing calibrations").

    cam = opencv_fisheye_camera("front.yaml")              # cv2.fisheye K, D: exact (opencv_fisheye)
    cams = kalibr_cameras("camchain.yaml")                 # name -> Imported (camera, T_cam_imu, residual)
    imp = ocamcalib_camera("calib_results.txt")            # Scaramuzza's polynomial: fitted, residual in px
    imp = import_calibration(path, fmt=None)               # any of these, format guessed from the file

Each importer returns an `Imported`: the camera, the source's own pose if it has one (`cam_to_ref`,
4x4, camera -> the file's reference frame: Kalibr's IMU, WoodScape's vehicle), and `residual_px`,
the largest distance in pixels between the source model and ours over the image (0 where the models
coincide exactly). Bad input is a `CalibrationError` naming the file and the field.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from common.errors import InputError
from common.files import read_json, read_text

from .cameras import Camera, CameraError, camera_from_dict


class CalibrationError(InputError):
    """A calibration file that cannot make a camera (names the file and the field)."""


@dataclass
class Imported:
    camera: Camera
    cam_to_ref: np.ndarray | None = None  # (4, 4) camera -> the file's reference frame, if it has one
    residual_px: float = 0.0  # max |source pixel - our pixel| over the image; 0: exact
    source: str = ""


FORMATS = ("opencv_fisheye", "kalibr", "ocamcalib", "woodscape")


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
            rows, cols = int(node["rows"]), int(node["cols"])
        except (KeyError, TypeError, ValueError):
            raise CalibrationError(f"{source}: {field}: needs whole 'rows' and 'cols'") from None
        if rows * cols != data.size:
            raise CalibrationError(f"{source}: {field}: rows x cols = {rows * cols}, but data has {data.size} numbers")
        return data.reshape(rows, cols)
    return np.atleast_2d(_numbers(node, source, field))


def read_opencv_storage(path) -> dict:
    """A file of OpenCV's FileStorage (YAML with `%YAML:1.0` and `!!opencv-matrix`, or JSON) as a dict
    whose matrices are numpy arrays."""
    import yaml

    path = Path(path)
    text = read_text(path, CalibrationError)
    if path.suffix.lower() == ".json":
        d = read_json(path, CalibrationError)
    else:
        text = re.sub(r"^%YAML[: ]1\.\d\s*\n", "", text)  # OpenCV writes a YAML 1.0 directive PyYAML refuses

        class _Loader(yaml.SafeLoader):
            pass

        def matrix(loader, node):
            return {"__opencv_matrix__": True, **loader.construct_mapping(node, deep=True)}

        _Loader.add_constructor("tag:yaml.org,2002:opencv-matrix", matrix)
        _Loader.add_multi_constructor("tag:yaml.org,2002:", lambda loader, suffix, node: loader.construct_mapping(node, deep=True)
                                      if isinstance(node, yaml.MappingNode) else loader.construct_scalar(node))
        try:
            d = yaml.load(text, Loader=_Loader)  # noqa: S506 - a SafeLoader subclass
        except yaml.YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            where = f" (line {mark.line + 1})" if mark else ""
            raise CalibrationError(f"{path}: not an OpenCV FileStorage YAML file{where}") from None
    if not isinstance(d, dict):
        raise CalibrationError(f"{path}: expected a mapping of named nodes")
    return {k: (_opencv_matrix(v, path, k) if isinstance(v, dict) and ("__opencv_matrix__" in v or v.get("type_id") == "opencv-matrix") else v)
            for k, v in d.items()}


def _first(d: dict, keys, source, what):
    for k in keys:
        if k in d:
            return k, d[k]
    raise CalibrationError(f"{source}: missing {what} (one of: {', '.join(keys)})")


def opencv_fisheye_dict(K, D, width: int, height: int, source="opencv", field="K") -> dict:
    """cv2.fisheye's K (3x3) and D (4) as our `opencv_fisheye` camera dict (the same model: exact)."""
    K = np.asarray(K, dtype=np.float64).reshape(3, 3)
    D = np.asarray(D, dtype=np.float64).ravel()
    if D.size != 4:
        raise CalibrationError(f"{source}: D: cv2.fisheye has 4 coefficients k1..k4, got {D.size}")
    if abs(K[0, 1]) > 1e-9 * abs(K[0, 0]):
        raise CalibrationError(f"{source}: {field}: skew K[0][1] = {K[0, 1]} (cv2.fisheye alpha) is not supported")
    if not np.allclose(K[2], [0, 0, 1]) or K[1, 0] != 0:
        raise CalibrationError(f"{source}: {field}: not a camera matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]")
    return {"model": "opencv_fisheye", "width": int(width), "height": int(height), "fx": float(K[0, 0]), "fy": float(K[1, 1]),
            "cx": float(K[0, 2]), "cy": float(K[1, 2]), "k": [float(v) for v in D]}


def opencv_fisheye_camera(path, width: int | None = None, height: int | None = None) -> Camera:
    """A cv2.fisheye calibration in a FileStorage file: K (`K`, `camera_matrix`), D (`D`,
    `dist_coeffs`, `distortion_coefficients`) and the image size (`resolution`/`image_size` [w, h],
    or `image_width` and `image_height`, or the arguments)."""
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
        else:
            sk, size = _first(d, ("resolution", "image_size", "imageSize"), path, "the image size")
            size = _numbers(np.asarray(size, dtype=object).tolist() if not isinstance(size, np.ndarray) else size, path, sk, 2)
        width, height = int(size[0]), int(size[1])
    try:
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
    u = np.arange(0, width, step, dtype=np.float64)
    v = np.arange(0, height, step, dtype=np.float64)
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

    def cam2world(self, uv: np.ndarray) -> np.ndarray:
        """Our pixels (u = column, v = row) -> unit rays in our camera frame (x right, y down, z forward)."""
        row, col = uv[:, 1] - self.xc, uv[:, 0] - self.yc
        inv = 1.0 / (self.c - self.d * self.e)
        xp = inv * (row - self.d * col)
        yp = inv * (-self.e * row + self.c * col)
        zp = np.polynomial.polynomial.polyval(np.hypot(xp, yp), self.pol)
        rays = np.stack([yp, xp, -zp], -1)  # OCam (row, col, back) -> ours (right, down, forward)
        return rays / np.linalg.norm(rays, axis=-1, keepdims=True)


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
    if not (h.is_integer() and w.is_integer() and h > 0 and w > 0):
        raise CalibrationError(f"{path}: image size: expected whole positive 'height width', got {h:g} {w:g}")
    pol = np.asarray(blocks["pol"][1:])
    if pol[0] >= 0:
        raise CalibrationError(f"{path}: pol: the first coefficient a0 must be negative (the ray at the centre looks forward), got {pol[0]:g}")
    c, d, e = blocks["affine"]
    if abs(c - d * e) < 1e-12:
        raise CalibrationError(f"{path}: affine: c - d e must not be 0")
    return OCamModel(pol, np.asarray(blocks["invpol"][1:]), *blocks["center"], c, d, e, int(h), int(w))


def ocamcalib_camera(path, step: int = 8) -> Imported:
    """An OCamCalib calibration fitted by an `opencv_fisheye` camera: fx = fy = -a0 (the focal length at
    the centre), (cx, cy) = the centre, k1..k4 by least squares over the image; `residual_px` is the
    largest pixel distance between the two over the pixels within 100 degrees of the axis (the affine
    part c, d, e is not radial: it shows there)."""
    m = read_ocamcalib(path)
    uv = _sample_pixels(m.width, m.height, step)
    rays = m.cam2world(uv)
    keep = rays[:, 2] > math.cos(math.radians(100))  # the part of the image a radial polynomial can hold
    f = -float(m.pol[0])
    try:
        cam, res = fit_opencv_fisheye(uv[keep], rays[keep], m.width, m.height, f, f, m.yc, m.xc)
    except CameraError as exc:
        raise CalibrationError(f"{path}: pol: no opencv_fisheye fits it ({exc})") from None
    return Imported(cam, None, res, str(path))


# ---------------------------------------------------------------- Kalibr camchain


def _radtan(mx, my, k):
    k1, k2, p1, p2 = k
    r2 = mx * mx + my * my
    radial = 1 + k1 * r2 + k2 * r2 * r2
    return (mx * radial + 2 * p1 * mx * my + p2 * (r2 + 2 * mx * mx), my * radial + p1 * (r2 + 2 * my * my) + 2 * p2 * mx * my)


def _kalibr_camera(c: dict, source: str, step: int) -> tuple[Camera, float]:
    model = c.get("camera_model")
    dist = c.get("distortion_model", "none")
    w, h = (int(v) for v in _numbers(c.get("resolution"), source, "resolution", 2))
    k = _numbers(c.get("distortion_coeffs", []), source, "distortion_coeffs")
    if dist is None or (dist == "radtan" and not np.any(k)):  # radtan of zeros is no distortion; equidistant of zeros is not
        dist = "none"
    base = {"width": w, "height": h}
    if model == "pinhole":
        fx, fy, cx, cy = _numbers(c.get("intrinsics"), source, "intrinsics", 4)
        base.update(fx=fx, fy=fy, cx=cx, cy=cy)
        if dist == "equidistant":
            return camera_from_dict({"model": "opencv_fisheye", **base, "k": list(_numbers(k, source, "distortion_coeffs", 4))}), 0.0
        if dist == "none":
            return camera_from_dict({"model": "pinhole", **base}), 0.0
    elif model == "omni":  # Mei: u = gamma x / (z + xi d) + c  ==  UCM with alpha = xi / (1 + xi), f = gamma / (1 + xi)
        xi, fx, fy, cx, cy = _numbers(c.get("intrinsics"), source, "intrinsics", 5)
        ucm = camera_from_dict({"model": "ucm", **base, "fx": fx / (1 + xi), "fy": fy / (1 + xi), "cx": cx, "cy": cy, "alpha": xi / (1 + xi)})
        if dist == "none":
            return ucm, 0.0
    elif model == "ds":
        xi, alpha, fx, fy, cx, cy = _numbers(c.get("intrinsics"), source, "intrinsics", 6)
        if dist == "none":
            return camera_from_dict({"model": "double_sphere", **base, "fx": fx, "fy": fy, "cx": cx, "cy": cy, "xi": xi, "alpha": alpha}), 0.0
    elif model == "eucm":
        alpha, beta, fx, fy, cx, cy = _numbers(c.get("intrinsics"), source, "intrinsics", 6)
        if dist == "none":
            return camera_from_dict({"model": "eucm", **base, "fx": fx, "fy": fy, "cx": cx, "cy": cy, "alpha": alpha, "beta": beta}), 0.0
    else:
        raise CalibrationError(f"{source}: camera_model: {model!r} is not one of pinhole, omni, ds, eucm")
    if dist != "radtan":
        raise CalibrationError(f"{source}: distortion_model: {dist!r} with {model} (supported: none, radtan; equidistant with pinhole)")
    # radtan distortion of the normalised (pinhole) or unit-plane (omni) point: not radial, so fitted
    k = _numbers(k, source, "distortion_coeffs", 4)
    uv = _sample_pixels(w, h, step)
    undist = _undistort_radtan((uv[:, 0] - cx) / fx, (uv[:, 1] - cy) / fy, k)
    if model == "pinhole":
        rays = np.stack([undist[0], undist[1], np.ones(len(uv))], -1)
    else:  # the omni unit plane: undistorted (mx, my) through Mei's inverse, as a UCM of unit focal length
        plane = camera_from_dict({"model": "ucm", "width": w, "height": h, "fx": 1 / (1 + xi), "fy": 1 / (1 + xi), "cx": 0.0, "cy": 0.0,
                                  "alpha": xi / (1 + xi)})
        rays, ok = plane.unproject(np.stack(undist, -1))
        uv, rays = uv[ok], rays[ok]
    ray_ok = rays[:, 2] / np.linalg.norm(rays, axis=-1) > math.cos(math.radians(100))
    return fit_opencv_fisheye(uv[ray_ok], rays[ray_ok], w, h, fx if model == "pinhole" else fx / (1 + xi),
                              fy if model == "pinhole" else fy / (1 + xi), cx, cy)


def _undistort_radtan(mx, my, k, iters: int = 50):
    x, y = mx.copy(), my.copy()
    for _ in range(iters):  # fixed point, as OpenCV's undistortPoints
        dx, dy = _radtan(x, y, k)
        x, y = x - (dx - mx), y - (dy - my)
    return x, y


def _matrix4(v, source, field) -> np.ndarray:
    m = _numbers(v, source, field, 16).reshape(4, 4)
    if not np.allclose(m[3], [0, 0, 0, 1]) or not np.allclose(m[:3, :3] @ m[:3, :3].T, np.eye(3), atol=1e-5):
        raise CalibrationError(f"{source}: {field}: not a rigid 4x4 transform")
    return m


def kalibr_cameras(path, step: int = 8) -> dict[str, Imported]:
    """A Kalibr camchain (cam0, cam1, ...): each camera as ours (exact for pinhole-equi = opencv_fisheye,
    omni without distortion = ucm, ds = double_sphere, eucm; fitted otherwise) and its pose in the IMU
    frame (`T_cam_imu` inverted), or, without IMU, in cam0's frame (the `T_cn_cnm1` chain)."""
    from common.files import read_yaml

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
