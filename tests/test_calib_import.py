"""Calibration import (geometry.calib_import, rig assembly in geometry.rig) on real calibrations:
tests/data/surround_view (cv2.fisheye, neozhaoliang/surround-view-system-introduction, MIT) and
tests/data/woodscape; Kalibr and OCamCalib files written from their documented formats."""

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from geometry.calib_import import (CalibrationError, import_calibration, kalibr_cameras, ocamcalib_camera, opencv_fisheye_camera,
                                   read_opencv_storage, read_ocamcalib)
from geometry.cameras import camera_from_dict
from geometry.rig import RigError, load_rig

from surround_view import NAMES, camera_pose

DATA = Path(__file__).parent / "data"
SV = DATA / "surround_view"


def _points_in_front(n=2000, max_deg=85.0, seed=0):
    rng = np.random.default_rng(seed)
    theta = np.radians(rng.uniform(0, max_deg, n))
    phi = rng.uniform(-np.pi, np.pi, n)
    d = rng.uniform(0.5, 20, n)
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1) * d[:, None]


@pytest.mark.parametrize("name", NAMES)
def test_opencv_fisheye_file_is_cv2_fisheye_exactly(name):
    cam = opencv_fisheye_camera(SV / f"{name}.yaml")
    fs = cv2.FileStorage(str(SV / f"{name}.yaml"), cv2.FILE_STORAGE_READ)
    K, D = fs.getNode("camera_matrix").mat(), fs.getNode("dist_coeffs").mat()
    assert (cam.width, cam.height) == tuple(int(v) for v in fs.getNode("resolution").mat().ravel())
    p = _points_in_front()
    ref, _ = cv2.fisheye.projectPoints(p[:, None, :], np.zeros(3), np.zeros(3), K, D)
    uv, valid = cam.project(p)
    assert valid.all()
    assert np.abs(uv - ref[:, 0]).max() <= 1e-6
    # and back: our unprojection of cv2's pixels gives the rays again (round trip <= 1e-6 px)
    rays, ok = cam.unproject(ref[:, 0])
    back, _ = cv2.fisheye.projectPoints(rays[:, None, :], np.zeros(3), np.zeros(3), K, D)
    assert ok.all() and np.abs(back[:, 0] - ref[:, 0]).max() <= 1e-6


def test_opencv_filestorage_written_by_cv2_yaml_and_json(tmp_path):
    K = np.array([[310.5, 0, 481.25], [0, 311.0, 322.5], [0, 0, 1]])
    D = np.array([[0.01], [-0.02], [0.003], [-0.0004]])
    for suffix in (".yaml", ".json"):
        path = str(tmp_path / f"cam{suffix}")
        fs = cv2.FileStorage(path, cv2.FILE_STORAGE_WRITE)
        fs.write("K", K)
        fs.write("D", D)
        fs.write("image_width", 960)
        fs.write("image_height", 640)
        fs.release()
        cam = opencv_fisheye_camera(path)
        assert cam.to_dict() == {"model": "opencv_fisheye", "width": 960, "height": 640, "fx": 310.5, "fy": 311.0, "cx": 481.25,
                                 "cy": 322.5, "k": D.ravel().tolist()}


def test_opencv_fisheye_round_trip_through_cv2(tmp_path):
    """ours -> FileStorage YAML -> cv2.FileStorage and ours again: the same numbers, the same pixels."""
    from geometry.calib_import import opencv_fisheye_yaml

    cam = opencv_fisheye_camera(SV / "left.yaml")
    path = _write(tmp_path / "out.yaml", opencv_fisheye_yaml(cam))
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    K, D = fs.getNode("K").mat(), fs.getNode("D").mat()
    assert (int(fs.getNode("image_width").real()), int(fs.getNode("image_height").real())) == (cam.width, cam.height)
    np.testing.assert_array_equal(K, [[cam.fx, 0, cam.cx], [0, cam.fy, cam.cy], [0, 0, 1]])
    np.testing.assert_array_equal(D.ravel(), cam.k)
    assert opencv_fisheye_camera(path) == cam


def test_opencv_bad_files_are_one_line_naming_the_field(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text((SV / "front.yaml").read_text().replace("dist_coeffs", "distortion"))
    with pytest.raises(CalibrationError, match="bad.yaml: missing the distortion coefficients"):
        opencv_fisheye_camera(bad)
    bad.write_text((SV / "front.yaml").read_text().replace("   cols: 1\n   dt: d", "   cols: 2\n   dt: d", 1))
    with pytest.raises(CalibrationError, match=r"bad.yaml: dist_coeffs: rows x cols = 8, but data has 4"):
        opencv_fisheye_camera(bad)
    with pytest.raises(CalibrationError, match="cannot tell its format"):
        import_calibration(_write(tmp_path / "x.yaml", "a: 1\n"))
    # negative rows/cols, aliases (a billion numbers once expanded), a lost digit
    bad.write_text((SV / "front.yaml").read_text().replace("   rows: 4\n   cols: 1", "   rows: -2\n   cols: -2", 1))
    with pytest.raises(CalibrationError, match=r"bad.yaml: dist_coeffs: needs whole 'rows' and 'cols' >= 1, got -2 x -2"):
        opencv_fisheye_camera(bad)
    bomb = "%YAML:1.0\n---\na: &a [1, 1, 1, 1, 1, 1, 1, 1, 1]\n" + "".join(
        f"{c}: &{c} [{', '.join(['*' + q] * 9)}]\n" for q, c in zip("abcdefgh", "bcdefghi")) + "K: *i\nD: [0, 0, 0, 0]\n"
    with pytest.raises(CalibrationError, match=r"bad.yaml: not valid YAML \(YAML aliases"):
        opencv_fisheye_camera(_write(bad, bomb))
    with pytest.raises(CalibrationError, match=r"bad.yaml: camera_matrix \(cx, cy\): \(496.64, 331.2\) is outside the 96x640 image"):
        opencv_fisheye_camera(_write(bad, (SV / "front.yaml").read_text().replace("data: [ 960, 640 ]", "data: [ 96, 640 ]")))
    with pytest.raises(CalibrationError, match=r"bad.yaml: resolution: must be whole numbers of pixels in \[1, 100000\], got 9600000.0 x 640"):
        opencv_fisheye_camera(_write(bad, (SV / "front.yaml").read_text().replace("data: [ 960, 640 ]", "data: [ 9600000, 640 ]")))


# ---------------------------------------------------------------- cv2.omnidir (Mei's model): exact, as its own camera


def omnidir_reference(p, K, D, xi):
    """cv2.omnidir.projectPoints written from its published formula (OpenCV ccalib omnidir.cpp;
    Mei and Rives 2007), independently of geometry.cameras: the unit-sphere point shifted by xi,
    radial-tangential distortion (k1, k2, p1, p2), then K with its skew."""
    xs = p / np.linalg.norm(p, axis=-1, keepdims=True)
    x, y = xs[:, 0] / (xs[:, 2] + xi), xs[:, 1] / (xs[:, 2] + xi)
    k1, k2, p1, p2 = D
    r2 = x * x + y * y
    rad = 1 + k1 * r2 + k2 * r2 * r2
    xd = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([K[0, 0] * xd + K[0, 1] * yd + K[0, 2], K[1, 1] * yd + K[1, 2]], -1)


OMNI_K = np.array([[385.2, 0.35, 481.7], [0, 383.9, 318.4], [0, 0, 1]])
OMNI_D = np.array([-0.271, 0.083, 0.0011, -0.0007])
OMNI_XI = 1.12


def _omnidir_file(path):
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)  # as a cv2.omnidir.calibrate script saves it
    fs.write("K", OMNI_K)
    fs.write("D", OMNI_D[None])
    fs.write("xi", np.array([[OMNI_XI]]))
    fs.write("image_width", 960)
    fs.write("image_height", 640)
    fs.release()
    return path


def test_omnidir_file_is_mei_exactly(tmp_path):
    """A cv2.omnidir calibration (with xi) was read as cv2.fisheye and reported exact, a
    pixel landing ~200 px off. It is Mei's model: our `mei` camera, exact against the formula."""
    imp = import_calibration(_omnidir_file(tmp_path / "omni.yaml"))
    cam = imp.camera
    assert cam.model == "mei" and not imp.fitted and imp.residual_px == 0 and imp.describe() == "mei (exact)"
    assert (cam.width, cam.height, cam.xi, cam.s) == (960, 640, OMNI_XI, 0.35)
    p = _points_in_front(3000, 100, seed=3)
    ref = omnidir_reference(p, OMNI_K, OMNI_D, OMNI_XI)
    uv, valid = cam.project(p)
    assert valid.all() and np.abs(uv - ref).max() <= 1e-9
    rays, ok = cam.unproject(ref)  # and back: the rays of cv2's pixels
    assert ok.all() and np.abs(omnidir_reference(rays, OMNI_K, OMNI_D, OMNI_XI) - ref).max() <= 1e-7
    # what reading it as cv2.fisheye (xi ignored) gave: far off, so the check above can fail
    as_fisheye = camera_from_dict({"model": "opencv_fisheye", "width": 960, "height": 640, "fx": 385.2, "fy": 383.9, "cx": 481.7,
                                   "cy": 318.4, "k": list(OMNI_D)})
    assert np.abs(as_fisheye.project(p)[0] - ref).max() > 50


def test_mei_camera_matches_cv2_omnidir_itself(tmp_path):
    """Against cv2.omnidir.projectPoints where opencv-contrib is installed (it is not in
    requirements.txt: run with it on PYTHONPATH to check)."""
    if not hasattr(cv2, "omnidir"):
        pytest.skip("cv2.omnidir needs opencv-contrib")
    cam = import_calibration(_omnidir_file(tmp_path / "omni.yaml")).camera
    p = _points_in_front(3000, 100, seed=4)
    ref, _ = cv2.omnidir.projectPoints(p[:, None, :], np.zeros(3), np.zeros(3), OMNI_K, OMNI_XI, OMNI_D[None])
    uv, valid = cam.project(p)
    assert valid.all() and np.abs(uv - ref[:, 0]).max() <= 1e-6
    # and cv2.omnidir's own undistortion of our pixels gives our rays back (it returns x/z, y/z: in front only)
    uv = uv[p[:, 2] > 0.2 * np.linalg.norm(p, axis=-1)]
    und = cv2.omnidir.undistortPoints(uv[:, None, :], OMNI_K, OMNI_D[None], np.array([[OMNI_XI]]), np.eye(3))[:, 0]
    rays, _ = cam.unproject(uv)
    assert np.abs(und - rays[:, :2] / rays[:, 2:]).max() <= 1e-9


def _write(path, text):
    path.write_text(text)
    return path


# ---------------------------------------------------------------- Kalibr (format of its wiki's camchain.yaml)

CAMCHAIN = """\
cam0:
  T_cam_imu:
  - [0.0, -1.0, 0.0, 0.05]
  - [0.0, 0.0, -1.0, 0.10]
  - [1.0, 0.0, 0.0, -0.20]
  - [0.0, 0.0, 0.0, 1.0]
  cam_overlaps: [1]
  camera_model: pinhole
  distortion_coeffs: [-0.0132, 0.0341, -0.0421, 0.0155]
  distortion_model: equidistant
  intrinsics: [280.1, 281.2, 321.4, 241.7]
  resolution: [640, 480]
  rostopic: /cam0/image_raw
cam1:
  T_cn_cnm1:
  - [1.0, 0.0, 0.0, -0.11]
  - [0.0, 1.0, 0.0, 0.0]
  - [0.0, 0.0, 1.0, 0.0]
  - [0.0, 0.0, 0.0, 1.0]
  camera_model: omni
  distortion_coeffs: [0.0, 0.0, 0.0, 0.0]
  distortion_model: none
  intrinsics: [0.8, 520.0, 521.0, 320.5, 240.5]
  resolution: [640, 480]
cam2:
  T_cam_imu:
  - [1.0, 0.0, 0.0, 0.0]
  - [0.0, 1.0, 0.0, 0.0]
  - [0.0, 0.0, 1.0, 0.0]
  - [0.0, 0.0, 0.0, 1.0]
  camera_model: ds
  distortion_coeffs: []
  distortion_model: none
  intrinsics: [-0.2, 0.6, 180.0, 180.5, 319.5, 239.5]
  resolution: [640, 480]
cam3:
  T_cam_imu:
  - [1.0, 0.0, 0.0, 0.0]
  - [0.0, 1.0, 0.0, 0.0]
  - [0.0, 0.0, 1.0, 0.0]
  - [0.0, 0.0, 0.0, 1.0]
  camera_model: pinhole
  distortion_coeffs: [-0.28, 0.07, 0.0002, -0.0001]
  distortion_model: radtan
  intrinsics: [458.6, 457.3, 367.2, 248.4]
  resolution: [752, 480]
"""


def test_kalibr_camchain(tmp_path):
    path = _write(tmp_path / "camchain.yaml", CAMCHAIN)
    cams = kalibr_cameras(path)
    # pinhole-equi is cv2.fisheye: exact
    c0 = cams["cam0"]
    assert c0.camera.model == "opencv_fisheye" and c0.residual_px == 0
    K = np.array([[280.1, 0, 321.4], [0, 281.2, 241.7], [0, 0, 1]])
    p = _points_in_front(500, 80)
    ref, _ = cv2.fisheye.projectPoints(p[:, None], np.zeros(3), np.zeros(3), K, np.array([-0.0132, 0.0341, -0.0421, 0.0155]))
    assert np.abs(c0.camera.project(p)[0] - ref[:, 0]).max() <= 1e-6
    # T_cam_imu maps IMU points to the camera: our pose is its inverse
    t = np.array(json.loads(json.dumps([[0.0, -1, 0, 0.05], [0, 0, -1, 0.10], [1, 0, 0, -0.20], [0, 0, 0, 1]])))
    np.testing.assert_allclose(c0.cam_to_ref @ t, np.eye(4), atol=1e-12)
    # omni without distortion is Mei's model: u = gamma x / (z + xi |p|) + c
    c1 = cams["cam1"].camera
    assert c1.model == "ucm"
    d = np.linalg.norm(p, axis=-1)
    mei = np.stack([520.0 * p[:, 0] / (p[:, 2] + 0.8 * d) + 320.5, 521.0 * p[:, 1] / (p[:, 2] + 0.8 * d) + 240.5], -1)
    assert np.abs(c1.project(p)[0] - mei).max() <= 1e-9
    # cam1's pose comes from T_cn_cnm1: cam1 = T cam0, so cam1 -> imu = (cam0 -> imu) T^-1
    t10 = np.eye(4)
    t10[0, 3] = -0.11
    np.testing.assert_allclose(cams["cam1"].cam_to_ref, c0.cam_to_ref @ np.linalg.inv(t10), atol=1e-12)
    assert cams["cam2"].camera.model == "double_sphere" and cams["cam2"].camera.xi == -0.2
    # pinhole-radtan is Mei's model with xi = 0 (exact, no longer fitted): OpenCV's own
    # pinhole projection with k1, k2, p1, p2 is the reference
    c3 = cams["cam3"]
    assert c3.camera.model == "mei" and c3.residual_px == 0 and not c3.fitted
    K3 = np.array([[458.6, 0, 367.2], [0, 457.3, 248.4], [0, 0, 1]])
    p3 = _points_in_front(500, 45)
    ref3, _ = cv2.projectPoints(p3, np.zeros(3), np.zeros(3), K3, np.array([-0.28, 0.07, 0.0002, -0.0001]))
    assert np.abs(c3.camera.project(p3)[0] - ref3[:, 0]).max() <= 1e-6


def test_kalibr_omni_radtan_is_mei_exactly(tmp_path):
    """Kalibr's omni + radtan (once fitted, 6.8 px reported where it reached 39 px) is Mei's
    model: exact against the formula over the whole field of view."""
    text = CAMCHAIN.replace("distortion_coeffs: [0.0, 0.0, 0.0, 0.0]\n  distortion_model: none\n  intrinsics: [0.8, 520.0",
                            "distortion_coeffs: [-0.12, 0.02, 0.0004, -0.0002]\n  distortion_model: radtan\n  intrinsics: [0.8, 520.0")
    c1 = kalibr_cameras(_write(tmp_path / "camchain.yaml", text))["cam1"]
    assert c1.camera.model == "mei" and c1.residual_px == 0 and not c1.fitted
    K = np.array([[520.0, 0, 320.5], [0, 521.0, 240.5], [0, 0, 1]])
    p = _points_in_front(2000, 110, seed=5)
    uv, valid = c1.camera.project(p)
    assert valid.all() and np.abs(uv - omnidir_reference(p, K, [-0.12, 0.02, 0.0004, -0.0002], 0.8)).max() <= 1e-9


def test_kalibr_pinhole_equi_with_zero_coefficients_is_equidistant(tmp_path):
    path = _write(tmp_path / "camchain.yaml", CAMCHAIN.replace("[-0.0132, 0.0341, -0.0421, 0.0155]", "[0.0, 0.0, 0.0, 0.0]"))
    cam = kalibr_cameras(path)["cam0"].camera
    equi = camera_from_dict({"model": "equidistant", "width": 640, "height": 480, "fx": 280.1, "fy": 281.2, "cx": 321.4, "cy": 241.7})
    p = _points_in_front(200, 100)
    assert np.abs(cam.project(p)[0] - equi.project(p)[0]).max() < 1e-9


def test_kalibr_bad_field(tmp_path):
    path = _write(tmp_path / "camchain.yaml", CAMCHAIN.replace("camera_model: ds", "camera_model: fov"))
    with pytest.raises(CalibrationError, match=r"camchain.yaml: cam2: camera_model: 'fov' is not one of"):
        kalibr_cameras(path)
    path = _write(tmp_path / "camchain.yaml", CAMCHAIN.replace("resolution: [640, 480]\n  rostopic", "resolution: [640]\n  rostopic"))
    with pytest.raises(CalibrationError, match=r"cam0: resolution: must have 2 numbers, has 1"):
        kalibr_cameras(path)
    # a T_cam_imu with determinant -1 is a reflection (the camera would look backwards)
    path = _write(tmp_path / "camchain.yaml", CAMCHAIN.replace("- [0.0, 0.0, -1.0, 0.10]", "- [0.0, 0.0, 1.0, 0.10]", 1))
    with pytest.raises(CalibrationError, match=r"cam0: T_cam_imu: a reflection \(determinant -1\), not a rotation"):
        kalibr_cameras(path)
    path = _write(tmp_path / "camchain.yaml", CAMCHAIN.replace("[280.1, 281.2, 321.4, 241.7]", "[280.1, 281.2, 3214.0, 241.7]"))
    with pytest.raises(CalibrationError, match=r"cam0: intrinsics \(cx, cy\): \(3214, 241.7\) is outside the 640x480 image"):
        kalibr_cameras(path)


# ---------------------------------------------------------------- OCamCalib (calib_results.txt as ocam_functions.c reads it)


def _ocam_text(pol, invpol, center, affine, size):
    def line(v):
        return " ".join(f"{x:.12e}" for x in v)

    return (f"#polynomial coefficients for the DIRECT mapping function (ocam_model.ss in MATLAB). These are used by cam2world\n\n"
            f"{len(pol)} {line(pol)} \n\n"
            f"#polynomial coefficients for the inverse mapping function (ocam_model.invpol in MATLAB). These are used by world2cam\n\n"
            f"{len(invpol)} {line(invpol)} \n\n"
            f"#center: \"row\" and \"column\" coordinates (x, y) of the center of the image\n\n{line(center)}\n\n"
            f"#affine parameters \"c\", \"d\", \"e\"\n\n{line(affine)}\n\n"
            f"#image size: \"height\" and \"width\"\n\n{size[0]} {size[1]}\n\n")


def test_ocamcalib_fitted_with_residual(tmp_path):
    # a typical fisheye pol (a0 < 0, a1 = 0): rays through the file's own cam2world, fitted by opencv_fisheye
    pol = [-250.0, 0.0, 1.2e-3, -1.0e-6, 2.0e-9]
    path = _write(tmp_path / "calib_results.txt", _ocam_text(pol, [300.0, 150.0], [481.2, 639.7], [1.0, 0.0, 0.0], (960, 1280)))
    m = read_ocamcalib(path)
    imp = ocamcalib_camera(path)
    cam = imp.camera
    assert (cam.width, cam.height, cam.cx, cam.cy, cam.fx) == (1280, 960, 639.7, 481.2, 250.0)
    # a polynomial in rho fitted by one in theta: close, not exact; the residual covers the whole field of
    # view, here the whole image (136 degrees from the axis in the corners; measured 2.99 px, 0.11 px
    # within 100 degrees, which is all that was once reported)
    assert imp.fitted and 1.0 < imp.residual_px < 5.0 and imp.describe().startswith("opencv_fisheye (fitted, residual")
    dense = np.stack(np.meshgrid(np.arange(0, 1280, 3.0), np.arange(0, 960, 3.0)), -1).reshape(-1, 2)
    rays = m.cam2world(dense)
    assert np.degrees(np.arccos(rays[:, 2].min())) > 130
    back, ok = cam.project(rays)
    err = np.linalg.norm(back - dense, axis=-1)
    assert ok.all() and imp.residual_px - 1e-9 <= err.max() <= 1.02 * imp.residual_px  # the stated residual is the true worst
    near = rays[:, 2] > math.cos(math.radians(100))
    assert err[~near].max() > 2 * err[near].max()  # the worst is beyond 100 degrees, where nothing was measured before
    # the centre is (row, column): the ray of the centre pixel looks straight forward
    np.testing.assert_allclose(m.cam2world(np.array([[639.7, 481.2]])), [[0, 0, 1]], atol=1e-12)
    # a pixel to the right of the centre sees a ray to the right (x > 0), one below sees y > 0
    r = m.cam2world(np.array([[800.0, 481.2], [639.7, 700.0]]))
    assert r[0, 0] > 0 and abs(r[0, 1]) < 1e-12 and r[1, 1] > 0
    # the affine part (c != 1) is not radial: the residual shows it
    skew = _write(tmp_path / "skew.txt", _ocam_text(pol, [300.0], [481.2, 639.7], [1.02, 0.001, 0.0005], (960, 1280)))
    assert ocamcalib_camera(skew).residual_px > 1.0


def test_ocamcalib_bad_field(tmp_path):
    path = _write(tmp_path / "calib_results.txt", _ocam_text([-250.0, 0, 1e-3], [300.0], [481.2, 639.7], [1.0, 0.0, 0.0], (960, 1280))
                  .replace("3 -2.5", "4 -2.5"))
    with pytest.raises(CalibrationError, match=r"calib_results.txt: pol: the length 4 does not match the 3 coefficients"):
        read_ocamcalib(path)
    # a centre outside the image (a lost decimal point) was fitted from no pixel and reported exact
    path = _write(tmp_path / "calib_results.txt", _ocam_text([-250.0, 0, 1e-3], [300.0], [4812, 6397], [1.0, 0.0, 0.0], (960, 1280)))
    with pytest.raises(CalibrationError, match=r"calib_results.txt: center \(row, column\): \(6397, 4812\) is outside the 1280x960 image"):
        ocamcalib_camera(path)
    # an image size with two zeros too many is refused; a big one is fitted from a bounded sample
    path = _write(tmp_path / "calib_results.txt", _ocam_text([-250.0, 0, 1e-3], [300.0], [481.2, 639.7], [1.0, 0.0, 0.0], (96000, 128000)))
    with pytest.raises(CalibrationError, match=r"calib_results.txt: image size: must be whole numbers of pixels in \[1, 100000\]"):
        ocamcalib_camera(path)
    import time

    path = _write(tmp_path / "calib_results.txt", _ocam_text([-2500.0, 0, 1e-4], [300.0], [4812, 6397], [1.0, 0.0, 0.0], (9600, 12800)))
    t0 = time.perf_counter()
    imp = ocamcalib_camera(path)
    assert imp.camera.width == 12800 and time.perf_counter() - t0 < 10


# ---------------------------------------------------------------- rigs of calibration files


def test_surround_view_rig_file_is_its_calibration():
    rig = load_rig(SV / "rig.yaml")
    assert rig.names == list(NAMES)
    for name in NAMES:
        assert rig[name].camera == opencv_fisheye_camera(SV / f"{name}.yaml")
        # the shipped extrinsics are those of the file's ground homography (rounded to 1e-6 m / 1e-8)
        np.testing.assert_allclose(rig[name].cam_to_ego, camera_pose(SV / f"{name}.yaml", name), atol=1e-5)
    # the cameras sit where a car's do: front ahead, back behind, left on the left, all 0.6-1.1 m high
    assert rig["front"].cam_to_ego[0, 3] > 2 and rig["back"].cam_to_ego[0, 3] < -1.5
    assert rig["left"].cam_to_ego[1, 3] > 0.8 and rig["right"].cam_to_ego[1, 3] < -0.8
    assert all(0.6 < rig[n].cam_to_ego[2, 3] < 1.1 for n in NAMES)


def test_mixed_rig_with_woodscape_and_kalibr(tmp_path):
    _write(tmp_path / "camchain.yaml", CAMCHAIN)
    (tmp_path / "front.json").write_text((DATA / "woodscape" / "front.json").read_text())
    rig_file = _write(tmp_path / "rig.yaml", """\
name: mixed
reference_to_vehicle: {translation: [1.0, 0.0, 1.5], rotation: {yaw_deg: 0, pitch_deg: 0}}
cameras:
  front: {calibration: front.json}
  side: {calibration: camchain.yaml, camera: cam0}
""")
    rig = load_rig(rig_file)
    ws = load_rig(DATA / "woodscape" / "front.json")
    assert rig["front"].camera == next(iter(ws)).camera
    np.testing.assert_allclose(rig["front"].cam_to_ego, next(iter(ws)).cam_to_ego)
    # Kalibr: imu frame -> vehicle by reference_to_vehicle (a rotation of yaw 0, pitch 0 is a forward camera's, so compose)
    from geometry.rig import make_transform, mount_rotation

    ref = make_transform(mount_rotation(0, 0), [1.0, 0.0, 1.5])
    np.testing.assert_allclose(rig["side"].cam_to_ego, ref @ kalibr_cameras(tmp_path / "camchain.yaml")["cam0"].cam_to_ref)


@pytest.mark.parametrize("text,needle", [
    ("cameras:\n  front: {calibration: missing.yaml, extrinsics: {translation: [0, 0, 1], rotation: {}}}\n", "missing.yaml"),
    ("cameras:\n  front: {calibration: front.yaml}\n", "cameras.front: needs 'extrinsics' (front.yaml holds no pose)"),
    ("cameras:\n  front: {calibration: front.yaml, lens: x}\n", "cameras.front: unknown key 'lens'"),
    ("cameras:\n  front: {calibration: front.yaml, format: kb8, extrinsics: {translation: [0, 0, 1], rotation: {}}}\n", "format: 'kb8'"),
])
def test_rig_assembly_errors_name_file_and_field(tmp_path, text, needle):
    (tmp_path / "front.yaml").write_text((SV / "front.yaml").read_text())
    rig_file = _write(tmp_path / "rig.yaml", text)
    with pytest.raises(RigError) as exc:
        load_rig(rig_file)
    assert needle in str(exc.value) and "rig.yaml" in str(exc.value) and "\n" not in str(exc.value)


# ---------------------------------------------------------------- the stitch of the real images


def _edges(line, coord):
    t = line > 0.5 * (np.percentile(line, 10) + np.percentile(line, 90))
    i = np.nonzero(t[1:] != t[:-1])[0]
    return (coord[i] + coord[i + 1]) / 2


def _square_size(edges):
    """Least-squares square size of the edges of a run of squares (a circle or a camera seam breaks a
    run: steps outside 0.25-0.55 m are counted as their rounded number of 0.4 m squares)."""
    e = np.sort(edges)
    d = np.diff(e)
    ok = (d > 0.25) & (d < 0.55)
    n = np.concatenate([[0], np.cumsum(np.where(ok, 1, np.rint(d / 0.4)))])
    keep = np.concatenate([[False], ok]) | np.concatenate([ok, [False]])
    a = np.stack([np.ones(keep.sum()), n[keep]], -1)
    sol, *_ = np.linalg.lstsq(a, e[keep], rcond=None)
    return sol[1], int(keep.sum())


def test_stitch_puts_the_mat_squares_at_their_true_spacing():
    """The mat's squares are 40 cm (doc/en.md of the data's repository). In the stitch of the four real
    images through the imported rig, the outer rows of squares in front of and behind the car (each
    6 m wide, 10+ edges, seen through the fisheye distortion of two or three cameras) measure 40 cm
    within 1.5 cm (measured 39.0 and 40.2 cm), and the mat is 6 m wide within 15 cm (measured 6.10 m,
    from its white border against the paving)."""
    from dataset_tools.stitch import read_images, stitch
    from geometry.bev import BevGrid

    rig = load_rig(SV / "rig.yaml")
    grid = BevGrid(x_min=-5.2, x_max=5.2, y_min=-3.2, y_max=3.2, res=0.01)
    bev, source = stitch(rig, read_images(SV, rig.names), grid)
    assert (source[abs(grid.cell_centres()[..., 0]) > 3.5] >= 0).all()  # the mat in front and behind: every cell seen
    gray = bev.mean(-1)
    xs = grid.x_max - (np.arange(grid.rows) + 0.5) * grid.res
    ys = grid.y_max - (np.arange(grid.cols) + 0.5) * grid.res
    for x in (4.8, -4.8):
        row = gray[int(np.argmin(abs(xs - x)))]
        inner = abs(ys) < 2.95
        size, n = _square_size(_edges(row[inner], ys[inner]))
        assert n >= 10 and abs(size - 0.40) <= 0.015, (x, size, n)
        # the mat's white border against the darker paving: its outer edges at y = +-3 m
        white = row > np.percentile(row, 90) * 0.8
        edges = ys[np.nonzero(white)[0][[0, -1]]]
        assert abs((edges[0] - edges[1]) - 6.0) <= 0.15, edges
