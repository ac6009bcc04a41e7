"""Blender cameras that render exactly our camera models (runs with bpy).

    ego = bpy.data.objects.new("ego", None)            # world matrix = ego pose
    cam = add_rig_camera("front", rc.camera, rc.cam_to_ego, parent=ego)   # OSL, exact
    use_camera(scene, cam); bpy.ops.render.render(write_still=True)

``method='osl'`` renders through a Custom (OSL) camera shader generated from the model (Cycles on
the CPU, or OptiX); ``method='polynomial'`` uses the built-in FISHEYE_LENS_POLYNOMIAL fitted to the
model (any Cycles device) and stores the fit's worst reprojection error in obj["fit_error_px"].
The mapping itself (frames, shader text, fit, top-down maths) lives in geometry/blender.py.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix

from common.files import write_with
from geometry.bev import BevGrid
from geometry.blender import (
    BlenderFitError,
    blender_camera_matrix,
    fit_lens_polynomial,
    topdown_camera,
    write_osl_shader,
)
from geometry.cameras import Camera

METHODS = ("osl", "polynomial")
__all__ = ["add_rig_camera", "add_topdown_camera", "use_camera", "BlenderFitError", "METHODS"]


def _enable_oslquery() -> None:
    """Cycles' Custom-camera update handler imports the wheel's own `oslquery`, which is not on
    sys.path in the bpy wheel; without it every custom_filepath change prints a traceback."""
    python = bpy.utils.system_resource("PYTHON")
    for p in Path(python).glob("lib/python3*/site-packages") if python else ():
        if (p / "oslquery").is_dir() and str(p) not in sys.path:
            sys.path.append(str(p))


def _compile_osl(osl_path: Path) -> Path:
    """Compile the shader to <name>.oso beside it now, so an error shows here and not as a black
    render; Cycles reuses the .oso (it recompiles only when the .osl is newer)."""
    import _cycles

    oso = osl_path.with_suffix(".oso")
    if oso.is_file() and oso.stat().st_mtime >= osl_path.stat().st_mtime:
        return oso

    def compile_to(tmp):
        if not _cycles.osl_compile(str(osl_path), str(tmp)):
            raise RuntimeError(f"{osl_path}: OSL compilation failed (see the console above)")

    write_with(oso, compile_to)
    return oso


def _new_camera_object(name: str, parent):
    data = bpy.data.cameras.new(name)
    obj = bpy.data.objects.new(name, data)
    if parent is not None:
        for coll in parent.users_collection:
            coll.objects.link(obj)
        obj.parent = parent
        obj.matrix_parent_inverse = Matrix.Identity(4)
    else:
        bpy.context.scene.collection.objects.link(obj)
    data.dof.use_dof = False
    return obj, data


def add_rig_camera(name: str, camera: Camera, cam_to_ego: np.ndarray, parent=None, method: str = "osl",
                   workdir=None):
    """A Cycles camera object that renders exactly `camera` mounted at `cam_to_ego`.

    parent: an ego empty whose world matrix is the ego pose (None: ego frame = world frame).
    method: 'osl' (exact, every model) or 'polynomial' (FISHEYE_LENS_POLYNOMIAL fit; raises
    BlenderFitError where it cannot meet the tolerance). workdir: where generated shaders go.
    """
    if method not in METHODS:
        raise ValueError(f"camera '{name}': method must be one of {METHODS}, got {method!r}")
    obj, data = _new_camera_object(name, parent)
    obj.matrix_basis = Matrix(blender_camera_matrix(cam_to_ego).tolist())
    data.clip_start = 1e-3
    data.clip_end = 1e4
    if method == "osl":
        _enable_oslquery()
        shader = write_osl_shader(camera, workdir)
        _compile_osl(shader)
        data.type = "CUSTOM"
        data.custom_mode = "EXTERNAL"
        data.custom_filepath = str(shader)
        obj["fit_error_px"] = 0.0
    else:
        try:
            fit = fit_lens_polynomial(camera)
        except BlenderFitError:
            bpy.data.objects.remove(obj)
            bpy.data.cameras.remove(data)
            raise
        data.type = "PANO"
        data.panorama_type = "FISHEYE_LENS_POLYNOMIAL"
        data.sensor_fit = "AUTO"
        data.sensor_width = fit.sensor_width
        data.fisheye_fov = fit.fov
        (data.fisheye_polynomial_k0, data.fisheye_polynomial_k1, data.fisheye_polynomial_k2,
         data.fisheye_polynomial_k3, data.fisheye_polynomial_k4) = fit.k
        data.shift_x, data.shift_y = fit.shift_x, fit.shift_y
        obj["fit_error_px"] = float(fit.fit_error_px)
        obj["lens_polynomial"] = json.dumps(fit.to_dict())
    obj["method"] = method
    obj["width"], obj["height"] = camera.width, camera.height
    obj["camera"] = json.dumps(camera.to_dict())
    obj["cam_to_ego"] = json.dumps(np.asarray(cam_to_ego, dtype=float).tolist())
    return obj


def add_topdown_camera(grid: BevGrid, height_m: float, parent=None, name: str = "topdown"):
    """Orthographic camera looking straight down over `grid`: rendered pixel (row i, col j) is BEV
    cell (i, j) (image up = ego +x, image left = ego +y). `use_camera` sets cols x rows."""
    td = topdown_camera(grid, height_m)
    obj, data = _new_camera_object(name, parent)
    obj.matrix_basis = Matrix(td.blender_matrix.tolist())
    data.type = "ORTHO"
    data.sensor_fit = "AUTO"
    data.ortho_scale = td.ortho_scale
    data.shift_x = data.shift_y = 0.0
    data.clip_start = 1e-3
    data.clip_end = td.clip_end
    obj["method"] = "ortho"
    obj["width"], obj["height"] = td.width, td.height
    obj["grid"] = json.dumps(grid.to_dict())
    return obj


def use_camera(scene, obj) -> None:
    """Make `obj` the scene's camera and set what must change with it: resolution (100 %, square
    pixels), no border crop; an OSL camera also needs Cycles on the CPU (or OptiX)."""
    if "width" not in obj or "height" not in obj:
        raise ValueError(f"camera '{obj.name}' was not made by add_rig_camera/add_topdown_camera")
    scene.camera = obj
    r = scene.render
    r.resolution_x, r.resolution_y = int(obj["width"]), int(obj["height"])
    r.resolution_percentage = 100
    r.pixel_aspect_x = r.pixel_aspect_y = 1.0
    r.use_border = False
    if obj.get("method") == "osl" and scene.render.engine == "CYCLES" and scene.cycles.device == "GPU":
        prefs = bpy.context.preferences.addons["cycles"].preferences
        if prefs.compute_device_type != "OPTIX":
            raise RuntimeError(f"camera '{obj.name}': OSL cameras need Cycles on the CPU or OptiX, not "
                               f"{prefs.compute_device_type}; use method='polynomial'")
