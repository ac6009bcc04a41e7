"""Rigs: named cameras with camera-to-ego transforms.

Ego frame ISO 8855 (x forward, y left, z up, origin on the ground under the rear axle); camera
frame OpenCV (x right, y down, z optical axis). `cam_to_ego` maps camera coordinates to ego ones.

Rig file (YAML or JSON)::

    name: default
    cameras:
      front:
        intrinsics: {model: equidistant, width: 480, height: 302, fx: ..., fy: ..., cx: ..., cy: ...}
        extrinsics:
          translation: [3.7, 0.0, 0.6]          # camera centre in the ego frame, metres
          rotation: {yaw_deg: 0, pitch_deg: 20, roll_deg: 0}   # or quaternion: [qx, qy, qz, qw]

`yaw_deg` turns the optical axis to the left of forward, `pitch_deg` tilts it down, `roll_deg`
turns the image clockwise about the optical axis as seen from behind the camera. A quaternion
[qx, qy, qz, qw] (scalar last, as WoodScape and scipy) is the camera-to-ego rotation itself.
"""

from __future__ import annotations

import json
import math
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from common.errors import InputError
from common.files import read_json, read_yaml, write_text_atomic

from .cameras import Camera, CameraError, camera_from_dict

# Columns: the OpenCV camera axes (x right, y down, z forward) of a camera looking along ego +x.
FORWARD_CAMERA = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


class RigError(InputError):
    """A rig file that cannot make a rig (names the file and field)."""


def rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]], dtype=np.float64)


def rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]], dtype=np.float64)


def rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], dtype=np.float64)


def mount_rotation(yaw_deg: float, pitch_deg: float, roll_deg: float = 0.0) -> np.ndarray:
    """Camera-to-ego rotation of a camera turned by yaw (left), pitched down and rolled."""
    # roll about the camera's own z (optical) axis, applied in the camera frame
    roll = np.array(
        [[math.cos(math.radians(roll_deg)), -math.sin(math.radians(roll_deg)), 0],
         [math.sin(math.radians(roll_deg)), math.cos(math.radians(roll_deg)), 0],
         [0, 0, 1]]
    )
    return rot_z(math.radians(yaw_deg)) @ rot_y(math.radians(pitch_deg)) @ FORWARD_CAMERA @ roll


def quat_to_matrix(q) -> np.ndarray:
    """[qx, qy, qz, qw] (scalar last, as WoodScape and scipy) -> 3x3 rotation matrix; normalises q."""
    from kornia.geometry.conversions import quaternion_to_rotation_matrix

    x, y, z, w = np.asarray(q, dtype=np.float64)
    return quaternion_to_rotation_matrix(torch.tensor([w, x, y, z], dtype=torch.float64)).numpy()


def matrix_to_quat(m: np.ndarray) -> list[float]:
    """3x3 rotation -> [qx, qy, qz, qw] (scalar last) with qw >= 0."""
    from kornia.geometry.conversions import rotation_matrix_to_quaternion

    w, x, y, z = rotation_matrix_to_quaternion(torch.as_tensor(np.asarray(m, dtype=np.float64))).tolist()
    q = np.array([x, y, z, w])
    return [float(v) for v in (-q if q[3] < 0 else q)]


def make_transform(rotation: np.ndarray, translation) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = rotation
    t[:3, 3] = np.asarray(translation, dtype=np.float64)
    return t


@dataclass
class RigCamera:
    name: str
    camera: Camera
    cam_to_ego: np.ndarray  # (4, 4)

    @property
    def ego_to_cam(self) -> np.ndarray:
        return np.linalg.inv(self.cam_to_ego)

    def to_dict(self) -> dict:
        return {
            "intrinsics": self.camera.to_dict(),
            "extrinsics": {
                "translation": [float(v) for v in self.cam_to_ego[:3, 3]],
                "quaternion": matrix_to_quat(self.cam_to_ego[:3, :3]),
            },
        }

    def project_ego(self, points_ego):
        """Ego-frame points (..., 3) -> (uv, valid); numpy or torch, as the camera."""
        import torch

        r = self.ego_to_cam
        if isinstance(points_ego, torch.Tensor):
            rt = torch.as_tensor(r, dtype=points_ego.dtype, device=points_ego.device)
            p = points_ego @ rt[:3, :3].T + rt[:3, 3]
        else:
            p = np.asarray(points_ego) @ r[:3, :3].T + r[:3, 3]
        return self.camera.project(p)

    def rays_ego(self, uv=None):
        """(origin (3,), unit ray directions in the ego frame (..., 3), valid) for pixels uv
        (default: every pixel centre, (H, W))."""
        import torch

        if uv is None:
            uv = self.camera.pixel_grid()
        rays, valid = self.camera.unproject(uv)
        if isinstance(rays, torch.Tensor):
            r = torch.as_tensor(self.cam_to_ego[:3, :3], dtype=rays.dtype, device=rays.device)
            return torch.as_tensor(self.cam_to_ego[:3, 3], dtype=rays.dtype), rays @ r.T, valid
        return self.cam_to_ego[:3, 3].copy(), rays @ self.cam_to_ego[:3, :3].T, valid


class Rig:
    def __init__(self, cameras, name: str = "rig", origins: dict | None = None):
        self.name = name
        self.cameras: "OrderedDict[str, RigCamera]" = OrderedDict((c.name, c) for c in cameras)
        # camera name -> what its calibration became ("mei (exact) from cam.yaml", "opencv_fisheye
        # (fitted, residual 2.99 px over its field of view) from calib_results.txt"); see describe()
        self.origins: dict[str, str] = dict(origins or {})

    def describe(self) -> list[str]:
        """One line per camera: its name, model and whether it is its calibration exactly or a fit
        (with the fit's residual in pixels); what the commands that load a rig print once."""
        return [f"{n}: {self.origins.get(n) or f'{c.camera.model} (exact, given inline)'}" for n, c in self.cameras.items()]

    def print_description(self, source) -> None:
        """describe()'s lines on stdout, each as `rig <source>: <line>` (`source`: where the rig came
        from, a file or a data set); what every command that loads a rig prints once."""
        for line in self.describe():
            print(f"rig {source}: {line}", flush=True)

    def __len__(self):
        return len(self.cameras)

    def __iter__(self):
        return iter(self.cameras.values())

    def __getitem__(self, name: str) -> RigCamera:
        return self.cameras[name]

    @property
    def names(self) -> list[str]:
        return list(self.cameras)

    def to_dict(self) -> dict:
        return {"name": self.name, "cameras": {n: c.to_dict() for n, c in self.cameras.items()}}

    def save(self, path) -> None:
        import yaml

        path = Path(path)
        text = json.dumps(self.to_dict(), indent=2) if path.suffix == ".json" else yaml.safe_dump(self.to_dict(), sort_keys=False)
        write_text_atomic(path, text)

    def map_cameras(self, fn) -> "Rig":
        """A rig whose cameras are fn(camera) (e.g. resized), same extrinsics."""
        return Rig([RigCamera(c.name, fn(c.camera), c.cam_to_ego.copy()) for c in self], self.name)

    def turned(self, yaw: float) -> "Rig":
        """The rig carried by the world turned by `yaw` radians about the ego z axis (to the left):
        every camera's pose rotated about the ego origin, its intrinsics kept, so each camera sees
        what it saw and an ego point p it saw now lies at rot_z(yaw) p (BevGrid.turned moves the
        labels alike)."""
        turn = make_transform(rot_z(yaw), [0.0, 0.0, 0.0])
        return Rig([RigCamera(c.name, c.camera, turn @ c.cam_to_ego) for c in self], self.name, self.origins)


def rig_difference(a: Rig, b: Rig, tol: float = 1e-6) -> str | None:
    """None where rig b is rig a (the same camera names, models, calibrations up to a resize of the
    images, and poses, within `tol` relative / metres), else the first difference, in words."""
    if a.names != b.names:
        return f"cameras {', '.join(b.names)} against {', '.join(a.names)}"
    for ca, cb in zip(a, b):
        if ca.camera.model != cb.camera.model:
            return f"camera {ca.name}: model {cb.camera.model} against {ca.camera.model}"
        try:
            other = cb.camera.resized(ca.camera.width, ca.camera.height)
        except CameraError:
            return f"camera {ca.name}: another calibration"
        da, db = ca.camera.to_dict(), other.to_dict()
        for k, va in da.items():
            if k == "model":
                continue
            x, y = np.atleast_1d(np.asarray(va, dtype=np.float64)), np.atleast_1d(np.asarray(db[k], dtype=np.float64))
            if x.shape != y.shape or np.any(np.abs(x - y) > tol * np.maximum(1.0, np.abs(x))):
                return f"camera {ca.name}: {k} {db[k]} against {va} (at {ca.camera.width}x{ca.camera.height})"
        if np.abs(ca.cam_to_ego - cb.cam_to_ego).max() > tol:
            return f"camera {ca.name}: another pose (camera-to-vehicle transform)"
    return None


# Per-scene rig jitter at scale 1: mount position (m, per axis), mount angles (deg, about each camera
# axis), focal length (fraction); each drawn uniformly in +-these (docs/scene-variety.md).
JITTER = {"translation_m": 0.03, "angle_deg": 2.0, "focal": 0.03}


def focal_scaled(camera: Camera, f: float) -> Camera:
    """The camera with its focal length times f (principal point, size and distortion kept)."""
    d = camera.to_dict()
    if "fx" in d:
        d["fx"], d["fy"] = d["fx"] * f, d["fy"] * f
        if "s" in d:  # mei's skew scales with the focal length
            d["s"] *= f
    elif d["model"] == "radial_poly":  # rho(theta) in pixels: every coefficient scales with the focal
        d["k"] = [k * f for k in d["k"]]
    else:
        raise ValueError(f"focal_scaled: no focal length in a {d['model']} camera")
    return camera_from_dict(d)


def jitter_rig(rig: Rig, rng: np.random.Generator, scale: float = 1.0) -> Rig:
    """The rig with every camera's mount moved, turned and its focal length changed a little
    (JITTER times `scale`), as a real car's cameras differ from the nominal calibration."""
    cams = []
    for rc in rig:
        t = rng.uniform(-1, 1, 3) * JITTER["translation_m"] * scale
        a = np.radians(rng.uniform(-1, 1, 3) * JITTER["angle_deg"] * scale)
        f = 1.0 + float(rng.uniform(-1, 1)) * JITTER["focal"] * scale
        m = rc.cam_to_ego.copy()
        m[:3, :3] = m[:3, :3] @ rot_x(a[0]) @ rot_y(a[1]) @ rot_z(a[2])  # about the camera's own axes
        m[:3, 3] += t
        cams.append(RigCamera(rc.name, focal_scaled(rc.camera, f), m))
    return Rig(cams, rig.name)


def _extrinsics(e, where: str) -> np.ndarray:
    if not isinstance(e, dict):
        raise RigError(f"{where}: 'extrinsics' must be a mapping")
    if "translation" not in e:
        raise RigError(f"{where}.extrinsics: missing 'translation'")
    t = e["translation"]
    if not (isinstance(t, (list, tuple)) and len(t) == 3 and all(_finite(v) for v in t)):
        raise RigError(f"{where}.extrinsics.translation: must be a list of 3 finite numbers, got {t!r}"[:200])
    has_q, has_r = "quaternion" in e, "rotation" in e
    if has_q == has_r:
        raise RigError(f"{where}.extrinsics: give exactly one of 'quaternion' or 'rotation'")
    try:
        if has_q:
            q = [float(v) for v in e["quaternion"]]
            if len(q) != 4 or not np.all(np.isfinite(q)) or np.linalg.norm(q) < 1e-9:
                raise ValueError
            r = quat_to_matrix(q)
        else:
            rot = e["rotation"]
            unknown = set(rot) - {"yaw_deg", "pitch_deg", "roll_deg"}
            if unknown:
                raise RigError(f"{where}.extrinsics.rotation: unknown key '{sorted(unknown)[0]}'")
            angles = [float(rot.get(k, 0)) for k in ("yaw_deg", "pitch_deg", "roll_deg")]
            if not all(math.isfinite(a) for a in angles):
                raise ValueError
            r = mount_rotation(*angles)
        return make_transform(r, [float(v) for v in t])
    except RigError:
        raise
    except (TypeError, ValueError, AttributeError):
        key = "quaternion" if has_q else "rotation"
        raise RigError(f"{where}.extrinsics.{key}: not a valid rotation") from None


def rig_from_dict(d: dict, source: str = "rig") -> Rig:
    if not isinstance(d, dict) or not isinstance(d.get("cameras"), dict) or not d["cameras"]:
        raise RigError(f"{source}: 'cameras' must be a non-empty mapping of name -> camera")
    cams = []
    for name, c in d["cameras"].items():
        where = f"{source}: cameras.{name}"
        if not isinstance(c, dict) or "intrinsics" not in c or "extrinsics" not in c:
            raise RigError(f"{where}: needs 'intrinsics' and 'extrinsics'")
        try:
            cam = camera_from_dict(c["intrinsics"])
        except (CameraError, TypeError) as exc:
            raise RigError(f"{where}.intrinsics: {exc}") from None
        cams.append(RigCamera(str(name), cam, _extrinsics(c["extrinsics"], where)))
    return Rig(cams, str(d.get("name", Path(source).stem)))


def _finite(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _read_mapping(path: Path):
    return read_json(path, RigError) if path.suffix == ".json" else read_yaml(path, RigError)


def load_rig(path) -> Rig:
    """A rig from a YAML/JSON rig file (cameras given inline, or as calibration files of other tools:
    `calibration:`), or from a WoodScape calibration JSON (one camera)."""
    path = Path(path)
    d = _read_mapping(path)
    if isinstance(d, dict) and "intrinsic" in d and "extrinsic" in d:
        rc = woodscape_camera(d, str(path))
        return Rig([rc], origins={rc.name: f"radial_poly (exact) from WoodScape {path.name}"})
    if isinstance(d, dict) and isinstance(d.get("cameras"), dict) and any(
            isinstance(c, dict) and "calibration" in c for c in d["cameras"].values()):
        return assemble_rig(d, path)
    return rig_from_dict(d, str(path))


# ---------------------------------------------------------------- WoodScape


def woodscape_camera(d: dict, source: str = "woodscape") -> RigCamera:
    """A WoodScape calibration (their JSON: `intrinsic` radial_poly, `extrinsic` camera-to-vehicle
    quaternion [qx, qy, qz, qw] and translation) as a RigCamera. cx = width/2 - 0.5 + cx_offset."""
    try:
        i, e = d["intrinsic"], d["extrinsic"]
    except (KeyError, TypeError):
        raise RigError(f"{source}: needs 'intrinsic' and 'extrinsic'") from None
    need = ["width", "height", "cx_offset", "cy_offset", "aspect_ratio", "k1", "k2", "k3", "k4"]
    for k in need:
        if k not in i:
            raise RigError(f"{source}: intrinsic: missing '{k}'")
    if i.get("model", "radial_poly") != "radial_poly":
        raise RigError(f"{source}: intrinsic.model: only 'radial_poly' is a WoodScape model, got {i['model']!r}")
    for k in need:
        if not _finite(i[k]):
            raise RigError(f"{source}: intrinsic.{k}: must be a finite number, got {i[k]!r}"[:200])
    for k in ("width", "height"):
        if not float(i[k]).is_integer() or not 1 <= i[k] <= 100_000:
            raise RigError(f"{source}: intrinsic.{k}: must be a whole number of pixels in [1, 100000], got {i[k]!r}")
    w, h = float(i["width"]), float(i["height"])
    for k, size in (("cx_offset", w), ("cy_offset", h)):
        if abs(i[k]) > size / 2:
            raise RigError(f"{source}: intrinsic.{k}: {i[k]} puts the principal point outside the {int(w)}x{int(h)} image")
    cam = {
        "model": "radial_poly",
        "width": int(w),
        "height": int(h),
        "cx": w / 2 - 0.5 + float(i["cx_offset"]),
        "cy": h / 2 - 0.5 + float(i["cy_offset"]),
        "aspect_ratio": float(i["aspect_ratio"]),
        "k": [float(i[f"k{n}"]) for n in range(1, 5)],
    }
    try:
        camera = camera_from_dict(cam)
    except CameraError as exc:
        raise RigError(f"{source}: intrinsic: {exc}") from None
    return RigCamera(str(d.get("name", "camera")), camera, _extrinsics(e, source))


# ---------------------------------------------------------------- rigs of calibration files


ASSEMBLY_KEYS = {"calibration", "format", "camera", "extrinsics"}


def assemble_rig(d: dict, path) -> Rig:
    """A rig file whose cameras name calibration files of other tools (docs/geometry.md, "Your own rig")::

        name: my_car
        reference_to_vehicle: {translation: [...], rotation: {...}}   # the files' own frame (Kalibr's IMU)
        cameras:
          front: {calibration: front.yaml, format: opencv_fisheye, extrinsics: {translation: ..., rotation: ...}}
          cam1:  {calibration: camchain.yaml, camera: cam1}            # pose from the file

    Paths are relative to the rig file. A camera's `extrinsics` (camera -> vehicle) win; without them
    the pose the file holds is used: Kalibr's (T_cam_imu inverted, or the T_cn_cnm1 chain from cam0)
    taken to the vehicle frame by `reference_to_vehicle` (default identity); WoodScape's, already in
    the vehicle frame. Cameras may mix formats and inline `intrinsics`."""
    from .calib_import import CalibrationError, import_calibration

    path = Path(path)
    ref = _extrinsics(d["reference_to_vehicle"], f"{path}: reference_to_vehicle") if "reference_to_vehicle" in d else np.eye(4)
    cams, origins = [], {}
    for name, c in d["cameras"].items():
        where = f"{path}: cameras.{name}"
        if not isinstance(c, dict) or "calibration" not in c:
            cams.extend(rig_from_dict({"cameras": {name: c}}, str(path)))
            continue
        unknown = set(c) - ASSEMBLY_KEYS
        if unknown:
            raise RigError(f"{where}: unknown key '{sorted(unknown)[0]}' (keys: {', '.join(sorted(ASSEMBLY_KEYS))})")
        file = path.parent / str(c["calibration"])
        try:
            if c.get("format") == "woodscape" or (c.get("format") is None and file.suffix == ".json"
                                                   and "intrinsic" in (_read_mapping(file) or {})):
                rc = woodscape_camera(_read_mapping(file), str(file))
                camera, pose = rc.camera, np.linalg.inv(ref) @ rc.cam_to_ego  # already in the vehicle frame
                origins[str(name)] = f"radial_poly (exact) from WoodScape {file.name}"
            else:
                imp = import_calibration(file, c.get("format"), c.get("camera"))
                camera, pose = imp.camera, imp.cam_to_ref
                origins[str(name)] = f"{imp.describe()} from {file.name}" + (f" {c['camera']}" if c.get("camera") else "")
        except CalibrationError as exc:
            raise RigError(f"{where}.calibration: {exc}") from None
        if "extrinsics" in c:
            cam_to_ego = _extrinsics(c["extrinsics"], where)
        elif pose is not None:
            cam_to_ego = ref @ pose
        else:
            raise RigError(f"{where}: needs 'extrinsics' ({file.name} holds no pose)")
        cams.append(RigCamera(str(name), camera, cam_to_ego))
    return Rig(cams, str(d.get("name", path.stem)), origins)
