"""Render agreement (real bpy, real Cycles renders, real multilayer EXR files).

A closed room with a ground plane and boxes, an ego empty at a non-trivial pose, a camera mounted on
it at a non-trivial cam_to_ego. Every one of the eleven models is rendered through its OSL shader at
64x48 with fx != fy and an off-centre principal point (1 sample, Depth + Position passes). For every
hit pixel the world position, projected through our rig camera, must land on the pixel centre
within 0.01 px; the Depth pass must be the Euclidean distance to the camera centre; the hit mask
must be exactly our valid region. The lens-polynomial fallback is held to its recorded fit error
+ 0.01 px. The top-down camera must put every ground point in its own BEV cell.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

from geometry.bev import BevGrid
from geometry.blender import fit_lens_polynomial
from geometry.cameras import MODELS, camera_from_dict
from geometry.rig import RigCamera, load_rig, make_transform, mount_rotation, rot_x, rot_z

bpy = pytest.importorskip("bpy", reason="bpy is part of the pinned environment (make setup)")
from mathutils import Matrix  # noqa: E402  (comes with bpy)

W, H = 64, 48
PX_TOL = 0.01
NEAR_POLE = 0.01  # rad
# Every model, non-square image, fx != fy, off-centre principal point, the valid-region edge in view
# where the model has one.
OSL_CAMERAS = [
    dict(model="pinhole", fx=40, fy=44, cx=30.3, cy=25.7),
    dict(model="equidistant", fx=12, fy=13, cx=33.2, cy=22.6),
    dict(model="equisolid", fx=15, fy=16, cx=33.2, cy=22.6),
    dict(model="stereographic", fx=12, fy=13, cx=33.2, cy=22.6),
    dict(model="kb_theta", fx=12, fy=13, cx=33.2, cy=22.6, p=[1.0, -0.02, 0.05, -0.005]),
    dict(model="radial_poly", cx=33.2, cy=22.6, aspect_ratio=1.05, k=[12.0, -1.0, 1.2, -0.35]),
    dict(model="opencv_fisheye", fx=12, fy=13, cx=33.3, cy=22.7, k=[-0.05, 0.0005, 0.0, 0.0]),
    dict(model="ucm", fx=14, fy=15, cx=33.2, cy=22.6, alpha=0.6),
    dict(model="eucm", fx=14, fy=15, cx=33.2, cy=22.6, alpha=0.6, beta=1.2),
    dict(model="double_sphere", fx=12, fy=13, cx=33.2, cy=22.6, xi=-0.2, alpha=0.6),
    dict(model="cylindrical", fx=10, fy=12, cx=33.2, cy=22.6),
    dict(model="mei", fx=24, fy=25, cx=33.2, cy=22.6, s=0.1, xi=0.9, k=[-0.2, 0.04, 0.001, -0.0005]),
]
# Radially symmetric, square pixels: what the lens polynomial can render.
POLY_CAMERAS = [
    dict(model="equidistant", fx=12, fy=12, cx=33.2, cy=22.6),
    dict(model="opencv_fisheye", fx=16, fy=16, cx=33.2, cy=22.6, k=[-0.02, 0.003, 0.0, 0.0]),
    dict(model="kb_theta", fx=14, fy=14, cx=30.1, cy=24.9, p=[1.0, 0.0, 0.04]),
    dict(model="pinhole", fx=48, fy=48, cx=33.2, cy=22.6),
]

EGO_POSE = make_transform(rot_z(math.radians(30.0)) @ rot_x(math.radians(2.0)), [12.0, -7.0, 0.3])
CAM_TO_EGO = make_transform(mount_rotation(yaw_deg=20.0, pitch_deg=15.0, roll_deg=5.0), [1.5, 0.3, 1.2])
MARKER_XY = (1.375, -0.875)  # ego metres: the centre of cell (10, 15)
TOPDOWN_GRID = BevGrid(x_min=-4.0, x_max=4.0, y_min=-3.0, y_max=3.0, res=0.25)  # 32 rows x 24 cols


def _box(name, location, size, pass_index):
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=location)
    obj = bpy.context.active_object
    obj.name = name
    obj.scale = size
    obj.pass_index = pass_index
    return obj


def build_scene():
    """A fresh scene: room, ground, boxes, the ego empty at EGO_POSE and a marker on it."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    sc.render.engine = "CYCLES"
    sc.cycles.device = "CPU"
    sc.cycles.samples = 1
    sc.cycles.use_denoising = False
    sc.cycles.use_adaptive_sampling = False
    sc.render.use_persistent_data = True
    vl = sc.view_layers[0]
    vl.use_pass_z = vl.use_pass_position = vl.use_pass_object_index = True
    st = sc.render.image_settings
    st.file_format, st.color_depth = "OPEN_EXR_MULTILAYER", "32"

    ex, ey = EGO_POSE[0, 3], EGO_POSE[1, 3]
    _box("room", (ex, ey, 4.0), (40.0, 40.0, 12.0), 1)  # closed: every ray hits something
    bpy.ops.mesh.primitive_plane_add(size=30.0, location=(ex, ey, 0.0))
    bpy.context.active_object.pass_index = 2
    for i, (dx, dy, s) in enumerate([(6, 2, 1.5), (-3, 5, 2.0), (2, -6, 1.0), (-5, -4, 2.5), (0.5, 3, 0.8)]):
        _box(f"box{i}", (ex + dx, ey + dy, s / 2), (s, s, s), 10 + i)

    ego = bpy.data.objects.new("ego", None)
    sc.collection.objects.link(ego)
    ego.matrix_world = Matrix(EGO_POSE.tolist())  # (a plain nested list would be read as columns)
    # marker: a thin slab filling the BEV cell around MARKER_XY, in the ego frame
    marker = _box("marker", (0.0, 0.0, 0.0), (0.1, 0.1, 0.05), 99)
    marker.parent = ego
    marker.matrix_parent_inverse.identity()
    marker.location = (MARKER_XY[0], MARKER_XY[1], 0.5)
    bpy.context.view_layer.update()
    return sc, ego


@pytest.fixture(scope="module")
def scene():
    return build_scene()


def _render(sc, obj, path):
    from blender_scripts.camera import use_camera

    use_camera(sc, obj)
    sc.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    ch = OpenEXR.File(str(path)).channels()
    pos = np.stack([ch[f"ViewLayer.Position.{a}"].pixels for a in "XYZ"], -1).astype(np.float64)
    return {
        "depth": ch["ViewLayer.Depth.Z"].pixels.astype(np.float64),
        "position": pos,
        "index": ch["ViewLayer.IndexOB.X"].pixels if "ViewLayer.IndexOB.X" in ch else ch["ViewLayer.IndexOB"].pixels,
    }


def _agreement(rc: RigCamera, out) -> dict:
    """Figures of one render against our rig camera: worst px error, depth error, mask mismatches."""
    cam = rc.camera
    grid = cam.pixel_grid().numpy()
    rays, valid = cam.unproject(grid)
    valid &= cam.inside(grid)
    # Within NEAR_POLE of straight backwards a whole ring of pixels maps to almost one ray, so a
    # float32 Position pass cannot resolve the pixel there (its error grows as 1/sin(theta)).
    resolvable = np.arctan2(np.hypot(rays[..., 0], rays[..., 1]), rays[..., 2]) < math.pi - NEAR_POLE
    hit = out["depth"] < 1e9
    world = out["position"]
    ego = (world - EGO_POSE[:3, 3]) @ EGO_POSE[:3, :3]  # world -> ego: R^T (p - t)
    uv, proj_ok = rc.project_ego(ego)
    err = np.linalg.norm(uv - grid, axis=-1)
    centre = (EGO_POSE @ rc.cam_to_ego)[:3, 3]
    dist = np.linalg.norm(world - centre, axis=-1)
    return {
        "hits": int(hit.sum()),
        "mask_mismatch": int((hit != valid).sum()),
        "project_fail": int((hit & ~proj_ok).sum()),
        "px_err": float(err[hit & resolvable].max()),
        "near_pole": int((hit & ~resolvable).sum()),
        "depth_err": float(np.abs(out["depth"] - dist)[hit].max()),
        "max_dist": float(dist[hit].max()),
    }


def test_every_model_has_a_shader_template():
    from geometry.blender import osl_shader_source

    assert sorted(d["model"] for d in OSL_CAMERAS) == sorted(MODELS)
    for d in OSL_CAMERAS:
        src = osl_shader_source(camera_from_dict(dict(d, width=W, height=H)))
        assert "$" not in src.split("*/", 1)[1], d["model"]


def test_osl_render_agreement(scene, tmp_path):
    from blender_scripts.camera import add_rig_camera

    sc, ego = scene
    figures = {}
    for d in OSL_CAMERAS:
        cam = camera_from_dict(dict(d, width=W, height=H))
        rc = RigCamera(d["model"], cam, CAM_TO_EGO)
        obj = add_rig_camera(f"osl_{d['model']}", cam, CAM_TO_EGO, parent=ego, method="osl", workdir=tmp_path / "osl")
        figures[d["model"]] = _agreement(rc, _render(sc, obj, tmp_path / f"{d['model']}.exr"))
    print("\nOSL render agreement (64x48, 1 sample): worst px error, worst |depth - distance| m, mask mismatches")
    for m, f in figures.items():
        print(f"  {m:15s} px {f['px_err']:.2e}  depth {f['depth_err']:.2e} (max dist {f['max_dist']:.1f} m)  "
              f"mask {f['mask_mismatch']}  hits {f['hits']}/{W * H}  near-pole {f['near_pole']}")
    for m, f in figures.items():
        assert f["hits"] > 0.5 * W * H, m
        assert f["mask_mismatch"] == 0, (m, f)
        assert f["project_fail"] == 0, (m, f)
        assert f["px_err"] <= PX_TOL, (m, f)
        assert f["depth_err"] <= 1e-5 * f["max_dist"] + 1e-5, (m, f)
    # the valid-region edge is in view for the models that have one (the mask check means something)
    for m in ("equidistant", "equisolid", "kb_theta", "radial_poly", "opencv_fisheye", "ucm", "eucm",
              "double_sphere", "cylindrical"):
        assert figures[m]["hits"] < W * H, m


def test_polynomial_fallback_agreement(scene, tmp_path):
    from blender_scripts.camera import add_rig_camera

    sc, ego = scene
    figures = {}
    for d in POLY_CAMERAS:
        cam = camera_from_dict(dict(d, width=W, height=H))
        rc = RigCamera(d["model"], cam, CAM_TO_EGO)
        obj = add_rig_camera(f"poly_{d['model']}", cam, CAM_TO_EGO, parent=ego, method="polynomial")
        assert obj["fit_error_px"] == pytest.approx(fit_lens_polynomial(cam).fit_error_px)
        figures[d["model"]] = dict(_agreement(rc, _render(sc, obj, tmp_path / f"poly_{d['model']}.exr")),
                                   fit=float(obj["fit_error_px"]))
    print("\nlens-polynomial fallback (64x48): recorded fit error vs rendered worst px error")
    for m, f in figures.items():
        print(f"  {m:15s} fit {f['fit']:.2e}  rendered px {f['px_err']:.2e}  depth {f['depth_err']:.2e}  "
              f"mask {f['mask_mismatch']}  near-pole pixels left out {f['near_pole']}")
    for m, f in figures.items():
        assert f["mask_mismatch"] == 0, (m, f)
        assert f["px_err"] <= f["fit"] + PX_TOL, (m, f)
        assert f["depth_err"] <= 1e-5 * f["max_dist"] + 1e-5, (m, f)


def test_topdown_camera_pixels_are_bev_cells(scene, tmp_path):
    from blender_scripts.camera import add_topdown_camera

    sc, ego = scene
    grid = TOPDOWN_GRID
    obj = add_topdown_camera(grid, height_m=6.0, parent=ego)
    out = _render(sc, obj, tmp_path / "topdown.exr")
    assert out["depth"].shape == grid.shape
    ego_xyz = (out["position"] - EGO_POSE[:3, 3]) @ EGO_POSE[:3, :3]
    centres = grid.cell_centres()
    off = np.abs(ego_xyz[..., :2] - centres).max()
    rows, cols = np.nonzero(out["index"] == 99)
    r0, c0, _ = grid.cell_of(np.array(MARKER_XY))
    print(f"\ntop-down {grid.cols}x{grid.rows}: worst |hit xy - cell centre| {off:.2e} m; marker at "
          f"cells {sorted(set(zip(rows.tolist(), cols.tolist())))}, expected ({int(r0)}, {int(c0)})")
    assert off <= PX_TOL * grid.res
    assert list(zip(rows.tolist(), cols.tolist())) == [(int(r0), int(c0))]


def test_use_camera_refuses_osl_on_a_gpu_without_optix(scene, tmp_path):
    from blender_scripts.camera import add_rig_camera, use_camera

    sc, ego = scene
    prefs = bpy.context.preferences.addons["cycles"].preferences
    if prefs.compute_device_type == "OPTIX":
        pytest.skip("this machine has OptiX, which runs OSL cameras")
    cam = camera_from_dict(dict(OSL_CAMERAS[1], width=W, height=H))
    obj = add_rig_camera("gpu_check", cam, CAM_TO_EGO, parent=ego, workdir=tmp_path)
    sc.cycles.device = "GPU"
    try:
        with pytest.raises(RuntimeError, match="method='polynomial'"):
            use_camera(sc, obj)
    finally:
        sc.cycles.device = "CPU"
    with pytest.raises(ValueError, match="method must be one of"):
        add_rig_camera("bad", cam, CAM_TO_EGO, parent=ego, method="fisheye")


def test_default_rig_front_camera_full_size(scene, tmp_path):
    """The production set-up: the default rig's 190-degree front camera at 480x302, both paths."""
    from blender_scripts.camera import add_rig_camera

    sc, ego = scene
    rc = load_rig(Path(__file__).resolve().parents[1] / "configs/rigs/default.yaml")["front"]
    figures = {}
    for method in ("osl", "polynomial"):
        obj = add_rig_camera(f"rig_front_{method}", rc.camera, rc.cam_to_ego, parent=ego, method=method,
                             workdir=tmp_path)
        f = _agreement(rc, _render(sc, obj, tmp_path / f"front_{method}.exr"))
        figures[method] = dict(f, fit=float(obj["fit_error_px"]))
    print(f"\ndefault rig front 480x302: OSL px {figures['osl']['px_err']:.2e}, lens polynomial px "
          f"{figures['polynomial']['px_err']:.2e} (fit {figures['polynomial']['fit']:.2e}); mask mismatches "
          f"{figures['osl']['mask_mismatch']}, {figures['polynomial']['mask_mismatch']}")
    for method, f in figures.items():
        assert f["hits"] == rc.camera.width * rc.camera.height, method  # 190 degrees: every pixel valid
        assert f["mask_mismatch"] == 0 and f["project_fail"] == 0, method
        assert f["px_err"] <= f["fit"] + PX_TOL, method
        assert f["depth_err"] <= 1e-5 * f["max_dist"] + 1e-5, method
