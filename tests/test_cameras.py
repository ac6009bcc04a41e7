"""Camera models: round trips, identities, independent references, gradients, resize and crop."""

import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from geometry.cameras import MODELS, CameraError, RadialCamera, camera_from_dict
from geometry.shapes import check_shape

W, H = 480, 302
BASE = dict(width=W, height=H, fx=145.0, fy=151.0, cx=241.3, cy=148.2)

CAMERAS = {
    "pinhole": dict(BASE, model="pinhole", fx=300.0, fy=310.0),
    "equidistant": dict(BASE, model="equidistant"),
    "equisolid": dict(BASE, model="equisolid"),
    "stereographic": dict(BASE, model="stereographic"),
    "kb_theta": dict(BASE, model="kb_theta", p=[1.0, 0.02, 0.05, -0.01]),
    "radial_poly": dict(model="radial_poly", width=1280, height=966, cx=643.442, cy=479.407,
                        aspect_ratio=1.02, k=[339.749, -31.988, 48.275, -7.201]),
    "opencv_fisheye": dict(BASE, model="opencv_fisheye", k=[0.05, -0.01, 0.002, -0.0003]),
    "ucm": dict(BASE, model="ucm", alpha=0.62),
    "eucm": dict(BASE, model="eucm", alpha=0.62, beta=1.2),
    "double_sphere": dict(BASE, model="double_sphere", xi=-0.2, alpha=0.6),
    "cylindrical": dict(BASE, model="cylindrical"),
    "mei": dict(BASE, model="mei", fx=290.0, fy=301.0, s=0.4, xi=0.95, k=[-0.25, 0.06, 0.0005, -0.0003]),
}

# more corners of the parameter spaces, for the domain tests
VARIANTS = dict(CAMERAS)
VARIANTS.update({
    "ucm_low_alpha": dict(BASE, model="ucm", alpha=0.3),
    "eucm_low_alpha": dict(BASE, model="eucm", alpha=0.35, beta=0.8),
    "double_sphere_xi_pos": dict(BASE, model="double_sphere", xi=0.4, alpha=0.65),
    "double_sphere_low_alpha": dict(BASE, model="double_sphere", xi=0.3, alpha=0.3),
    "kb_theta_folding": dict(BASE, model="kb_theta", p=[1.0, 0.0, -0.08]),
    "mei_xi_above_1": dict(BASE, model="mei", fx=330.0, fy=340.0, s=0.0, xi=1.4, k=[-0.1, 0.01, 0.0, 0.0]),
    "mei_pinhole_radtan": dict(BASE, model="mei", fx=300.0, fy=310.0, s=0.0, xi=0.0, k=[-0.28, 0.07, 0.0002, -0.0001]),
    "mei_folding": dict(BASE, model="mei", fx=200.0, fy=210.0, s=0.0, xi=0.9, k=[-0.2, 0.0, 0.001, 0.0]),
})


def angle_between(a, b):
    """Angle between unit vectors, accurate near 0 (atan2 of |a x b| and a.b)."""
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), (a * b).sum(-1))


def sphere_points(n=100_000, seed=0):
    p = np.random.default_rng(seed).normal(size=(n, 3))
    return p / np.linalg.norm(p, axis=-1, keepdims=True)


def test_every_design_model_is_here():
    assert set(MODELS) == set(CAMERAS) and len(MODELS) == 12


@pytest.mark.parametrize("name", VARIANTS)
def test_round_trip_point_pixel_point(name):
    cam = camera_from_dict(VARIANTS[name])
    rays = sphere_points()
    uv, valid = cam.project(rays * 7.3)
    back, valid2 = cam.unproject(uv)
    assert valid.mean() > 0.3, "valid domain suspiciously small"
    assert valid2[valid].all(), "a projected valid point must unproject as valid"
    err = angle_between(back[valid], rays[valid])
    assert err.max() <= 1e-9, f"{name}: worst round-trip error {err.max():.2e} rad"


@pytest.mark.parametrize("name", CAMERAS)
def test_round_trip_pixel_ray_pixel(name):
    cam = camera_from_dict(CAMERAS[name])
    rng = np.random.default_rng(1)
    uv = rng.uniform([-0.5, -0.5], [cam.width - 0.5, cam.height - 0.5], size=(50_000, 2))
    rays, valid = cam.unproject(uv)
    np.testing.assert_allclose(np.linalg.norm(rays, axis=-1), 1.0, atol=1e-12)
    uv2, valid2 = cam.project(rays * 2.0)
    assert valid2[valid].all()
    assert np.abs(uv2[valid] - uv[valid]).max() <= 1e-7  # pixels; <= 1e-9 rad at these focal lengths


@pytest.mark.parametrize("name", VARIANTS)
def test_validity_is_exact_at_the_domain_edge(name):
    """Points outside the domain never round-trip (and, above, every point inside does)."""
    cam = camera_from_dict(VARIANTS[name])
    p = sphere_points(400_000, seed=3)
    uv, valid = cam.project(p)
    if valid.all():
        return
    # invalid points must not silently alias onto valid pixels of other rays
    back, v2 = cam.unproject(uv[~valid])
    same = angle_between(back, p[~valid]) < 1e-6
    assert not (same & v2).any(), f"{name}: a point outside the domain round-trips"


def test_pinhole_validity_is_z_positive():
    cam = camera_from_dict(CAMERAS["pinhole"])
    _, valid = cam.project(np.array([[0.1, 0.2, 1e-6], [0.1, 0.2, 0.0], [0.1, 0.2, -1.0]]))
    assert valid.tolist() == [True, False, False]


def _same(a, b, pts):
    uva, va = a.project(pts)
    uvb, vb = b.project(pts)
    assert (va == vb).all()
    np.testing.assert_allclose(uva[va], uvb[va], atol=1e-9)
    uv = uva[va]
    ra, _ = a.unproject(uv)
    rb, _ = b.unproject(uv)
    np.testing.assert_allclose(ra, rb, atol=1e-9)


@pytest.mark.parametrize(
    "a, b",
    [
        (dict(model="ucm", alpha=0.0), dict(model="pinhole")),
        (dict(model="ucm", alpha=0.5), dict(model="stereographic")),
        (dict(model="double_sphere", xi=0.0, alpha=0.6), dict(model="ucm", alpha=0.6)),
        (dict(model="double_sphere", xi=0.0, alpha=0.3), dict(model="ucm", alpha=0.3)),
        (dict(model="eucm", alpha=0.7, beta=1.0), dict(model="ucm", alpha=0.7)),
        (dict(model="opencv_fisheye", k=[0, 0, 0, 0]), dict(model="equidistant")),
        (dict(model="kb_theta", p=[1.0]), dict(model="equidistant")),
        (dict(model="mei", xi=0.0, s=0.0, k=[0, 0, 0, 0]), dict(model="pinhole")),
        (dict(model="mei", xi=1.0, s=0.0, k=[0, 0, 0, 0], fx=2 * 145.0, fy=2 * 151.0), dict(model="ucm", alpha=0.5)),
    ],
)
def test_identities(a, b):
    pts = sphere_points(20_000, seed=4) * 3
    _same(camera_from_dict(dict(BASE, **a)), camera_from_dict(dict(BASE, **b)), pts)


def test_opencv_fisheye_matches_cv2_below_90_degrees():
    d = CAMERAS["opencv_fisheye"]
    cam = camera_from_dict(d)
    p = sphere_points(20_000, seed=5)
    p = p[p[:, 2] > 0.02]  # cv2.fisheye works on x/z, so only in front of the camera
    uv, valid = cam.project(p)
    assert valid.all()
    K = np.array([[d["fx"], 0, d["cx"]], [0, d["fy"], d["cy"]], [0, 0, 1]], dtype=np.float64)
    ref, _ = cv2.fisheye.projectPoints(p.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, np.array(d["k"], dtype=np.float64))
    np.testing.assert_allclose(uv, ref.reshape(-1, 2), atol=1e-6)


def woodscape_reference(points, k, cx_offset, cy_offset, width, height, aspect_ratio):
    """WoodScape's published projection (their projection.py), written independently of ours."""
    x, y, z = points.T
    chi = np.sqrt(x**2 + y**2)
    theta = np.pi / 2 - np.arctan2(z, chi)
    rho = k[0] * theta + k[1] * theta**2 + k[2] * theta**3 + k[3] * theta**4
    lens = np.stack([x, y], -1) * np.divide(rho, chi, out=np.zeros_like(rho), where=chi != 0)[:, None]
    centre = np.array([cx_offset + width / 2 - 0.5, cy_offset + height / 2 - 0.5])
    return lens * np.array([1.0, aspect_ratio]) + centre


def test_radial_poly_matches_woodscape_formula():
    from geometry.rig import load_rig

    rig = load_rig(Path(__file__).parent / "data" / "woodscape" / "front.json")
    cam = rig["FV"].camera
    assert (cam.width, cam.height) == (1280, 966)
    p = sphere_points(20_000, seed=6) * 4
    uv, valid = cam.project(p)
    ref = woodscape_reference(p, [339.749, -31.988, 48.275, -7.201], 3.942, -3.093, 1280, 966, 1.0)
    np.testing.assert_allclose(uv[valid], ref[valid], atol=1e-9)
    # and the inverse of their formula: their pixel unprojects to the point's ray
    rays, v2 = cam.unproject(ref[valid])
    assert v2.all()
    assert angle_between(rays, p[valid] / 4).max() < 1e-9


@pytest.mark.parametrize("name", CAMERAS)
def test_gradcheck_float64(name):
    cam = camera_from_dict(CAMERAS[name])
    rays = torch.tensor(sphere_points(8, seed=7), dtype=torch.float64)
    rays = rays[cam.project(rays)[1]][:4]  # valid points only
    pts = (rays * 3).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda p: cam.project(p)[0], (pts,))
    uv = cam.project(rays)[0].detach().requires_grad_(True)
    assert torch.autograd.gradcheck(lambda q: cam.unproject(q)[0], (uv,))


def test_numpy_in_numpy_out_torch_in_torch_out_batched():
    cam = camera_from_dict(CAMERAS["double_sphere"])
    p = sphere_points(24).reshape(2, 3, 4, 3)
    uv, valid = cam.project(p)
    assert isinstance(uv, np.ndarray) and uv.shape == (2, 3, 4, 2) and valid.shape == (2, 3, 4) and valid.dtype == bool
    uvt, validt = cam.project(torch.from_numpy(p).float())
    assert isinstance(uvt, torch.Tensor) and uvt.dtype == torch.float32 and uvt.shape == (2, 3, 4, 2)
    np.testing.assert_allclose(uvt.numpy()[valid], uv[valid], atol=1e-3)
    with pytest.raises(ValueError, match=r"points must have shape \(\.\.\., 3\), got \(5, 2\)"):
        cam.project(np.zeros((5, 2)))
    with pytest.raises(ValueError, match=r"uv must have shape \(\.\.\., 2\), got \(\)"):
        cam.unproject(torch.tensor(1.0))


def test_check_shape_sizes_names_and_ellipsis():
    assert check_shape(np.zeros((4, 4)), (4, 4), "m").shape == (4, 4)
    check_shape(torch.zeros(2, 7, 3), ("B", ..., 3), "x")
    check_shape(torch.zeros(2, 3), ("B", ..., 3), "x")  # ... may be no dimensions
    check_shape(np.zeros((2, 3, 5)), (2, ...), "x")
    for a, shape, message in [
        (np.zeros((3, 4)), (4, 4), r"m must have shape \(4, 4\), got \(3, 4\)"),
        (np.zeros((4, 4, 1)), (4, 4), r"got \(4, 4, 1\)"),
        (torch.zeros(2, 3), ("B", "N", 3), r"m must have shape \(B, N, 3\), got \(2, 3\)"),
        (torch.zeros(3), (2, ..., 3), r"\(2, \.\.\., 3\), got \(3,\)"),
        (np.zeros(5), (4,), r"\(4,\), got \(5,\)"),
    ]:
        with pytest.raises(ValueError, match=message):
            check_shape(a, shape, "m")


def test_kb_theta_is_a_radial_camera_whose_polynomial_is_theta_of_rho():
    cam = camera_from_dict(CAMERAS["kb_theta"])
    assert isinstance(cam, RadialCamera)
    r = torch.linspace(0, cam.rho_max * 0.999, 50, dtype=torch.float64)
    p1, p2, p3, p4 = CAMERAS["kb_theta"]["p"]
    np.testing.assert_allclose(cam.theta_of_rho(r), p1 * r + p2 * r**2 + p3 * r**3 + p4 * r**4, rtol=1e-15, atol=0)
    np.testing.assert_allclose(cam.rho(cam.theta_of_rho(r)), r, atol=1e-12)
    assert cam.theta_of_rho(torch.tensor(cam.rho_max, dtype=torch.float64)) == pytest.approx(cam.theta_max)


@pytest.mark.parametrize("name", CAMERAS)
def test_resize_and_crop_move_pixels_as_images_do(name):
    cam = camera_from_dict(CAMERAS[name])
    p = sphere_points(5_000, seed=8)
    uv, valid = cam.project(p)
    sx, sy = 0.5, 0.25
    small = cam.scaled(sx, sy)
    assert (small.width, small.height) == (round(cam.width * sx), round(cam.height * sy))
    uv_s, v_s = small.project(p)
    expected = (uv + 0.5) * np.array([sx, sy]) - 0.5
    np.testing.assert_allclose(uv_s[valid], expected[valid], atol=1e-7)
    crop = cam.cropped(17, 9, 100, 80)
    uv_c, _ = crop.project(p)
    np.testing.assert_allclose(uv_c[valid], uv[valid] - np.array([17, 9]), atol=1e-7)
    assert (crop.width, crop.height) == (100, 80)
    r = cam.resized(200, 100)
    assert (r.width, r.height) == (200, 100)


@pytest.mark.parametrize("name", CAMERAS)
def test_dict_round_trip(name):
    cam = camera_from_dict(CAMERAS[name])
    again = camera_from_dict(cam.to_dict())
    assert again == cam and again.to_dict() == cam.to_dict()


@pytest.mark.parametrize(
    "d, message",
    [
        (dict(BASE), "missing key 'model'"),
        (dict(BASE, model="fisheye9000"), "unknown model 'fisheye9000'"),
        ({**{k: v for k, v in BASE.items() if k != "fx"}, "model": "equidistant"}, "missing key 'fx'"),
        (dict(BASE, model="equidistant", f=3), "unknown key 'f'"),
        (dict(BASE, model="equidistant", fx="wide"), "'fx' must be a number"),
        (dict(BASE, model="ucm", alpha=1.5), "'alpha' must be in"),
        (dict(BASE, model="opencv_fisheye", k=[0.1, 0.2]), "'k' must have 4 to 4 entries"),
        (dict(BASE, model="kb_theta", p=[-1.0]), "positive p1"),
        (dict(BASE, model="pinhole", fx=-3), "'fx' must be positive"),
        (dict(BASE, model="pinhole", width=10.5), "whole number"),
    ],
)
def test_bad_dicts_name_the_field(d, message):
    with pytest.raises(CameraError, match=message):
        camera_from_dict(d)


def test_polynomial_domain_stops_where_the_lens_folds_back():
    # rho = theta - 0.3 theta^3 peaks at theta = 1/sqrt(0.9): beyond it two angles share a radius
    cam = camera_from_dict(dict(BASE, model="opencv_fisheye", k=[-0.3, 0, 0, 0]))
    assert cam.theta_max == pytest.approx(1 / math.sqrt(0.9), abs=1e-9)
    t = np.array([cam.theta_max - 1e-3, cam.theta_max + 1e-3])
    _, valid = cam.project(np.stack([np.sin(t), 0 * t, np.cos(t)], -1))
    assert valid.tolist() == [True, False]


def test_the_kept_domain_limit_is_each_polynomials_own():
    """The domain limit is kept per coefficient tuple (a camera's resized and cropped copies check
    the same polynomial again): a copy finds its camera's limit, another polynomial its own."""
    a = camera_from_dict(dict(BASE, model="opencv_fisheye", k=[-0.3, 0, 0, 0]))
    assert a.resized(a.width // 2, a.height // 2).theta_max == a.theta_max
    assert a.cropped(3, 2, 20, 10).theta_max == a.theta_max
    b = camera_from_dict(dict(BASE, model="opencv_fisheye", k=[-0.2, 0, 0, 0]))
    assert b.theta_max == pytest.approx(1 / math.sqrt(0.6), abs=1e-9) != a.theta_max


@pytest.mark.parametrize("first_power", [1, 3])
def test_the_newton_solves_polynomial_is_the_polynomial_and_its_derivative(first_power):
    """_Poly (the split coefficients a Newton solve evaluates ~7 times) gives _poly's values to the
    last bit and the derivative autograd finds, for a first power of 1 and above."""
    from geometry.cameras import _Poly, _poly

    c = torch.tensor([1.0, 0.0, -0.02, 0.0, 0.003, 0.0, 1e-4], dtype=torch.float64)
    t = torch.linspace(0.0, 1.6, 101, dtype=torch.float64, requires_grad=True)
    p = _Poly(c, first_power)
    assert torch.equal(p(t), _poly(c, t, first_power))
    (grad,) = torch.autograd.grad(_poly(c, t, first_power).sum(), t)
    assert torch.allclose(p.deriv(t.detach()), grad, rtol=1e-12, atol=1e-12)
