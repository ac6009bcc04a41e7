"""geometry/blender.py without bpy: frame conversion, OSL shader text, lens-polynomial fit, top-down
camera maths. (The renders that prove these against Cycles are in test_render_agreement.py.)"""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from geometry.bev import BevGrid
from geometry.blender import (
    BLENDER_FROM_OPENCV,
    BlenderFitError,
    blender_camera_matrix,
    default_osl_workdir,
    fit_lens_polynomial,
    opencv_camera_matrix,
    osl_shader_source,
    topdown_camera,
    write_osl_shader,
)
from geometry.cameras import MODELS, camera_from_dict
from geometry.rig import load_rig, make_transform, mount_rotation, rot_x, rot_z

REPO = Path(__file__).resolve().parents[1]
CAM_TO_EGO = make_transform(mount_rotation(yaw_deg=20.0, pitch_deg=15.0, roll_deg=5.0), [1.5, 0.3, 1.2])
EGO_POSE = make_transform(rot_z(math.radians(30.0)) @ rot_x(math.radians(2.0)), [12.0, -7.0, 0.3])

EXAMPLES = {
    "pinhole": dict(fx=40, fy=44, cx=30.3, cy=25.7),
    "equidistant": dict(fx=12, fy=13, cx=33.2, cy=22.6),
    "equisolid": dict(fx=15, fy=16, cx=33.2, cy=22.6),
    "stereographic": dict(fx=12, fy=13, cx=33.2, cy=22.6),
    "kb_theta": dict(fx=12, fy=13, cx=33.2, cy=22.6, p=[1.0, -0.02, 0.05]),
    "radial_poly": dict(cx=33.2, cy=22.6, aspect_ratio=1.05, k=[12.0, -1.0, 1.2, -0.35]),
    "opencv_fisheye": dict(fx=12, fy=13, cx=33.2, cy=22.6, k=[-0.05, 0.0005, 0.0, 0.0]),
    "ucm": dict(fx=14, fy=15, cx=33.2, cy=22.6, alpha=0.6),
    "eucm": dict(fx=14, fy=15, cx=33.2, cy=22.6, alpha=0.6, beta=1.2),
    "double_sphere": dict(fx=12, fy=13, cx=33.2, cy=22.6, xi=-0.2, alpha=0.6),
    "cylindrical": dict(fx=10, fy=12, cx=33.2, cy=22.6),
    "mei": dict(fx=24, fy=25, cx=33.2, cy=22.6, s=0.1, xi=0.9, k=[-0.2, 0.04, 0.001, -0.0005]),
}


def _cam(model, w=64, h=48, **kw):
    return camera_from_dict(dict(EXAMPLES.get(model, {}), model=model, width=w, height=h, **kw))


# ---------------------------------------------------------------- frames


def test_blender_camera_looks_down_its_minus_z_with_y_up():
    m = blender_camera_matrix(CAM_TO_EGO)
    # Blender's view direction (-z local) and up (+y local) are OpenCV's +z and -y
    np.testing.assert_allclose(m @ [0, 0, -1, 0], CAM_TO_EGO @ [0, 0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(m @ [0, 1, 0, 0], CAM_TO_EGO @ [0, -1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(m @ [1, 0, 0, 0], CAM_TO_EGO @ [1, 0, 0, 0], atol=1e-15)
    np.testing.assert_allclose(m[:3, 3], CAM_TO_EGO[:3, 3])
    assert np.linalg.det(m[:3, :3]) == pytest.approx(1.0)


def test_blender_camera_matrix_with_ego_pose_is_world_matrix():
    w = blender_camera_matrix(CAM_TO_EGO, EGO_POSE)
    np.testing.assert_allclose(w, EGO_POSE @ blender_camera_matrix(CAM_TO_EGO), atol=1e-12)
    # a point 5 m ahead of the camera (OpenCV) is 5 m down Blender's -z, in world coordinates
    ahead_world = EGO_POSE @ CAM_TO_EGO @ [0, 0, 5, 1]
    np.testing.assert_allclose(w @ [0, 0, -5, 1], ahead_world, atol=1e-12)


def test_frame_conversion_round_trip_and_shape_check():
    np.testing.assert_allclose(opencv_camera_matrix(blender_camera_matrix(CAM_TO_EGO)), CAM_TO_EGO, atol=1e-15)
    np.testing.assert_array_equal(BLENDER_FROM_OPENCV @ BLENDER_FROM_OPENCV, np.eye(3))
    with pytest.raises(ValueError, match=r"cam_to_ego must have shape \(4, 4\), got \(3, 3\)"):
        blender_camera_matrix(np.eye(3))
    with pytest.raises(ValueError, match=r"ego_pose must have shape \(4, 4\), got \(4,\)"):
        blender_camera_matrix(CAM_TO_EGO, ego_pose=[1.0, 0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match=r"blender_matrix must have shape \(4, 4\)"):
        opencv_camera_matrix(np.eye(4)[:3])


# ---------------------------------------------------------------- OSL shader text


@pytest.mark.parametrize("model", sorted(MODELS))
def test_osl_shader_is_filled_with_the_camera(model):
    cam = _cam(model)
    src = osl_shader_source(cam)
    body = src.split("*/", 1)[1]
    assert "$" not in body
    assert "shader camera(" in body and "output vector direction" in body
    for k, v in cam.to_dict().items():
        if k in ("model",):
            continue
        for x in v if isinstance(v, list) else [v]:
            assert repr(float(x)) in body, (model, k)
    # a different camera gives a different shader
    assert osl_shader_source(cam.resized(32, 24)) != src


def test_osl_shader_bakes_model_limits():
    cam = _cam("opencv_fisheye")
    src = osl_shader_source(cam)
    assert f"float theta_max = {cam.theta_max!r}" in src
    assert f"float rho_max = {cam.rho_max!r}" in src
    kb = _cam("kb_theta")
    assert f"float rho_max = {kb.rho_max!r}" in osl_shader_source(kb)
    assert "{1.0, -0.02, 0.05, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0}" in osl_shader_source(kb)


def test_write_osl_shader_is_content_addressed(tmp_path):
    a = write_osl_shader(_cam("double_sphere"), tmp_path)
    b = write_osl_shader(_cam("double_sphere"), tmp_path)
    c = write_osl_shader(_cam("double_sphere", cx=30.0), tmp_path)
    assert a == b != c
    assert a.read_text() == osl_shader_source(_cam("double_sphere"))
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted({a.name, c.name})  # no temp files left
    assert REPO not in default_osl_workdir().resolve().parents


# ---------------------------------------------------------------- lens polynomial


def _blender_lens_ray(fit, uv):
    """Blender's FISHEYE_LENS_POLYNOMIAL written out from its definition (sensor mm, shift, theta
    = -(k0 + k1 r + ... + k4 r^4)), independent of LensPolynomial.as_camera: OpenCV-frame rays."""
    w, h = fit.width, fit.height
    mm = fit.sensor_width / max(w, h)
    x = ((uv[..., 0] + 0.5) / w + fit.shift_x - 0.5) * w * mm  # mm, right
    y = (0.5 - (uv[..., 1] + 0.5) / h + fit.shift_y) * h * mm  # mm, up
    r = np.hypot(x, y)
    k = fit.k
    theta = -(k[0] + k[1] * r + k[2] * r**2 + k[3] * r**3 + k[4] * r**4)
    phi = np.arctan2(y, x)
    rays = np.stack([np.sin(theta) * np.cos(phi), -np.sin(theta) * np.sin(phi), np.cos(theta)], -1)
    return rays, np.abs(theta) <= fit.fov / 2


def test_fit_equidistant_is_exact_and_matches_designs_identity():
    cam = _cam("equidistant", fx=20.0, fy=20.0)
    fit = fit_lens_polynomial(cam)
    assert fit.fit_error_px < 1e-9
    # theta = r_px / f and r_mm = r_px sensor_width / max(W, H), so k1 = -max(W, H) / (sensor_width f),
    # the rest 0 (the render agreement test confirms this against Cycles)
    assert fit.k[1] == pytest.approx(-max(cam.width, cam.height) / (fit.sensor_width * 20.0), rel=1e-9)
    assert max(abs(c) for c in (fit.k[0], fit.k[2], fit.k[3], fit.k[4])) < 1e-9


@pytest.mark.parametrize(
    "cam",
    [
        _cam("equidistant", fx=12.0, fy=12.0),  # valid circle edge inside the image
        _cam("stereographic", fx=14.0, fy=14.0),
        _cam("opencv_fisheye", fx=16.0, fy=16.0, k=[-0.02, 0.003, 0.0, 0.0]),
        _cam("pinhole", fx=48.0, fy=48.0),
        _cam("ucm", fx=14.0, fy=14.0, alpha=0.5),  # = stereographic
        load_rig(REPO / "configs/rigs/default.yaml")["front"].camera,  # the default rig, 480x302
    ],
    ids=["equidistant", "stereographic", "opencv_fisheye", "pinhole", "ucm", "default_rig"],
)
def test_fit_error_is_the_true_worst_pixel_error(cam):
    fit = fit_lens_polynomial(cam, tol_px=0.05)
    grid = cam.pixel_grid().numpy()
    _, ours = cam.unproject(grid)
    rays, theirs = _blender_lens_ray(fit, grid)
    assert np.array_equal(ours, theirs)  # the fitted FOV reproduces our valid region exactly
    uv, ok = cam.project(rays[ours])
    assert ok.all()
    err = np.linalg.norm(uv - grid[ours], axis=-1).max()
    assert err == pytest.approx(fit.fit_error_px, rel=1e-6, abs=1e-9)
    assert fit.fit_error_px <= 0.05
    print(f"\n{cam.model} {cam.width}x{cam.height}: lens polynomial worst error {fit.fit_error_px:.4f} px")
    # the principal point survives the shift conversion
    kb = fit.as_camera()
    assert (kb.cx, kb.cy) == pytest.approx((cam.params["cx"], cam.params["cy"]), abs=1e-9)


@pytest.mark.parametrize(
    "cam, why",
    [
        (_cam("cylindrical"), "not radially symmetric"),
        (_cam("equidistant"), "fx 12.0 != fy 13.0"),
        (_cam("radial_poly"), "aspect_ratio 1.05 != 1"),
        (_cam("equisolid", fx=15.0, fy=15.0), "exceeds the tolerance"),  # theta -> pi at the circle
        (_cam("pinhole", fx=12.0, fy=12.0), "exceeds the tolerance"),  # 140 degrees across
        (_cam("double_sphere", fx=12.0, fy=12.0), "exceeds the tolerance"),
    ],
    ids=["cylindrical", "fx_ne_fy", "radial_poly_aspect", "equisolid_full_sphere", "wide_pinhole", "double_sphere"],
)
def test_fit_refuses_with_one_clear_line(cam, why):
    with pytest.raises(BlenderFitError) as exc:
        fit_lens_polynomial(cam)
    msg = str(exc.value)
    assert why in msg and cam.model in msg and "\n" not in msg


def test_fit_tolerance_is_enforced():
    cam = _cam("opencv_fisheye", fx=16.0, fy=16.0, k=[-0.02, 0.003, 0.0, 0.0])
    err = fit_lens_polynomial(cam, tol_px=1.0).fit_error_px
    assert err > 1e-4
    with pytest.raises(BlenderFitError, match="exceeds the tolerance"):
        fit_lens_polynomial(cam, tol_px=err / 2)


def test_radial_poly_with_square_pixels_fits():
    cam = camera_from_dict(dict(model="radial_poly", width=64, height=48, cx=31.0, cy=24.0, aspect_ratio=1.0,
                                k=[12.0, -1.0, 1.2, -0.2]))
    fit = fit_lens_polynomial(cam, tol_px=0.05)
    assert fit.fit_error_px <= 0.05


# ---------------------------------------------------------------- top-down camera


@pytest.mark.parametrize("grid", [BevGrid(), BevGrid(x_min=-4.0, x_max=4.0, y_min=-3.0, y_max=3.0, res=0.25)])
def test_topdown_pixel_centres_are_cell_centres(grid):
    td = topdown_camera(grid, height_m=40.0)
    assert (td.height, td.width) == grid.shape
    pixel = td.ortho_scale / max(td.width, td.height)  # metres per pixel (sensor_fit AUTO)
    assert pixel == pytest.approx(grid.res)
    centres = grid.cell_centres()
    pts = np.concatenate([centres, np.zeros(centres.shape[:2] + (1,))], -1)
    cam = (pts - td.cam_to_ego[:3, 3]) @ td.cam_to_ego[:3, :3]  # ego -> OpenCV camera frame
    # orthographic: u = x / pixel + (W - 1) / 2, v = y / pixel + (H - 1) / 2
    u = cam[..., 0] / pixel + (td.width - 1) / 2
    v = cam[..., 1] / pixel + (td.height - 1) / 2
    rows, cols = np.meshgrid(np.arange(grid.rows), np.arange(grid.cols), indexing="ij")
    np.testing.assert_allclose(u, cols, atol=1e-9)
    np.testing.assert_allclose(v, rows, atol=1e-9)
    assert np.allclose(cam[..., 2], 40.0)  # looking straight down from 40 m
    with pytest.raises(ValueError):
        topdown_camera(grid, 0.0)


def test_geometry_blender_imports_without_bpy():
    code = "import sys, geometry.blender; assert 'bpy' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True, cwd=REPO)
