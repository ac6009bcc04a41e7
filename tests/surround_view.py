"""The rig of tests/data/surround_view from its own files: the cv2.fisheye intrinsics and, for the
pose, each camera's ground homography `project_matrix` (undistorted image -> the 1 cm/pixel
bird's-eye view of its author's stitcher, surround_view/param_settings.py and birdview.py of
neozhaoliang/surround-view-system-introduction). Vehicle frame of this rig: origin on the ground at
the centre of the 6 m x 10 m calibration mat, x forward, y left, z up."""

import numpy as np

from geometry.calib_import import pose_from_ground_homography, read_opencv_storage
from geometry.rig import matrix_to_quat

NAMES = ("front", "back", "left", "right")
TOTAL_W, TOTAL_H = 1200, 1600  # the bird's-eye view, pixels of 1 cm: x right, y down, front at the top


def ego_to_projected(name: str) -> np.ndarray:
    """Ego (x, y, 1) in metres -> that camera's projected image (u, v, 1): the inverse of the author's
    flips (front as is, back turned 180 degrees, left and right transposed) after ego -> bird's-eye view."""
    to_bev = np.array([[0, -100, TOTAL_W / 2 - 0.5], [-100, 0, TOTAL_H / 2 - 0.5], [0, 0, 1.0]])
    flip = {"front": np.eye(3), "back": np.array([[-1, 0, TOTAL_W - 1], [0, -1, TOTAL_H - 1], [0, 0, 1.0]]),
            "left": np.array([[0, -1, TOTAL_H - 1], [1, 0, 0], [0, 0, 1.0]]),
            "right": np.array([[0, 1, 0], [-1, 0, TOTAL_W - 1], [0, 0, 1.0]])}[name]
    return flip @ to_bev


def camera_pose(path, name: str) -> np.ndarray:
    """cam_to_ego (4x4) from the file's K, scale_xy, shift_xy (the undistorted image's camera) and project_matrix."""
    d = read_opencv_storage(path)
    K, s, sh = d["camera_matrix"], d["scale_xy"].ravel(), d["shift_xy"].ravel()
    k_new = K.copy()
    k_new[0, 0] *= s[0]
    k_new[1, 1] *= s[1]
    k_new[0, 2] += sh[0]
    k_new[1, 2] += sh[1]
    return pose_from_ground_homography(np.linalg.inv(k_new) @ np.linalg.inv(d["project_matrix"]) @ ego_to_projected(name))


def rig_yaml_dict(folder) -> dict:
    cams = {}
    for n in NAMES:
        m = camera_pose(f"{folder}/{n}.yaml", n)
        cams[n] = {"calibration": f"{n}.yaml", "format": "opencv_fisheye",
                   "extrinsics": {"translation": [round(float(v), 6) for v in m[:3, 3]],
                                  "quaternion": [round(v, 8) for v in matrix_to_quat(m[:3, :3])]}}
    return {"name": "surround_view_eu5", "cameras": cams}


if __name__ == "__main__":  # writes tests/data/surround_view/rig.yaml
    import yaml

    folder = "tests/data/surround_view"
    head = "# " + __doc__.replace("\n", "\n# ") + "\n# Written by `PYTHONPATH=. python tests/surround_view.py` (extrinsics from each file's project_matrix).\n"
    with open(f"{folder}/rig.yaml", "w") as f:
        f.write(head + yaml.safe_dump(rig_yaml_dict(folder), sort_keys=False))
