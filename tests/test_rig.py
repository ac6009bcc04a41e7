"""Rigs: conventions of the mount angles, quaternions, files and WoodScape import."""

from pathlib import Path

import numpy as np
import pytest

from geometry.bev import BevGrid
from geometry.rig import RigError, load_rig, matrix_to_quat, mount_rotation, quat_to_matrix, rig_from_dict

WOODSCAPE = str(Path(__file__).parent / "data" / "woodscape" / "front.json")


def test_mount_angles_point_the_optical_axis():
    z = np.array([0, 0, 1.0])
    np.testing.assert_allclose(mount_rotation(0, 0) @ z, [1, 0, 0], atol=1e-12)  # forward
    np.testing.assert_allclose(mount_rotation(90, 0) @ z, [0, 1, 0], atol=1e-12)  # left
    np.testing.assert_allclose(mount_rotation(0, 90) @ z, [0, 0, -1], atol=1e-12)  # straight down
    # a forward camera's x (image right) is ego right (-y) and its y (image down) is ego down
    np.testing.assert_allclose(mount_rotation(0, 0) @ [1, 0, 0], [0, -1, 0], atol=1e-12)
    np.testing.assert_allclose(mount_rotation(0, 0) @ [0, 1, 0], [0, 0, -1], atol=1e-12)
    # roll turns the image clockwise: image right moves towards ego down
    np.testing.assert_allclose(mount_rotation(0, 0, 90) @ [1, 0, 0], [0, 0, -1], atol=1e-12)


def test_quaternion_round_trip():
    rng = np.random.default_rng(0)
    for _ in range(100):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        m = quat_to_matrix(q)
        np.testing.assert_allclose(m @ m.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(m) == pytest.approx(1)
        np.testing.assert_allclose(quat_to_matrix(matrix_to_quat(m)), m, atol=1e-12)


@pytest.mark.parametrize("path", ["configs/rigs/default.yaml", "configs/rigs/mixed.yaml"])
def test_shipped_rigs(path, tmp_path):
    rig = load_rig(path)
    assert {"front", "rear", "left", "right"} <= set(rig.names)
    for rc in rig:
        assert rc.camera.width == 480 and rc.camera.height == 302
        assert rc.cam_to_ego[2, 3] > 0.3  # mounted above the ground
    # every cell within 5 m around the car's body is seen by some camera (no hole in the surround view)
    grid = BevGrid(x_min=-6, x_max=9, y_min=-6, y_max=6, res=0.5)
    centres = grid.cell_centres().reshape(-1, 2)
    seen = np.zeros(len(centres), bool)
    for rc in rig:
        uv, valid = rc.project_ego(np.c_[centres, np.zeros(len(centres))])
        seen |= valid & rc.camera.inside(uv)
    near = (np.abs(centres[:, 0] - 1.35) < 5) & (np.abs(centres[:, 1]) < 5)
    body = (centres[:, 0] > -1.6) & (centres[:, 0] < 4.3) & (np.abs(centres[:, 1]) < 1.5)
    assert seen[near & ~body].all()
    assert not seen[(np.abs(centres[:, 0] - 1.35) < 0.5) & (np.abs(centres[:, 1]) < 0.5)].any()  # under the car
    # the rig writes itself out and reads back the same
    out = tmp_path / "rig.json"
    rig.save(out)
    again = load_rig(out)
    for a, b in zip(rig, again):
        assert a.camera == b.camera
        np.testing.assert_allclose(a.cam_to_ego, b.cam_to_ego, atol=1e-12)


def test_front_camera_pitched_down_sees_near_ground_below_centre():
    rc = load_rig("configs/rigs/default.yaml")["front"]  # 0.6 m high, pitched 20 degrees down
    uv, valid = rc.project_ego(np.array([[4.75, 0.0, 0.0], [20.0, 0.0, 0.0], [20.0, 3.0, 0.0], [20.0, 0.0, 5.0]]))
    assert valid.all()
    assert uv[0, 1] > rc.camera.cy  # ground 1 m ahead (31 degrees down): below the principal point
    assert uv[1, 1] < rc.camera.cy  # ground 16 m ahead (2 degrees down): above it
    assert abs(uv[0, 0] - rc.camera.cx) < 1 and abs(uv[1, 0] - rc.camera.cx) < 1  # straight ahead: centre column
    assert uv[2, 0] < uv[1, 0]  # a point to the left appears left
    assert uv[3, 1] < uv[1, 1]  # higher appears higher


def test_woodscape_import():
    rig = load_rig(WOODSCAPE)
    rc = rig["FV"]
    cam = rc.camera
    assert cam.model == "radial_poly" and (cam.width, cam.height) == (1280, 966)
    assert cam.cx == pytest.approx(1280 / 2 - 0.5 + 3.942) and cam.cy == pytest.approx(966 / 2 - 0.5 - 3.093)
    assert cam.k == [339.749, -31.988, 48.275, -7.201]
    np.testing.assert_allclose(rc.cam_to_ego[:3, 3], [3.7484, 0.0, 0.66017])
    axis = rc.cam_to_ego[:3, :3] @ [0, 0, 1]
    assert axis[0] > 0.9 and axis[2] < -0.3  # front camera looking forward and down
    right = rc.cam_to_ego[:3, :3] @ [1, 0, 0]
    assert right[1] < -0.99  # image right is the car's right


@pytest.mark.parametrize(
    "d, message",
    [
        ({}, "'cameras' must be a non-empty mapping"),
        ({"cameras": {"a": {"intrinsics": {}}}}, "cameras.a: needs 'intrinsics' and 'extrinsics'"),
        ({"cameras": {"a": {"intrinsics": {"model": "pinhole"}, "extrinsics": {}}}}, "cameras.a.intrinsics: pinhole: missing key 'width'"),
        (
            {"cameras": {"a": {"intrinsics": {"model": "pinhole", "width": 4, "height": 4, "fx": 1, "fy": 1, "cx": 1, "cy": 1},
                               "extrinsics": {"translation": [0, 0, 1], "rotation": {"yaw": 3}}}}},
            "cameras.a.extrinsics.rotation: unknown key 'yaw'",
        ),
        (
            {"cameras": {"a": {"intrinsics": {"model": "pinhole", "width": 4, "height": 4, "fx": 1, "fy": 1, "cx": 1, "cy": 1},
                               "extrinsics": {"translation": [0, 0], "quaternion": [0, 0, 0, 1]}}}},
            "cameras.a.extrinsics.translation: must be a list of 3 finite numbers",
        ),
    ],
)
def test_bad_rigs_name_file_and_field(d, message):
    with pytest.raises(RigError, match=message.replace("(", r"\(").replace(")", r"\)")):
        rig_from_dict(d, "my_rig.yaml")


def test_unreadable_rig_file(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("cameras: [1, 2\n")
    with pytest.raises(RigError, match="bad.yaml: not valid YAML"):
        load_rig(bad)
    with pytest.raises(RigError, match="missing.yaml: missing"):
        load_rig(tmp_path / "missing.yaml")
