"""Render one frame's passes and write them (every file atomically).

Per rig camera: `cam_<name>.exr` with R, G, B (half, linear scene light), `distance` (float32,
along the ray), `semantic` and `instance` (uint32), `position.X/Y/Z` (float32, world frame);
`cam_<name>.png`, 8-bit sRGB as Blender's view transform shows it. With the ego car's body in the
scene: `ego` (half, 1 where the camera sees the ego body) and `cam_<name>_ego.png` (255 there).
Top-down: `topdown.exr` with `all.*` (first hit from above) and `ground.*` (overhead occluders
hidden), each `semantic`, `instance` (uint32) and `height` (float32, ego-frame z of the hit), one
pixel per label cell: rendered `supersample` times finer and reduced to coverage labels
(dataset_tools.labels.coverage).
"""

from __future__ import annotations

import functools
import math
import time
from contextlib import contextmanager
from pathlib import Path

import bpy
import numpy as np

from dataset_tools.format.exr import read_exr, write_exr
from dataset_tools.format.layout import FrameFiles
from dataset_tools.labels.classes import CLASS_IDS
from dataset_tools.format.png import read_png, write_png_atomic
from dataset_tools.generation import sensor
from dataset_tools.labels.coverage import reduce_supersampled

from .camera import use_camera

BACKGROUND_DEPTH = 1e9  # Cycles writes 1e10 where a ray hits nothing
VIEW_LOOK = "AgX - Medium Low Contrast"  # the camera PNGs' tone curve (AgX's looks, Blender 4.5)


def configure_render(scene, samples: int, denoise: bool, threads: int, max_bounces: int = 4,
                     denoise_quality: str = "balanced") -> None:
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = denoise
    if denoise:
        scene.cycles.denoiser = "OPENIMAGEDENOISE"
        # ACCURATE prefiltering denoises albedo and normal too (three OIDN passes): at 2-4 samples
        # it looks the same as FAST and costs a multiple
        scene.cycles.denoising_prefilter = "FAST"
        scene.cycles.denoising_quality = denoise_quality.upper()
    scene.cycles.max_bounces = max_bounces
    scene.cycles.diffuse_bounces = min(2, max_bounces)
    scene.cycles.glossy_bounces = min(2, max_bounces)
    scene.cycles.transmission_bounces = min(2, max_bounces)
    scene.cycles.volume_bounces = 0
    scene.cycles.caustics_reflective = False
    scene.cycles.caustics_refractive = False
    scene.render.use_persistent_data = True
    scene.render.threads_mode = "FIXED"
    scene.render.threads = max(1, threads)
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = False
    scene.view_settings.view_transform = "AgX"
    # an automotive HDR camera's flatter tone curve than AgX's base look (docs/rendering.md, "Kept: a
    # flatter tone curve"): night dev vehicles +0.02 steady p, daylight unchanged
    scene.view_settings.look = VIEW_LOOK
    vl = scene.view_layers[0]
    vl.use_pass_z = True
    vl.use_pass_object_index = True
    vl.use_pass_material_index = True
    vl.use_pass_position = True
    vl.pass_alpha_threshold = 0.0  # label passes stop at the first surface, see-through glass included
    scene.update_tag()


def set_cycles(scene, **settings) -> None:
    """Change scene.cycles settings so that the next render sees them. Cycles' persistent session
    re-reads them only when the scene is tagged as changed: a bare assignment (the seed, the
    bounces) would silently apply to some later render instead (measured, Blender 4.5)."""
    for k, v in settings.items():
        setattr(scene.cycles, k, v)
    scene.update_tag()


LABEL_SURFACE = "label_surface"  # the plain shader every material shows the label renders


def _plain_surfaces() -> list:
    """Every node material's surface wired to one plain emission node of its own tree (made once,
    kept unconnected in between): the label passes are written at the first hit whatever shades it,
    and the procedural shaders (noise, bump, car paint) were half the top-down renders' time.
    -> (tree, output socket, the socket it was linked from or None) for `_restore_surfaces`."""
    saved = []
    for m in bpy.data.materials:
        nt = m.node_tree if m.use_nodes else None
        outputs = [n for n in nt.nodes if n.bl_idname == "ShaderNodeOutputMaterial"] if nt else []
        if not outputs:
            continue
        plain = nt.nodes.get(LABEL_SURFACE)
        if plain is None:
            plain = nt.nodes.new("ShaderNodeEmission")
            plain.name = LABEL_SURFACE
        for out in outputs:
            sock = out.inputs["Surface"]
            saved.append((nt, sock, sock.links[0].from_socket if sock.is_linked else None))
            nt.links.new(plain.outputs["Emission"], sock)
    return saved


def _restore_surfaces(saved: list) -> None:
    for nt, sock, src in saved:
        if src is not None:
            nt.links.new(src, sock)
        else:
            for link in list(sock.links):
                nt.links.remove(link)


@contextmanager
def label_mode(scene):
    """Settings for renders whose only use is the label passes (written at the first hit): one
    sample at the pixel centre, no denoising, no bounces (through glass neither), no lights, no sky
    (half the two top-down renders' time), and a plain shader on every surface (`_plain_surfaces`:
    half again, 0.63 s a `medium` frame instead of 1.35). Everything is restored on exit, and
    nothing leaves Cycles' scene on the way: objects hidden and shown again come back in another
    order, and later frames' noise would then depend on what was rendered before. The sky goes
    through the view layer's `use_sky`: changing the world itself makes Cycles recompute the
    Nishita sky (0.15 s)."""
    c = scene.cycles
    view_layer = scene.view_layers[0]
    saved = {k: getattr(c, k) for k in ("samples", "use_denoising", "max_bounces", "transparent_max_bounces")}
    lights = [o.data for o in scene.objects if o.type == "LIGHT"]  # zero strength: left out
    energies = [light.energy for light in lights]
    use_sky = view_layer.use_sky
    # no path goes on through see-through glass either: the passes already stopped at it
    set_cycles(scene, samples=1, use_denoising=False, max_bounces=0, transparent_max_bounces=0)
    for light in lights:
        light.energy = 0.0
    view_layer.use_sky = False
    surfaces = _plain_surfaces()
    try:
        yield
    finally:
        _restore_surfaces(surfaces)
        view_layer.use_sky = use_sky
        for light, e in zip(lights, energies):
            light.energy = e
        set_cycles(scene, **saved)


def _light_image(lin: np.ndarray):
    """A float image of Blender's holding the scene-linear light `lin` (H, W, 3, rows top-down), to be
    written through the scene's view transform as a render is (`save_render`)."""
    h, w = lin.shape[:2]
    im = bpy.data.images.get("camera_light")
    if im is None:
        im = bpy.data.images.new("camera_light", w, h, float_buffer=True, alpha=True)
        im.colorspace_settings.name = "Linear Rec.709"
    elif tuple(im.size) != (w, h):
        im.scale(w, h)
    rgba = np.ones((h, w, 4), np.float32)
    rgba[..., :3] = lin[::-1]  # Blender's rows run bottom-up
    im.pixels.foreach_set(rgba.ravel())
    return im


def _render_to_exr(scene, camera, width, height, tmpdir: Path, tag: str, png: Path | None = None,
                   clock: dict | None = None, post=None, expose=None, tone=None):
    """Render through `camera` and return Blender's passes as a dict (rows top-down); time spent
    saving the PNG (through the view transform at `expose(passes)` times the light, compressed by
    `tone(light)` first when given, then `post(pixels, passes)`: the camera's auto-exposure and
    effects) goes to clock["write"]."""
    use_camera(scene, camera)
    if (scene.render.resolution_x, scene.render.resolution_y) != (width, height):
        raise RuntimeError(f"camera '{camera.name}' renders {scene.render.resolution_x}x"
                           f"{scene.render.resolution_y}, expected {width}x{height}")
    settings = scene.render.image_settings
    settings.file_format = "OPEN_EXR_MULTILAYER"
    settings.color_depth = "32"
    settings.exr_codec = "NONE"
    raw = tmpdir / f"{tag}.exr"
    scene.render.filepath = str(raw)
    bpy.ops.render.render(write_still=True)
    passes = read_exr(raw)
    raw.unlink()
    out = {k.split(".", 1)[1]: v for k, v in passes.items() if not k.startswith("Composite.")}
    for c in "RGB":  # the compositor's image (fog) replaces the render layer's where it ran
        if f"Composite.Combined.{c}" in passes:
            out[f"Combined.{c}"] = passes[f"Composite.Combined.{c}"]
    if png is not None:
        t0 = time.perf_counter()
        settings.file_format = "PNG"
        settings.color_depth = "8"
        settings.color_mode = "RGB"
        # Blender writes date and render-time text chunks: re-encode so equal pixels give equal bytes
        tmp = tmpdir / f"{tag}.png"
        gain = expose(out) if expose else 1.0
        image = bpy.data.images["Render Result"]
        if tone is not None:  # the camera's own tone mapping of the exposed light, then the view transform
            image = _light_image(tone(np.stack([out[f"Combined.{c}"] for c in "RGB"], -1).astype(np.float32) * gain))
            gain = 1.0
        scene.view_settings.exposure = math.log2(gain)  # the scene's light, before the tone curve
        try:
            image.save_render(str(tmp), scene=scene)
        finally:
            scene.view_settings.exposure = 0.0
        img = read_png(tmp, np.uint8, 3)
        write_png_atomic(png, post(img, out) if post else img)
        tmp.unlink()
        if clock is not None:
            clock["write"] = clock.get("write", 0.0) + time.perf_counter() - t0
    return out


def render_fisheye(scene, camera, width, height, out_dir: Path, name: str, tmpdir: Path, clock: dict,
                   ego_mask: bool = False, post=None, expose=None, tone=None) -> None:
    files = FrameFiles(out_dir)
    p = _render_to_exr(scene, camera, width, height, tmpdir, f"cam_{name}", files.camera_png(name), clock, post,
                       expose, tone)
    t0 = time.perf_counter()
    semantic = np.rint(p["IndexMA.X"]).astype(np.uint32)
    extra = {}
    if ego_mask:  # the camera's self-occlusion mask: 1 where the ego car's body is
        ego = semantic == CLASS_IDS["ego"]
        extra["ego"] = ego.astype(np.float16)
        write_png_atomic(files.camera_ego_mask(name), ego.astype(np.uint8) * 255)
    write_exr(files.camera_exr(name), {**extra,
        "R": p["Combined.R"].astype(np.float16),
        "G": p["Combined.G"].astype(np.float16),
        "B": p["Combined.B"].astype(np.float16),
        "distance": p["Depth.Z"].astype(np.float32),
        "semantic": semantic,
        "instance": np.rint(p["IndexOB.X"]).astype(np.uint32),
        "position.X": p["Position.X"].astype(np.float32),
        "position.Y": p["Position.Y"].astype(np.float32),
        "position.Z": p["Position.Z"].astype(np.float32),
    })
    clock["write"] = clock.get("write", 0.0) + time.perf_counter() - t0


def render_topdown(scene, camera, size: int, occluders, world_to_ego: np.ndarray, tmpdir: Path,
                   supersample: int = 1, marking_share: float = 0.25, ego_body=()) -> dict:
    """Two label renders from above: everything ('all.*', one sample per cell), then with the
    overhead occluders hidden from camera rays ('ground.*', hidden, not removed: see label_mode),
    the one the labels come from: rendered `supersample` times finer and reduced to coverage
    labels, `marking_share` of a cell's sub-samples making it paint. Every sample is at its
    (sub-)pixel's centre (a 0.01 px box filter). The ego car's body is hidden from both: the labels under it are the
    ground (the fusion marks its footprint invalid)."""
    out = {}
    n = int(supersample)
    saved = {"width": camera["width"], "height": camera["height"]}
    filt = {k: getattr(scene.cycles, k) for k in ("pixel_filter_type", "filter_width")}
    view_layer = scene.view_layers[0]
    use_position = view_layer.use_pass_position
    # the height comes from the depth (the camera looks straight down the ego's z axis): no position
    # pass, a third less EXR to write and read at the supersampled size
    view_layer.use_pass_position = False
    set_cycles(scene, pixel_filter_type="BOX", filter_width=0.01)
    cam_z = float((np.asarray(world_to_ego) @ np.append(np.asarray(camera.matrix_world.translation), 1.0))[2])
    try:
        for obj in ego_body:
            obj.visible_camera = False
        for group, hide in (("all", False), ("ground", True)):
            for obj in occluders:
                obj.visible_camera = not hide
            k = n if group == "ground" else 1
            camera["width"], camera["height"] = saved["width"] * k, saved["height"] * k
            p = _render_to_exr(scene, camera, size * k, size * k, tmpdir, f"topdown_{group}")
            depth = p["Depth.Z"]
            sem, inst, height = reduce_supersampled(
                np.rint(p["IndexMA.X"]).astype(np.uint32), np.rint(p["IndexOB.X"]).astype(np.uint32),
                np.where(depth < BACKGROUND_DEPTH, cam_z - depth.astype(np.float64), 0.0).astype(np.float32), k,
                marking_share)
            out[f"{group}.semantic"], out[f"{group}.instance"], out[f"{group}.height"] = sem, inst, height
    finally:
        for obj in [*occluders, *ego_body]:
            obj.visible_camera = True
        camera["width"], camera["height"] = saved["width"], saved["height"]
        view_layer.use_pass_position = use_position
        set_cycles(scene, **filt)
    return out


def render_frame(built, frame_dir: Path, fisheye_sizes: dict, topdown_size: int, render_cfg: dict,
                 cycles_seed: int, tmpdir: Path, frame_meta: dict, supersample: int = 1,
                 marking_share: float = 0.25, sensor_geometry: dict | None = None, rig=None) -> tuple[dict, dict]:
    """Render every pass of the posed frame into frame_dir; -> (timings (s), the camera effects drawn
    per camera). sensor_geometry: camera name -> (ray angles, principal point), sensor.camera_geometry;
    rig: the cameras the motion blur projects through (frame_meta["motion"] says how the scene moves)."""
    scene = bpy.context.scene
    frame_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    set_cycles(scene, seed=cycles_seed, samples=render_cfg["samples"], use_denoising=render_cfg["denoise"])
    clock: dict = {}
    effects = {}
    for k, (name, cam) in enumerate(built.cameras.items()):
        w, h = fisheye_sizes[name]
        effects[name] = sensor.draw(render_cfg["sensor"], np.random.default_rng([cycles_seed, 7, k]))
        theta, principal = (sensor_geometry or {}).get(name, (None, None))
        post = expose = tone = None
        if "hdr_compression" in effects[name]:
            tone = functools.partial(sensor.local_tone, compression=effects[name]["hdr_compression"])
        if effects[name]:
            def expose(passes, p=effects[name]):  # metered on the scene's light
                return sensor.meter(np.stack([passes[f"Combined.{c}"] for c in "RGB"], -1), p)

            def post(img, passes, p=effects[name], t=theta, c=principal, rc=rig[name] if rig is not None else None):
                flow = None
                if p.get("motion_blur") and rc is not None:
                    pos = np.stack([passes[f"Position.{a}"] for a in "XYZ"], -1)
                    flow = sensor.motion_flow(rc.camera, rc.cam_to_ego, pos, np.rint(passes["IndexOB.X"]).astype(np.int64),
                                              frame_meta["motion"])
                return sensor.apply(img, p, t, c, flow, exposed=True)
        render_fisheye(scene, cam, w, h, frame_dir, name, tmpdir, clock, bool(built.ego_body), post, expose, tone)
    t1 = time.perf_counter()
    with label_mode(scene):
        td = render_topdown(scene, built.topdown, topdown_size, built.occluders, frame_meta["world_to_ego"], tmpdir,
                            supersample, marking_share, built.ego_body)
    t2 = time.perf_counter()
    write_exr(FrameFiles(frame_dir).topdown, td)
    t3 = time.perf_counter()
    w = clock.get("write", 0.0)
    return {"fisheye_s": t1 - t0 - w, "topdown_s": t2 - t1, "write_s": t3 - t2 + w}, effects
