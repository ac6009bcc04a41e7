"""A rendering worker: `python -m blender_scripts.worker`, driven by dataset_tools.generate.

Reads render tasks on stdin; builds a task's scene once (kept while the next task is the same
scene) and renders its frames with persistent data. The protocol (task lines, message lines) is
common.worker_protocol; the driver writes the manifest.
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
import traceback
from pathlib import Path

from common.worker_protocol import RenderTask, message_line


def say(**msg) -> None:
    sys.stdout.write(message_line(**msg))
    sys.stdout.flush()


def frame_seed(scene_seed: int, frame: int) -> int:
    import numpy as np

    return int(np.random.default_rng([int(scene_seed), 4, int(frame)]).integers(0, 2**31 - 1))


def own_threads(n: int) -> None:
    """The worker's numerical work (camera geometry, the camera effects) on its own `n` cores, as
    Cycles renders on them: torch and OpenCV would otherwise start a thread per core of the
    machine, and beside the other workers' renders those threads wait on each other (two workers of
    one thread: writing with the camera effects 0.63 s a frame instead of 1.12; docs/scenes.md, "Speed")."""
    import cv2
    import torch

    torch.set_num_threads(max(1, n))
    cv2.setNumThreads(max(1, n))


def run_task(task: RenderTask, state: dict) -> None:
    """Render the task's frames. Its topdown and render sections are complete (the dataset
    config's schema filled in every default), so no default is restated here."""
    import bpy  # noqa: F401  (first import starts Blender)

    from dataset_tools.format.layout import frame_dir_name
    from dataset_tools.format.meta import FrameMeta, write_meta
    from dataset_tools.generation.dataset_config import for_weather
    from geometry.bev import BevGrid
    from geometry.rig import load_rig

    own_threads(task.threads)

    from .build_scene import build_scene, set_frame
    from .render_frame import configure_render, render_frame

    recipe, td, render = task.recipe, task.topdown, task.render
    key = json.dumps([recipe, task.rig, task.fisheye_size, td, render], sort_keys=True)
    t_build = 0.0
    if state.get("key") != key:
        t0 = time.perf_counter()
        rig = load_rig(task.rig)
        if task.fisheye_size:
            w, h = task.fisheye_size
            rig = rig.map_cameras(lambda c: c.resized(w, h))
        nominal = rig
        if recipe.get("rig_jitter"):
            from geometry.rig import jitter_rig

            from .build_scene import scene_rng

            rig = jitter_rig(rig, scene_rng(recipe["seed"], 6), recipe["rig_jitter"])
        grid = BevGrid(-td["bound"], td["bound"], -td["bound"], td["bound"], 2 * td["bound"] / td["size"])
        built = build_scene(recipe, rig, grid, td["height_m"], state["osl_dir"], render["camera_method"],
                            render["ego_body"])
        render = for_weather(render, built.weather)
        configure_render(bpy.context.scene, render["samples"], render["denoise"], task.threads,
                         render["max_bounces"], render["denoise_quality"])
        from dataset_tools.generation.sensor import camera_geometry

        geometry = {rc.name: camera_geometry(rc.camera) for rc in rig} if any(render["sensor"].values()) else {}
        state.update(key=key, built=built, render=render, rig=rig, nominal=nominal, grid=grid, sensor_geometry=geometry)
        t_build = time.perf_counter() - t0
    built, rig, render = state["built"], state["rig"], state["render"]
    sizes = {rc.name: (rc.camera.width, rc.camera.height) for rc in rig}
    for frame in task.frames:
        t0 = time.perf_counter()
        frame_dir = Path(task.out) / frame_dir_name(task.scene, frame)
        fm = set_frame(built, frame)
        seed = frame_seed(recipe["seed"], frame)
        timings, effects = render_frame(built, frame_dir, sizes, td["size"], render, seed, Path(state["tmp"]), fm,
                                        td["supersample"], td["marking_share"], state["sensor_geometry"], rig)
        w = built.weather
        meta = {
            "scene": task.scene, "frame": frame, "split": task.split, "family": recipe["family"],
            "time_s": fm["time_s"],
            "ego_pose": fm["ego_pose"],
            "actors": fm["actors"],
            "instances": {str(k): v for k, v in built.objects.items()},
            "weather": w,
            "sun": {"elevation_deg": w["sun_elevation_deg"], "azimuth_deg": w["sun_azimuth_deg"],
                    "strength": w["sun_strength"]},
            "seeds": {"scene": recipe["seed"], "cycles": seed},
            "rig": rig.to_dict(),  # this frame's calibration (jittered when the recipe asks)
            "rig_nominal": state["nominal"].to_dict(),
            "ego": built.ego_meta,
            "camera_method": render["camera_method"],
            "fit_errors_px": built.fit_errors,
            "topdown": {"grid": state["grid"].to_dict(), "height_m": td["height_m"],
                        "supersample": td["supersample"], "marking_share": td["marking_share"]},
            "render": render,
            "sensor": effects,
            "recipe": recipe,
        }
        # frame_s: this frame's posing, renders and writes (meta.json's own write, ~1 ms, excluded)
        meta["timings"] = dict(timings, build_s=t_build, frame_s=time.perf_counter() - t0)
        t_build = 0.0
        write_meta(frame_dir, FrameMeta(**meta))
        files = sorted(p.name for p in frame_dir.iterdir() if not p.name.startswith("."))
        say(event="frame", scene=task.scene, frame=frame, files=files, timings=meta["timings"])


def main() -> int:
    state = {"tmp": tempfile.mkdtemp(prefix="bev_worker_")}
    state["osl_dir"] = str(Path(state["tmp"]) / "osl")
    say(event="ready")
    for line in sys.stdin:
        if not line.strip():
            continue
        task = RenderTask.from_line(line)
        try:
            run_task(task, state)
        except Exception as exc:  # the driver prints it as one line and stops
            say(event="error", message=f"{type(exc).__name__}: {exc}", trace=traceback.format_exc())
            return 1
        say(event="task_done")
    import shutil

    shutil.rmtree(state["tmp"], ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
