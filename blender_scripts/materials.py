"""Materials: each one's `pass_index` is the fine class it paints (IndexMA = semantic pass).

Built per scene because the weather changes them (wet asphalt, lamps glowing at night).
Colours that vary per object (car paint, facades) come from the object's colour.
"""

from __future__ import annotations

import bpy

from dataset_tools.labels.classes import CLASS_IDS

# material name -> fine class
MATERIAL_CLASSES = {
    "asphalt": "road",
    "asphalt_lot": "parking",
    "paint_white": "lane_marking",
    "paint_yellow": "lane_marking",
    "paint_crosswalk": "crosswalk",
    "paint_stop": "stop_line",
    "pavement": "sidewalk",
    "kerb": "curb",
    "grass": "terrain",
    "bark": "vegetation",
    "leaves": "canopy",
    "wall": "building",
    "window": "building",
    "metal": "pole",
    "lamp": "pole",
    "bridge": "bridge",
    "concrete": "pillar",
    "barrier_concrete": "barrier",
    "car_paint": "vehicle",
    "car_glass": "vehicle",
    "cargo": "vehicle",
    "tyre": "vehicle",
    "headlight": "vehicle",
    "taillight": "vehicle",
}


def _principled(name, color, rough=0.5, metallic=0.0, spec=0.5):
    m = bpy.data.materials.new(name)
    m.use_nodes = True
    b = m.node_tree.nodes["Principled BSDF"]
    b.inputs["Base Color"].default_value = (*color, 1.0)
    b.inputs["Roughness"].default_value = rough
    b.inputs["Metallic"].default_value = metallic
    b.inputs["Specular IOR Level"].default_value = spec
    return m, b


def _noise_mix(m, bsdf, c0, c1, scale, detail=4.0, target="Base Color"):
    """Base colour varied by a noise texture between c0 and c1 (wear, dirt)."""
    nt = m.node_tree
    tex = nt.nodes.new("ShaderNodeTexNoise")
    tex.inputs["Scale"].default_value = scale
    tex.inputs["Detail"].default_value = detail
    ramp = nt.nodes.new("ShaderNodeValToRGB")
    ramp.color_ramp.elements[0].color = (*c0, 1)
    ramp.color_ramp.elements[1].color = (*c1, 1)
    ramp.color_ramp.elements[0].position = 0.35
    ramp.color_ramp.elements[1].position = 0.65
    nt.links.new(tex.outputs["Fac"], ramp.inputs["Fac"])
    nt.links.new(ramp.outputs["Color"], bsdf.inputs[target])
    return tex


def _object_color(m, bsdf, mix_with=None):
    nt = m.node_tree
    info = nt.nodes.new("ShaderNodeObjectInfo")
    nt.links.new(info.outputs["Color"], bsdf.inputs["Base Color"])


def _emission(bsdf, color, strength):
    bsdf.inputs["Emission Color"].default_value = (*color, 1)
    bsdf.inputs["Emission Strength"].default_value = strength


def build_materials(weather: dict) -> dict[str, bpy.types.Material]:
    wet = float(weather.get("wetness", 0.0))
    night = bool(weather.get("lights_on", False))
    mats = {}

    def make(name, *a, **k):
        m, b = _principled(name, *a, **k)
        mats[name] = m
        return m, b

    # asphalt: darker and glossy when wet, puddles where a coarse noise dips
    for name, base in (("asphalt", 0.06), ("asphalt_lot", 0.08)):
        m, b = make(name, (base,) * 3, rough=0.85 - 0.6 * wet)
        dark = base * (1 - 0.5 * wet)
        _noise_mix(m, b, (dark * 0.7,) * 3, (dark * 1.4,) * 3, 3.0)
        if wet > 0:
            nt = m.node_tree
            tex = nt.nodes.new("ShaderNodeTexNoise")
            tex.inputs["Scale"].default_value = 0.15
            ramp = nt.nodes.new("ShaderNodeValToRGB")
            ramp.color_ramp.elements[0].position = 0.55 - 0.1 * wet
            ramp.color_ramp.elements[0].color = (0.12, 0.12, 0.12, 1)
            ramp.color_ramp.elements[1].position = 0.6 - 0.1 * wet
            ramp.color_ramp.elements[1].color = (0.45 - 0.3 * wet,) * 3 + (1,)
            nt.links.new(tex.outputs["Fac"], ramp.inputs["Fac"])
            nt.links.new(ramp.outputs["Color"], b.inputs["Roughness"])
    make("paint_white", (0.75, 0.75, 0.72), rough=0.6 - 0.4 * wet)
    make("paint_yellow", (0.75, 0.55, 0.08), rough=0.6 - 0.4 * wet)
    make("paint_crosswalk", (0.78, 0.78, 0.75), rough=0.6 - 0.4 * wet)
    make("paint_stop", (0.78, 0.78, 0.75), rough=0.6 - 0.4 * wet)
    m, b = make("pavement", (0.35, 0.34, 0.32), rough=0.9 - 0.4 * wet)
    _noise_mix(m, b, (0.28, 0.27, 0.26), (0.4, 0.39, 0.37), 8.0)
    make("kerb", (0.5, 0.5, 0.48), rough=0.8)
    m, b = make("grass", (0.08, 0.2, 0.04), rough=0.95)
    _noise_mix(m, b, (0.05, 0.14, 0.03), (0.14, 0.24, 0.06), 1.5)
    make("bark", (0.12, 0.08, 0.05), rough=0.9)
    m, b = make("leaves", (0.05, 0.18, 0.03), rough=0.8)
    _noise_mix(m, b, (0.03, 0.12, 0.02), (0.1, 0.25, 0.05), 2.0)
    m, b = make("wall", (0.5, 0.45, 0.4), rough=0.85)
    _object_color(m, b)
    m, b = make("window", (0.05, 0.07, 0.09), rough=0.1, spec=1.0)
    if night:
        _emission(b, (1.0, 0.8, 0.5), 0.3)
    make("metal", (0.4, 0.4, 0.42), rough=0.4, metallic=1.0)
    m, b = make("lamp", (0.9, 0.9, 0.85), rough=0.3)
    if night:
        _emission(b, (1.0, 0.85, 0.6), 30.0)
    make("bridge", (0.45, 0.44, 0.42), rough=0.85)
    make("concrete", (0.5, 0.49, 0.47), rough=0.85)
    make("barrier_concrete", (0.5, 0.49, 0.47), rough=0.85)  # looks like the pillars, labelled barrier
    m, b = make("car_paint", (0.5, 0.5, 0.5), rough=0.25, metallic=0.4)
    _object_color(m, b)
    make("car_glass", (0.02, 0.025, 0.03), rough=0.05, spec=1.0)
    make("cargo", (0.75, 0.75, 0.72), rough=0.6)
    make("tyre", (0.02, 0.02, 0.02), rough=0.9)
    m, b = make("headlight", (0.9, 0.9, 0.9), rough=0.1)
    if night:
        _emission(b, (1.0, 0.95, 0.85), 40.0)
    m, b = make("taillight", (0.5, 0.02, 0.02), rough=0.2)
    if night:
        _emission(b, (1.0, 0.05, 0.02), 10.0)
    for name, m in mats.items():
        m.pass_index = CLASS_IDS[MATERIAL_CLASSES[name]]
        # glowing windows and lamps are seen, not sampled as lights: the street lights and
        # headlights are real lamps, and thousands of emissive triangles would slow every sample
        m.cycles.emission_sampling = "NONE"
    return mats
