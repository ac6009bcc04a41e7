"""Street furniture (pure numpy: the layout Blender builds): traffic lights at every stop line
facing the traffic that stops there, guard rails along highways, hedges, bushes, benches and bins;
none of it where vehicles drive, and each painted with its own class's materials."""

from __future__ import annotations

import math

import numpy as np
import pytest

from blender_scripts.build_scene import scene_rng
from blender_scripts.layouts import build_layout
from blender_scripts.materials import MATERIAL_CLASSES
from dataset_tools.generation.recipe import FAMILIES, junction_crossings, validate_recipe
from dataset_tools.generation.sampler import SAMPLE, sample_recipes

FURNITURE = ("traffic_light", "guard_rail", "hedge", "bush", "bench", "bin")
CLASSES = {"traffic_light": {"pole"}, "guard_rail": {"barrier"}, "hedge": {"vegetation"}, "bush": {"vegetation"},
           "bench": {"street_furniture"}, "bin": {"street_furniture"}}


def _kind(name: str) -> str | None:
    return next((k for k in FURNITURE if name.startswith(k) and name[len(k):][:1].isdigit()), None)


def _world_xy(obj) -> np.ndarray:
    v = obj.mesh.vertices
    c, s = math.cos(obj.yaw), math.sin(obj.yaw)
    return np.column_stack([obj.location[0] + c * v[:, 0] - s * v[:, 1], obj.location[1] + s * v[:, 0] + c * v[:, 1]])


def test_a_traffic_light_at_each_stop_line_facing_the_traffic():
    r = validate_recipe({"family": "intersection", "seed": 5, "roadside": {"sidewalk_width": 3.0}}, "x")
    lay = build_layout(r, scene_rng(5, 1))
    lights = [o for o in lay.objects if _kind(o.name) == "traffic_light"]
    assert len(lights) == 2 * len(junction_crossings(r))
    for o in lights:
        lens_faces = [f for f, n in zip(o.mesh.faces, o.mesh.mats) if n.startswith("signal_") and n != "signal_housing"]
        lens = o.mesh.vertices[sorted({i for f in lens_faces for i in f})]
        assert lens[:, 1].max() < -0.2, "the lenses are on the housing's front (local -y)"
        # the lenses face local -y; turned by the yaw they face the traffic coming toward the light
        facing = np.array([math.sin(o.yaw), -math.cos(o.yaw)])
        assert abs(abs(facing[0]) - 1) < 1e-9, "a light faces along the main road"
        assert np.sign(facing[0]) == np.sign(o.location[1]), "faces the incoming lane on its side (right-hand traffic)"
        assert lens[:, 2].max() > 3.0
        lit = [n for n in o.mesh.mats if n.startswith("signal_") and n not in ("signal_off", "signal_housing")]
        assert len(set(lit)) == 1, "exactly one lens lit"


@pytest.mark.parametrize("family", FAMILIES)
def test_furniture_stays_off_the_lanes(family):
    spec = SAMPLE.validate({"count": 6, "seed": 21, "families": [family]}, "test")
    seen = set()
    for r in sample_recipes(spec):
        lay = build_layout(r, scene_rng(r["seed"], 1))
        lanes = [(np.asarray(ln.path.at(np.arange(0.0, ln.path.length, 0.5))[0]), ln.width) for ln in lay.lanes]
        for o in lay.objects:
            kind = _kind(o.name)
            if kind is None:
                continue
            seen.add(kind)
            assert {MATERIAL_CLASSES[n] for n in o.mesh.mats} <= CLASSES[kind] | ({"pole"} if kind == "traffic_light" else set())
            xy = _world_xy(o)
            for pts, width in lanes:
                near = pts[np.abs(pts[:, 0] - xy[:, 0].mean()) + np.abs(pts[:, 1] - xy[:, 1].mean()) < 30]
                if len(near):
                    d = np.linalg.norm(xy[:, None, :] - near[None], axis=-1).min()
                    assert d > width / 2 + 0.2, (r["name"], o.name, d)
    if family == "highway":
        assert "guard_rail" in seen
    if family in ("intersection", "urban_block", "t_junction"):
        assert {"traffic_light", "bench", "bin"} <= seen, seen


def test_awnings_and_balconies_stay_in_front_of_the_building_by_less_than_its_setback():
    """Buildings stand 1.5 m back from the roadside: what hangs off their front stays within that."""
    from blender_scripts.assets import building_mesh

    kinds = set()
    for seed in range(40):
        rng = np.random.default_rng(seed)
        depth, height = 12.0, float(rng.uniform(6, 30))
        m = building_mesh(rng, float(rng.uniform(10, 30)), depth, height)
        kinds |= set(m.mats)
        assert m.vertices[:, 1].min() >= -(depth / 2 + 1.4)
        assert {MATERIAL_CLASSES[n] for n in m.mats} == {"building"}
    assert {"awning", "railing"} <= kinds


def test_a_lots_lamp_posts_stand_clear_of_every_bay_and_light_its_rows():
    r = validate_recipe({"family": "parking_lot", "seed": 3, "layout": {"bay_rows": 3, "bays_per_row": 24,
                                                                        "occupancy": 0.95}}, "x")
    lay = build_layout(r, scene_rng(3, 1))
    poles = [o for o in lay.objects if o.name.startswith("lot_light")]
    assert len(poles) >= 20 and len(lay.lamps) >= len(poles)
    for o in poles:
        px, py = o.location[:2]
        for cx, cy, yaw, length, width in lay.parked:  # the largest car a bay takes, turned with it
            c, s = math.cos(yaw), math.sin(yaw)
            lx, ly = c * (px - cx) + s * (py - cy), -s * (px - cx) + c * (py - cy)
            assert max(abs(lx) - length / 2, abs(ly) - width / 2) > 0.09 + 0.01, (o.name, px, py)
        assert abs(py + 1.5) > 3.5 + 0.09, "a pole in the aisle the ego drives"
    # every parked car has a lamp within 15 m
    bulbs = np.array([b[:2] for b in lay.lamps])
    far = [p for p in lay.parked if np.linalg.norm(bulbs - p[:2], axis=1).min() > 15]
    assert not far


def test_a_trees_limbs_are_part_of_its_crown_hidden_with_it_from_the_label_pass():
    """What stands in the top-down ground pass must block a camera as a 2.5D height would: a trunk
    does, limbs in the crown do not (the audit's line-of-sight sweep took them for walls)."""
    from blender_scripts.assets import TREE_SHAPES, tree_meshes
    from dataset_tools.labels.classes import CLASS_IDS, OVERHEAD_OCCLUDERS

    for k, shape in enumerate(TREE_SHAPES):
        trunk, canopy = tree_meshes(np.random.default_rng(k), overhang=k % 2 == 0 and shape in ("round", "clustered"),
                                    shape=shape)
        assert set(trunk.mats) == {"bark"}
        assert all(CLASS_IDS[MATERIAL_CLASSES[n]] in OVERHEAD_OCCLUDERS for n in canopy.mats)
        if shape != "conifer":
            assert "branch" in canopy.mats
