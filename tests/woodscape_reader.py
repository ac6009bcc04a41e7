"""A reader of the WoodScape layout written from its published description (github.com/valeoai/WoodScape:
README, scripts/calibration/calibration_readme.txt, the annotation parsers and generators), independent
of our exporter and of geometry/: used by tests/test_export_woodscape.py."""

import csv
import json
from pathlib import Path

import cv2
import numpy as np


def frame_ids(root) -> list[tuple[str, str]]:
    """(id, camera) of every rgb_images/<id>_<cam>.png."""
    return sorted(tuple(p.stem.split("_", 1)) for p in Path(root, "rgb_images").glob("*.png"))


def rgb(root, fid, cam) -> np.ndarray:
    return cv2.imread(str(Path(root, "rgb_images", f"{fid}_{cam}.png")), cv2.IMREAD_COLOR)[..., ::-1]


def gt_labels(root, fid, cam) -> np.ndarray:
    return cv2.imread(str(Path(root, "semantic_annotations", "gtLabels", f"{fid}_{cam}.png")), cv2.IMREAD_UNCHANGED)


def boxes(root, fid, cam) -> list[tuple[str, int, int, int, int, int]]:
    """box_2d_annotations: csv rows class_name, class_index, left, top, right, bottom (0-based pixels)."""
    with open(Path(root, "box_2d_annotations", f"{fid}_{cam}.txt"), newline="") as f:
        return [(r[0], int(r[1]), *map(int, r[2:6])) for r in csv.reader(f) if r]


def instances(root, fid, cam) -> dict:
    """instance_annotations JSON: one entry (keyed by the image) with image_width/height/channels and
    `annotation`, a list of objects with `tags` (one class tag), `segmentation` ([[x, y], ...]), `id`, `z_order`."""
    data = json.loads(Path(root, "instance_annotations", f"{fid}_{cam}.json").read_text())
    return next(iter(data.values()))


def polygon_mask(entry: dict, tag: str) -> np.ndarray:
    """The pixels of the polygons of `tag`, filled as semantic_map_generator.py fills them."""
    m = np.zeros((entry["image_height"], entry["image_width"]), np.uint8)
    for a in sorted(entry["annotation"], key=lambda a: a["z_order"]):
        if a["tags"] == [tag]:
            cv2.fillPoly(m, [np.array(a["segmentation"]).astype(int)], 1)
    return m.astype(bool)


def calibration(root, fid, cam) -> dict:
    return json.loads(Path(root, "calibration", f"{fid}_{cam}.json").read_text())


def quaternion_matrix(q) -> np.ndarray:
    """[qx, qy, qz, qw] (scipy's from_quat order, as the readme says) -> rotation matrix."""
    x, y, z, w = np.asarray(q, float) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def project(calib: dict, points_vehicle: np.ndarray) -> np.ndarray:
    """The readme's projection: vehicle -> camera by the inverse of (quaternion, translation), then
    rho(theta) = k1 theta + ... + k4 theta^4, u = rho X/chi + cx + width/2 - 0.5, v = rho Y/chi * aspect_ratio + cy + height/2 - 0.5."""
    e, i = calib["extrinsic"], calib["intrinsic"]
    r = quaternion_matrix(e["quaternion"])
    p = (points_vehicle - np.asarray(e["translation"])) @ r  # R^T (p - t)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    chi = np.sqrt(x * x + y * y)
    theta = np.pi / 2 - np.arctan2(z, chi)
    rho = i["k1"] * theta + i["k2"] * theta ** 2 + i["k3"] * theta ** 3 + i["k4"] * theta ** 4
    safe = np.where(chi != 0, chi, 1.0)
    u = np.where(chi != 0, rho * x / safe, 0.0) + i["cx_offset"] + i["width"] / 2 - 0.5
    v = np.where(chi != 0, rho * y / safe, 0.0) * i["aspect_ratio"] + i["cy_offset"] + i["height"] / 2 - 0.5
    return np.stack([u, v], -1)


