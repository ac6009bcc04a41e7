"""Build a Blender scene from a checked recipe: layout, assets, traffic, weather, ego and rig.

Instance ids (object `pass_index`) are given in creation order from 1, so the same recipe gives the
same ids; material `pass_index` is the fine class (see dataset_tools/classes.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import bpy
import numpy as np
from mathutils import Matrix

from dataset_tools.labels.classes import CLASS_IDS, OVERHEAD_OCCLUDERS
from . import assets, lighting
from .camera import add_rig_camera, add_topdown_camera
from .layouts import Layout, build_layout
from .materials import MATERIAL_CLASSES, build_materials
from .people import place_people
from .meshes import MeshData
from .traffic import ego_pose, place_traffic, vehicle_pose
from .two_wheelers import place_two_wheelers


MAX_HEADLIGHT_CARS = 24


@dataclass
class BuiltScene:
    recipe: dict
    weather: dict
    layout: Layout
    vehicles: list  # (Vehicle, bpy object)
    objects: dict  # instance id -> {"name", "class"}
    occluders: list  # bpy objects hidden for the ground-level top-down pass
    ego: object  # ego empty
    cameras: dict  # rig camera name -> bpy camera object
    topdown: object
    fit_errors: dict = field(default_factory=dict)
    ego_body: list = field(default_factory=list)  # bpy objects of the ego car (hidden from the top-down camera)
    ego_meta: dict | None = None  # meta.json's `ego`: footprint box, kind


def scene_rng(seed: int, *keys: int) -> np.random.Generator:
    """A generator for (scene seed, keys...): independent streams, same everywhere."""
    return np.random.default_rng([int(seed), *[int(k) for k in keys]])


def reset_blender() -> None:
    bpy.ops.wm.read_factory_settings(use_empty=True)


def _mesh_object(name, data: MeshData, mats, instance: int, location=(0, 0, 0), yaw=0.0):
    mesh = bpy.data.meshes.new(name)
    v = data.vertices
    mesh.from_pydata(v.tolist(), [], data.faces)
    names = sorted(set(data.mats))
    for n in names:
        mesh.materials.append(mats[n])
    index = {n: i for i, n in enumerate(names)}
    mesh.polygons.foreach_set("material_index", [index[n] for n in data.mats])
    if data.smooth_angle is not None:
        mesh.shade_smooth()
        mesh.set_sharp_from_angle(angle=math.radians(data.smooth_angle))
    mesh.update()
    obj = bpy.data.objects.new(name, mesh)
    obj.location = location
    obj.rotation_euler = (0.0, 0.0, yaw)
    obj.pass_index = instance
    bpy.context.scene.collection.objects.link(obj)
    classes = [CLASS_IDS[MATERIAL_CLASSES[n]] for n in data.mats]
    main = max(set(classes), key=classes.count)
    return obj, main, set(classes)


def build_scene(recipe: dict, rig, grid, topdown_height: float = 60.0, osl_workdir=None,
                camera_method: str = "osl", ego_body: bool = True) -> BuiltScene:
    """Everything static plus the movable ego and vehicles; call `set_frame` to pose them."""
    reset_blender()
    scene = bpy.context.scene
    seed = recipe["seed"]
    layout = build_layout(recipe, scene_rng(seed, 1))
    weather = lighting.resolve_weather(recipe["weather"], scene_rng(seed, 2))
    mats = build_materials(weather)
    objects, occluders = {}, []
    next_id = 1
    for so in layout.objects:
        obj, cls, classes = _mesh_object(so.name, so.mesh, mats, next_id, so.location, so.yaw)
        if so.color is not None:
            obj.color = (*so.color, 1.0)
        objects[next_id] = {"name": so.name, "class": _class_name(cls)}
        if classes <= OVERHEAD_OCCLUDERS:
            occluders.append(obj)
        next_id += 1
    vehicles = []
    rng = scene_rng(recipe["traffic"]["seed"], 3)
    for k, v in enumerate(place_traffic(layout, recipe, rng)):
        obj, cls, _ = _mesh_object(f"vehicle{k}_{v.kind}", assets.vehicle_mesh(v.kind, v.size, rng), mats, next_id)
        obj.color = v.color  # RGB and, as alpha, whether the paint is metallic
        obj["lights"] = 0.0 if v.parked_pose is not None else 1.0  # parked cars have their lamps off
        objects[next_id] = {"name": obj.name, "class": "vehicle"}
        vehicles.append((v, obj))
        next_id += 1
    for k, (mesh, loc, yaw) in enumerate(place_people(layout, scene_rng(seed, 8))):
        obj, _, _ = _mesh_object(f"person{k}", mesh, mats, next_id, loc, yaw)
        objects[next_id] = {"name": obj.name, "class": "pedestrian"}
        next_id += 1
    for k, (cls, mesh, loc, yaw, paint) in enumerate(place_two_wheelers(layout, scene_rng(seed, 9))):
        obj, _, _ = _mesh_object(f"{cls}{k}", mesh, mats, next_id, loc, yaw)
        if paint is not None:
            obj.color = (*paint, 1.0)
        objects[next_id] = {"name": obj.name, "class": cls}
        next_id += 1
    if weather["lights_on"]:
        # spot lights for the vehicles nearest the ego's start; farther ones keep glowing lamps
        ex, ey, _ = ego_pose(layout, recipe, 0.0)
        near = sorted(vehicles, key=lambda vo: math.dist(vehicle_pose(layout, vo[0], 0.0)[:2], (ex, ey)))
        for v, obj in [vo for vo in near if vo[0].parked_pose is None][:MAX_HEADLIGHT_CARS]:
            lighting.add_headlights(scene, obj, v.size[0], v.size[1])
    lighting.setup_world(scene, weather)
    if weather["lights_on"]:
        lighting.add_street_lamps(scene, layout.lamps)

    ego = bpy.data.objects.new("ego", None)
    scene.collection.objects.link(ego)
    cams, fit_errors = {}, {}
    for rc in rig:
        cam = add_rig_camera(rc.name, rc.camera, rc.cam_to_ego, parent=ego, method=camera_method,
                             workdir=osl_workdir)
        cams[rc.name] = cam
        fit_errors[rc.name] = float(cam.get("fit_error_px", 0.0))
    topdown = add_topdown_camera(grid, topdown_height, parent=ego)
    body, ego_meta = [], None
    if ego_body:
        mesh, box, kind, colour = assets.ego_body([np.asarray(rc.cam_to_ego)[:3, 3] for rc in rig], scene_rng(seed, 5))
        obj, _, _ = _mesh_object("ego_body", mesh, mats, next_id)
        obj.color = (*colour, 1.0)  # alpha 1: metallic paint
        obj["lights"] = 1.0
        obj.parent = ego
        objects[next_id] = {"name": obj.name, "class": "ego"}
        body.append(obj)
        ego_meta = {"box": box, "kind": kind, "instance": next_id}
        next_id += 1
        if weather["lights_on"]:  # the ego drives with its headlights on
            lighting.add_headlights(scene, ego, box[1] - box[0], box[3] - box[2], front_x=box[1])
    return BuiltScene(recipe, weather, layout, vehicles, objects, occluders, ego, cams, topdown, fit_errors,
                      body, ego_meta)


def _class_name(cid: int) -> str:
    from dataset_tools.labels.classes import CLASS_NAMES

    return CLASS_NAMES[cid]


def pose_matrix(x, y, yaw) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    m = np.eye(4)
    m[:2, :2] = [[c, -s], [s, c]]
    m[:2, 3] = [x, y]
    return m


def set_frame(built: BuiltScene, frame: int) -> dict:
    """Pose the ego and the traffic at the frame's time; returns the frame's actor metadata."""
    r = built.recipe
    t = frame / r["frames"]["rate_hz"]
    ex, ey, eyaw = ego_pose(built.layout, r, t)
    ego_to_world = pose_matrix(ex, ey, eyaw)
    built.ego.matrix_world = Matrix(ego_to_world.tolist())
    world_to_ego = np.linalg.inv(ego_to_world)
    actors = []
    for v, obj in built.vehicles:
        x, y, yaw = vehicle_pose(built.layout, v, t)
        obj.location = (x, y, 0.0)
        obj.rotation_euler = (0.0, 0.0, yaw)
        c = world_to_ego @ np.array([x, y, v.size[2] / 2, 1.0])
        rel = (yaw - eyaw + math.pi) % (2 * math.pi) - math.pi
        actors.append({
            "instance": obj.pass_index, "class": "vehicle", "kind": v.kind,
            "box": {"center": [float(a) for a in c[:3]], "size": [float(a) for a in v.size], "yaw": float(rel)},
            "parked": v.parked_pose is not None,
        })
    bpy.context.view_layer.update()
    return {"time_s": t, "ego_pose": {"x": ex, "y": ey, "yaw": eyaw, "ego_to_world": ego_to_world.tolist()},
            "actors": actors, "world_to_ego": world_to_ego, "motion": frame_motion(built, t)}


MOTION_DT = 0.04  # s: the span around a frame the motion blur's paths are taken over (>= any exposure)


def frame_motion(built: BuiltScene, t: float, dt: float = MOTION_DT) -> dict:
    """How the scene moves over `dt` seconds centred on time t (sensor.motion_flow): the ego's
    world-to-ego matrices at both ends and, per moving vehicle, the world motion from its pose at t
    to its pose at each end."""
    r, lay = built.recipe, built.layout
    ends = (t - dt / 2, t + dt / 2)
    w2e = [np.linalg.inv(pose_matrix(*ego_pose(lay, r, s))).tolist() for s in ends]
    moving = {}
    for v, obj in built.vehicles:
        if v.parked_pose is None:
            at_t = np.linalg.inv(pose_matrix(*vehicle_pose(lay, v, t)))
            moving[obj.pass_index] = [(pose_matrix(*vehicle_pose(lay, v, s)) @ at_t).tolist() for s in ends]
    return {"dt": dt, "world_to_ego": w2e, "instances": moving}
