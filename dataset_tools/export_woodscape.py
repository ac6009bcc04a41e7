"""Export a rendered data set in the WoodScape layout (github.com/valeoai/WoodScape, its README and
scripts: calibration/calibration_readme.txt, semantic_map_generator.py, box_2d_generator.py).

    python -m dataset_tools export-woodscape DATA OUT

    OUT/rgb_images/<id>_<FV|RV|MVL|MVR>.png           the camera images, as rendered
    OUT/calibration/<id>_<cam>.json                    radial_poly k1..k4, cx/cy_offset, quaternion, translation
    OUT/semantic_annotations/gtLabels/<id>_<cam>.png   WoodScape 9-class ids (0 void) per pixel
    OUT/semantic_annotations/rgbLabels/<id>_<cam>.png  the same in WoodScape's colours
    OUT/instance_annotations/<id>_<cam>.json           vehicle polygons (tags, segmentation, id, z_order)
    OUT/box_2d_annotations/<id>_<cam>.txt              class_name,class_index,x_min,y_min,x_max,y_max
    OUT/export.json                                    ids -> our frames, class map, fit residuals

<id> is a 5-digit frame number in index order (all splits). Cameras: front FV, rear RV, left MVL,
right MVR. A camera of another model than radial_poly is fitted (k1..k4 by least squares in pixels
over the image) and the residual is reported in pixels per camera. Our vehicle frame is WoodScape's
(ISO 8855, origin on the ground below the rear axle midpoint).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from common.cli import ArgumentParser, run_cli
from common.errors import InputError
from common.files import build_folder, output_dir, write_bytes_atomic, write_json_atomic
from geometry.cameras import camera_from_dict
from geometry.rig import matrix_to_quat

from .format.layout import FrameFiles
from .format.passes import read_camera_passes
from .format.png import write_png_atomic
from .format.reader import DatasetIndex
from .labels.classes import CLASS_IDS

CAMERA_NAMES = {"front": "FV", "rear": "RV", "left": "MVL", "right": "MVR"}

# WoodScape's 9 semantic classes (scripts/configs/semantic_mapping_9_classes.json): index, colour (RGB;
# their file lists BGR for cv2.imwrite)
WOODSCAPE_CLASSES = ["void", "road", "lanemarks", "curb", "person", "rider", "vehicles", "bicycle", "motorcycle", "traffic_sign"]
WOODSCAPE_RGB = [(0, 0, 0), (255, 0, 255), (0, 0, 255), (0, 255, 0), (255, 0, 0), (255, 255, 255), (0, 255, 255), (255, 255, 0),
                 (255, 128, 128), (128, 128, 0)]
# our fine classes -> WoodScape's; everything else (sidewalk, building, vegetation, canopy, pole,
# bridge, pillar, terrain, barrier, the ego body, sky) is void, as WoodScape maps its own
# structure/pole/fence/green_strip/ego_vehicle; riders are people (pedestrian -> person), and
# WoodScape's rider and traffic_sign have no counterpart in our scenes.
FINE_TO_WOODSCAPE = {"road": "road", "parking": "road", "lane_marking": "lanemarks", "crosswalk": "lanemarks",
                     "stop_line": "lanemarks", "curb": "curb", "vehicle": "vehicles",
                     "pedestrian": "person", "bicycle": "bicycle", "motorcycle": "motorcycle"}
BOX_CLASS = ("vehicles", 0)  # scripts/configs/box_2d_mapping_5_classes.json
INSTANCE_TAG = "car"  # scripts/mappers/class_names.json: car -> vehicles


class ExportError(InputError):
    pass


def woodscape_lut() -> np.ndarray:
    lut = np.zeros(max(CLASS_IDS.values()) + 1, np.uint8)
    for fine, ws in FINE_TO_WOODSCAPE.items():
        lut[CLASS_IDS[fine]] = WOODSCAPE_CLASSES.index(ws)
    return lut


def radial_poly_fit(camera, step: int = 4):
    """(intrinsic dict in WoodScape's form, residual in pixels): the camera as radial_poly. An
    opencv_fisheye/equidistant/... camera is fitted: rho(theta) = fx * rho_model(theta) sampled over the
    angles the image sees, k1..k4 by least squares; the residual is the largest pixel distance, over
    the image's pixels, between the camera and the fit."""
    w, h = camera.width, camera.height
    if camera.model == "radial_poly":
        k, aspect = list(camera.k), camera.aspect_ratio
    else:
        if not hasattr(camera, "rho"):
            raise ExportError(f"camera model {camera.model}: not radially symmetric, no radial_poly fits it")
        import torch

        uv = camera.pixel_grid()[::step, ::step].reshape(-1, 2).numpy()
        rays, ok = camera.unproject(uv)
        theta_max = float(np.arctan2(np.linalg.norm(rays[ok, :2], axis=-1), rays[ok, 2]).max())
        theta = np.linspace(0, theta_max, 2000)
        rho = camera.fx * camera.rho(torch.from_numpy(theta)).numpy()
        a = np.stack([theta, theta ** 2, theta ** 3, theta ** 4], -1)
        k = [float(v) for v in np.linalg.lstsq(a, rho, rcond=None)[0]]
        aspect = camera.fy / camera.fx
    intr = {"aspect_ratio": float(aspect), "cx_offset": float(camera.cx - (w / 2 - 0.5)), "cy_offset": float(camera.cy - (h / 2 - 0.5)),
            "height": float(h), "k1": k[0], "k2": k[1], "k3": k[2], "k4": k[3], "model": "radial_poly", "poly_order": 4, "width": float(w)}
    fitted = camera_from_dict({"model": "radial_poly", "width": w, "height": h, "cx": camera.cx, "cy": camera.cy, "aspect_ratio": aspect, "k": k})
    if camera.model == "radial_poly":
        return intr, 0.0
    uv = camera.pixel_grid()[::step, ::step].reshape(-1, 2).numpy()
    rays, ok = camera.unproject(uv)
    back, valid = fitted.project(rays[ok])
    res = float(np.max(np.linalg.norm(back - uv[ok], axis=-1))) if valid.all() else math.inf
    return intr, res


def vehicle_polygons(semantic: np.ndarray, instance: np.ndarray):
    """[(instance id, [contour (n, 2) int]...)] of the vehicle instances seen in a camera image."""
    import cv2

    mask_all = (semantic == CLASS_IDS["vehicle"]) & (instance > 0)
    out = []
    for iid in np.unique(instance[mask_all]):
        mask = (mask_all & (instance == iid)).astype(np.uint8)
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        out.append((int(iid), [c[:, 0, :] for c in contours]))
    return out


PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def camera_png_bytes(path: Path) -> bytes:
    """A frame's camera PNG, checked: missing, empty (0 bytes) or not a PNG is bad input naming it."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise ExportError(f"{path}: missing (the frame has no image for this camera)") from None
    except IsADirectoryError:
        raise ExportError(f"{path}: is a folder, not a PNG") from None
    if not data:
        raise ExportError(f"{path}: empty (0 bytes), not a PNG")
    if not data.startswith(PNG_SIGNATURE) or b"IEND" not in data[-16:]:
        raise ExportError(f"{path}: not a whole PNG file")
    return data


def export_frame(ref, fid: str, out: Path, lut: np.ndarray) -> dict:
    from .format.meta import read_meta

    files = FrameFiles(ref.dir)
    rig = read_meta(files.dir).camera_rig()
    residuals = {}
    for rc in rig:
        if rc.name not in CAMERA_NAMES:
            raise ExportError(f"{files.meta}: camera '{rc.name}' has no WoodScape name (one of: {', '.join(CAMERA_NAMES)})")
        cam = CAMERA_NAMES[rc.name]
        stem = f"{fid}_{cam}"
        write_bytes_atomic(out / "rgb_images" / f"{stem}.png", camera_png_bytes(files.camera_png(rc.name)))
        passes = read_camera_passes(files.camera_exr(rc.name))
        camera = rc.camera
        h, w = passes["semantic"].shape
        if (camera.height, camera.width) != (h, w):
            camera = camera.resized(w, h)
        intr, residuals[cam] = radial_poly_fit(camera)
        calib = {"extrinsic": {"quaternion": matrix_to_quat(rc.cam_to_ego[:3, :3]), "translation": [float(v) for v in rc.cam_to_ego[:3, 3]]},
                 "intrinsic": intr, "name": cam}
        write_json_atomic(out / "calibration" / f"{stem}.json", calib, indent=2)
        sem = passes["semantic"]
        gt = lut[np.clip(sem, 0, len(lut) - 1)]
        write_png_atomic(out / "semantic_annotations" / "gtLabels" / f"{stem}.png", gt)
        write_png_atomic(out / "semantic_annotations" / "rgbLabels" / f"{stem}.png", np.asarray(WOODSCAPE_RGB, np.uint8)[gt])
        annotations, boxes = [], []
        for z, (iid, contours) in enumerate(vehicle_polygons(sem, passes["instance"])):
            for c in contours:
                ann = {"tags": [INSTANCE_TAG], "segmentation": c.tolist(), "id": iid, "z_order": z}
                if len(contours) > 1:
                    ann["group_id"] = iid  # one vehicle seen in several pieces
                annotations.append(ann)
            pts = np.concatenate(contours)
            boxes.append(f"{BOX_CLASS[0]},{BOX_CLASS[1]},{pts[:, 0].min()},{pts[:, 1].min()},{pts[:, 0].max()},{pts[:, 1].max()}")
        write_json_atomic(out / "instance_annotations" / f"{stem}.json",
                          {f"{stem}.png": {"image_width": w, "image_height": h, "image_channels": 3, "annotation": annotations}}, indent=None)
        write_bytes_atomic(out / "box_2d_annotations" / f"{stem}.txt", "".join(b + "\r\n" for b in boxes).encode())
    return residuals


def export(data, out) -> dict:
    """Export the data set `data` into `out`, atomically: everything is written into a hidden temp
    folder beside `out` (`.<out>.<pid>.tmp`), which then replaces `out` (an earlier export there,
    stale frames and calibrations included, goes as a whole); a failure leaves `out` as it was.
    `out` must be missing, empty or an earlier export (its export.json): other files are never removed."""
    index = DatasetIndex(data)
    return build_folder(out, lambda tmp: _export_into(index, data, tmp), "export.json")


def _export_into(index, data, out: Path) -> dict:
    lut = woodscape_lut()
    for sub in ("rgb_images", "calibration", "semantic_annotations/gtLabels", "semantic_annotations/rgbLabels", "instance_annotations",
                "box_2d_annotations"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    frames, worst = {}, {}
    for n, ref in enumerate(index.all_frames()):
        fid = f"{n:05d}"
        res = export_frame(ref, fid, out, lut)
        frames[fid] = {"scene": ref.scene, "frame": ref.frame, "split": ref.split, "fit_residual_px": res}
        for cam, r in res.items():
            worst[cam] = max(worst.get(cam, 0.0), r)
    summary = {"source": str(Path(data)), "cameras": CAMERA_NAMES, "classes": WOODSCAPE_CLASSES,
               "fine_to_woodscape": {fine: FINE_TO_WOODSCAPE.get(fine, "void") for fine in CLASS_IDS},
               "max_fit_residual_px": worst, "frames": frames}
    write_json_atomic(out / "export.json", summary, indent=1)
    return summary


def main(argv=None) -> int:
    p = ArgumentParser(prog="python -m dataset_tools export-woodscape", description="Export a data set in the WoodScape layout.")
    p.add_argument("data", help="a fused data set (index.json)")
    p.add_argument("out", help="output folder")
    a = p.parse_args(argv)
    output_dir(Path(a.out), "OUT")
    s = export(a.data, a.out)
    print(f"written {len(s['frames'])} frames x {len(CAMERA_NAMES)} cameras to {a.out}; radial_poly fit residual (max px): "
          + ", ".join(f"{c} {r:.3g}" for c, r in s["max_fit_residual_px"].items()))
    return 0


if __name__ == "__main__":
    run_cli(main)
