"""Constructed frames rendered by Blender: the ground plane and axis-aligned boxes of
testing.constructed, plus flat paint strips, built as real objects and rendered
through the production render path (render_fisheye, label_mode, render_topdown) into a frame
directory that fusion and the audit read like any other. The tests' proof that the labels are
right for geometry whose answer is known exactly.
"""

from __future__ import annotations

from pathlib import Path

import bpy
import numpy as np

from blender_scripts import lighting
from blender_scripts.build_scene import _mesh_object, reset_blender, scene_rng
from blender_scripts.camera import add_rig_camera, add_topdown_camera
from blender_scripts.materials import MATERIAL_CLASSES, build_materials
from blender_scripts.render_frame import configure_render, label_mode, render_fisheye, render_topdown
from blender_scripts.meshes import MeshData
from dataset_tools.format.exr import write_exr
from dataset_tools.format.layout import FrameFiles
from dataset_tools.format.meta import FrameMeta, write_meta

from .constructed import GROUND_INSTANCE, Box
# the fine class of a Box -> the material that paints it
CLASS_MATERIAL = {"vehicle": "car_paint", "curb": "kerb", "building": "wall", "road": "asphalt",
                  "lane_marking": "paint_white", "sidewalk": "pavement", "barrier": "barrier_concrete"}
PAINT_Z = 0.01


def build_boxes(boxes, paint=(), ground_half: float = 60.0):
    """A fresh scene: a road plane at z = 0 (instance 1), `boxes` (their own instance ids) and
    paint strips (x0, x1, y0, y1) lane_marking 1 cm above the road (instance 2)."""
    reset_blender()
    weather = lighting.resolve_weather({"preset": "clear_noon"}, scene_rng(0, 2))
    mats = build_materials(weather)
    assert all(m in MATERIAL_CLASSES for m in CLASS_MATERIAL.values())
    _mesh_object("ground", MeshData().rect(-ground_half, ground_half, -ground_half, ground_half, 0.0, "asphalt"),
                 mats, GROUND_INSTANCE)
    if paint:
        lines = MeshData()
        for x0, x1, y0, y1 in paint:
            lines.rect(x0, x1, y0, y1, PAINT_Z, "paint_white")
        _mesh_object("paint", lines, mats, 2)
    for k, b in enumerate(boxes):
        mesh = MeshData().box(((b.x0 + b.x1) / 2, (b.y0 + b.y1) / 2, b.z0), (b.x1 - b.x0, b.y1 - b.y0, b.z1 - b.z0),
                              mat=CLASS_MATERIAL[b.fine])
        _mesh_object(f"box{k}", mesh, mats, b.instance)
    lighting.setup_world(bpy.context.scene, weather)


def render_boxes_frame(frame_dir, rig, grid, boxes: list[Box], paint=(), supersample: int = 2,
                       marking_share: float = 0.25, tmpdir=None, osl_dir=None) -> Path:
    """Build and render one constructed frame (1 sample) in the renderer's layout; the ego frame is
    the world frame. Returns the frame directory."""
    files = FrameFiles(frame_dir)
    files.dir.mkdir(parents=True, exist_ok=True)
    tmpdir = Path(tmpdir or files.dir / ".tmp")
    tmpdir.mkdir(parents=True, exist_ok=True)
    build_boxes(boxes, paint)
    scene = bpy.context.scene
    ego = bpy.data.objects.new("ego", None)
    scene.collection.objects.link(ego)
    cams = {rc.name: add_rig_camera(rc.name, rc.camera, rc.cam_to_ego, parent=ego, workdir=osl_dir) for rc in rig}
    top = add_topdown_camera(grid, 60.0, parent=ego)
    configure_render(scene, samples=1, denoise=False, threads=2, max_bounces=0)
    clock: dict = {}
    for rc in rig:
        render_fisheye(scene, cams[rc.name], rc.camera.width, rc.camera.height, files.dir, rc.name, tmpdir, clock)
    with label_mode(scene):
        td = render_topdown(scene, top, grid.cols, [], np.eye(4), tmpdir, supersample, marking_share)
    write_exr(files.topdown, td)
    write_meta(files.dir, FrameMeta(rig=rig.to_dict(), weather={"preset": "clear_noon"},
                                    topdown={"grid": grid.to_dict(), "height_m": 60.0, "supersample": supersample,
                                             "marking_share": marking_share}))
    return files.dir
