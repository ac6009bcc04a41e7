"""Render settings in Cycles' persistent session (real bpy, a real night scene at tiny size).

Pins two facts the data set's determinism rests on: settings changed through `set_cycles` reach
the next render (a bare assignment to scene.cycles does not, in a persistent session), and the
label renders' `label_mode` (no lights, no sky, no bounces, one sample, a plain shader on every
surface) changes no label pass and leaves nothing behind: the rgb rendered after it is
bit-identical to the rgb rendered before it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from dataset_tools.generation.recipe import load_recipe
from geometry.bev import BevGrid
from geometry.rig import load_rig

bpy = pytest.importorskip("bpy", reason="bpy is part of the pinned environment (make setup)")

from blender_scripts.build_scene import build_scene, set_frame  # noqa: E402
from blender_scripts.render_frame import (  # noqa: E402
    LABEL_SURFACE,
    _render_to_exr,
    configure_render,
    label_mode,
    render_topdown,
    set_cycles,
)

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def night(tmp_path_factory):
    """The urban block at night (street lamps, headlights, overpass, canopies), 64x40 fisheye."""
    tmp = tmp_path_factory.mktemp("render_frame")
    recipe = load_recipe(ROOT / "scenes" / "urban_block.yaml")
    assert recipe["weather"]["preset"] == "night"
    rig = load_rig(ROOT / "configs" / "rigs" / "default.yaml").map_cameras(lambda c: c.resized(64, 40))
    grid = BevGrid(-25.0, 25.0, -25.0, 25.0, 50.0 / 48)
    built = build_scene(recipe, rig, grid, 60.0, str(tmp / "osl"))
    scene = bpy.context.scene
    configure_render(scene, samples=2, denoise=False, threads=2, max_bounces=3)
    frame = set_frame(built, 1)
    assert built.occluders and any(o.type == "LIGHT" for o in scene.objects)
    return built, scene, frame, tmp


def _rgb(built, scene, tmp):
    p = _render_to_exr(scene, built.cameras["front"], 64, 40, tmp, "front")
    return np.stack([p[f"Combined.{c}"] for c in "RGB"], -1)


def test_set_cycles_reaches_the_next_render(night):
    built, scene, _, tmp = night
    seed = scene.cycles.seed
    a = _rgb(built, scene, tmp)
    set_cycles(scene, seed=seed + 1)
    b = _rgb(built, scene, tmp)
    set_cycles(scene, seed=seed)
    c = _rgb(built, scene, tmp)
    assert not np.array_equal(a, b), "a new seed must change the noise"
    assert np.array_equal(a, c)


def test_label_mode_changes_no_label_and_leaves_nothing_behind(night):
    built, scene, frame, tmp = night
    energies = {o.name: o.data.energy for o in scene.objects if o.type == "LIGHT"}
    settings = {k: getattr(scene.cycles, k) for k in ("samples", "use_denoising", "max_bounces")}
    before = _rgb(built, scene, tmp)

    full = render_topdown(scene, built.topdown, 48, built.occluders, frame["world_to_ego"], tmp)
    with label_mode(scene):
        assert scene.cycles.max_bounces == 0 and scene.cycles.samples == 1
        assert all(o.data.energy == 0 for o in scene.objects if o.type == "LIGHT")
        assert not scene.view_layers[0].use_sky
        assert all(_surface_source(m) == LABEL_SURFACE for m in _shaded(scene)), "a plain shader on every surface"
        fast = render_topdown(scene, built.topdown, 48, built.occluders, frame["world_to_ego"], tmp)
    assert full.keys() == fast.keys()
    for k in full:
        assert np.array_equal(full[k], fast[k]), k
    under = full["all.instance"] != full["ground.instance"]
    assert under.any(), "the overpass or a canopy must be in view from above"

    assert scene.view_layers[0].use_sky
    assert {o.name: o.data.energy for o in scene.objects if o.type == "LIGHT"} == energies
    assert {k: getattr(scene.cycles, k) for k in settings} == settings
    assert all(o.visible_camera for o in built.occluders)
    assert not any(_surface_source(m) == LABEL_SURFACE for m in _shaded(scene))
    assert np.array_equal(_rgb(built, scene, tmp), before)


def _shaded(scene) -> list:
    """The node materials on the scene's objects."""
    mats = {s.material for o in scene.objects for s in getattr(o, "material_slots", ()) if s.material}
    assert mats, "the scene has materials"
    return [m for m in mats if m.use_nodes]


def _surface_source(m) -> str | None:
    """The name of the node the material's output takes its surface from."""
    out = next(n for n in m.node_tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial")
    links = out.inputs["Surface"].links
    return links[0].from_node.name if links else None


def test_the_hdr_tone_mapping_writes_through_the_view_transform_as_a_render_does(night):
    """The camera's tone mapping hands Blender its own linear light (`_light_image`): with nothing
    changed it writes the same PNG as the render itself (Blender's dither aside, 1 level); with the
    HDR compression, far less of a night frame taken 16x too bright clips to white."""
    from dataset_tools.format.png import read_png
    from dataset_tools.generation import sensor

    built, scene, _, tmp = night
    shots = {}
    for k, tone in {"plain": None, "same": lambda lin: lin, "hdr": lambda lin: sensor.local_tone(lin, 0.3)}.items():
        _render_to_exr(scene, built.cameras["front"], 64, 40, tmp, "front", tmp / f"{k}.png",
                       expose=lambda passes: 16.0 / float(sensor.log_average(
                           np.stack([passes[f"Combined.{c}"] for c in "RGB"], -1))), tone=tone)
        shots[k] = read_png(tmp / f"{k}.png", np.uint8, 3).astype(int)
    assert np.abs(shots["same"] - shots["plain"]).max() <= 1
    white = {k: (v.min(-1) >= 250).mean() for k, v in shots.items()}
    assert white["plain"] > 0.2 and white["hdr"] < 0.5 * white["plain"]
