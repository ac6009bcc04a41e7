"""Cylindrical rectification (geometry.rectify): the remapped image and the cylindrical camera agree."""

import numpy as np
import pytest

from geometry.bev import BevGrid
from geometry.rectify import Rectifier, covered_cells, cylindrical_camera, lost_fisheye_pixels
from geometry.rig import load_rig


def sphere_blob(camera, direction, sigma_rad):
    """A float image of `camera` whose content is an angular Gaussian about `direction` (camera frame)."""
    rays, ok = camera.unproject(camera.pixel_grid().numpy())
    d = np.asarray(direction) / np.linalg.norm(direction)
    ang = np.arccos(np.clip(rays @ d, -1, 1))
    return np.where(ok, np.exp(-0.5 * (ang / sigma_rad) ** 2), 0.0).astype(np.float32)


def centroid(img, around, radius=12):
    v, u = np.mgrid[0 : img.shape[0], 0 : img.shape[1]]
    w = np.where((np.abs(u - around[0]) < radius) & (np.abs(v - around[1]) < radius), img, 0.0)
    return np.array([(u * w).sum() / w.sum(), (v * w).sum() / w.sum()])


def test_cylindrical_camera_spans_the_chosen_field_of_view():
    cam = cylindrical_camera(480, 302, 180.0, 90.0)
    rays, ok = cam.unproject(np.array([[-0.5, 150.5], [479.5, 150.5], [239.5, -0.5], [239.5, 301.5]]))
    assert ok.all()
    az = np.degrees(np.arctan2(rays[:, 0], rays[:, 2]))
    el = np.degrees(np.arctan2(rays[:, 1], np.hypot(rays[:, 0], rays[:, 2])))
    assert az[0] == pytest.approx(-90, abs=1e-9) and az[1] == pytest.approx(90, abs=1e-9)
    assert el[2] == pytest.approx(-45, abs=1e-9) and el[3] == pytest.approx(45, abs=1e-9)


def test_rectified_image_and_cylindrical_camera_agree():
    """Content placed around a 3D point's ray in the fisheye image lands, after rectification,
    where the cylindrical camera projects that point (to a fraction of a pixel)."""
    rig = load_rig("configs/rigs/default.yaml")
    rect = Rectifier(rig)
    checked = 0
    for name, points in (("front", ([8.0, 2.0, 0.0], [6.0, -4.0, 1.0], [12.0, 0.5, 0.0])),
                         ("left", ([1.0, 6.0, 0.0], [4.0, 3.0, 0.5]))):
        rc, cyl = rig[name], rect.rig[name]
        for p in points:
            uv_f, ok_f = rc.project_ego(np.array(p))
            uv_c, ok_c = cyl.project_ego(np.array(p))
            assert ok_f and ok_c and rc.camera.inside(uv_f)
            if not (15 < uv_c[0] < cyl.camera.width - 15 and 15 < uv_c[1] < cyl.camera.height - 15):
                continue
            direction = rc.ego_to_cam[:3, :3] @ np.array(p) + rc.ego_to_cam[:3, 3]
            fisheye = sphere_blob(rc.camera, direction, sigma_rad=0.012)
            assert np.abs(centroid(fisheye, uv_f) - uv_f).max() < 0.2  # the content sits on the point
            out = rect(name, fisheye)
            assert out.shape == (cyl.camera.height, cyl.camera.width)
            assert np.abs(centroid(out, uv_c) - uv_c).max() < 0.2, (name, p, centroid(out, uv_c), uv_c)
            checked += 1
    assert checked >= 4


def test_rectification_loses_field_of_view():
    rig = load_rig("configs/rigs/default.yaml")
    rect = Rectifier(rig, 180.0, 90.0)
    lost = lost_fisheye_pixels(rig["front"], rect.rig["front"].camera)
    assert 0.05 < lost < 0.6
    wider = lost_fisheye_pixels(rig["front"], cylindrical_camera(480, 302, 200.0, 120.0))
    assert wider < lost
    grid = BevGrid.from_dict({"bound": 25.0, "res": 0.5})
    fish, cyl = covered_cells(rig, grid), covered_cells(rect.rig, grid)
    assert fish.mean() > 0.9 and (cyl & ~fish).mean() < 1e-3 and cyl.mean() <= fish.mean()
