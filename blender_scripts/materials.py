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
    "sign": "pole",
    "bollard": "pole",
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
    "trim": "vehicle",
    "rim": "vehicle",
}
# the ego car's body: the traffic's materials again, painting the fine class `ego`
EGO_MATERIALS = {f"ego_{n}": n for n in ("car_paint", "car_glass", "tyre", "rim", "trim", "headlight", "taillight")}
MATERIAL_CLASSES.update({n: "ego" for n in EGO_MATERIALS})


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


def _object_coords(nt):
    """Object-space coordinates (metres): procedural detail the same size on every mesh (the
    default, generated coordinates, stretch over each object's bounding box)."""
    return nt.nodes.new("ShaderNodeTexCoord").outputs["Object"]


def _asphalt_detail(m, bsdf, dark: float):
    """Patches of repaired, darker asphalt over the base colour already linked to the BSDF (cracks,
    as Voronoi cell edges, cost 10 % of the render time and barely showed at 480 x 302: left out)."""
    nt = m.node_tree
    co = _object_coords(nt)
    base = bsdf.inputs["Base Color"].links[0].from_socket
    patch = nt.nodes.new("ShaderNodeTexNoise")
    patch.inputs["Scale"].default_value = 0.08
    patch.inputs["Detail"].default_value = 0.0
    nt.links.new(co, patch.inputs["Vector"])
    step = nt.nodes.new("ShaderNodeValToRGB")
    step.color_ramp.interpolation = "CONSTANT"
    step.color_ramp.elements[0].color = (0, 0, 0, 1)
    step.color_ramp.elements[1].position = 0.66
    step.color_ramp.elements[1].color = (1, 1, 1, 1)
    nt.links.new(patch.outputs["Fac"], step.inputs["Fac"])
    mix = nt.nodes.new("ShaderNodeMix")
    mix.data_type = "RGBA"
    mix.inputs["B"].default_value = (dark * 0.6, dark * 0.6, dark * 0.62, 1)
    nt.links.new(step.outputs["Color"], mix.inputs["Factor"])
    nt.links.new(base, mix.inputs["A"])
    nt.links.new(mix.outputs["Result"], bsdf.inputs["Base Color"])


def _worn(m, bsdf, paint, worn):
    """Road paint worn through to the asphalt in places (object-space noise, 0.5 m blotches)."""
    nt = m.node_tree
    tex = nt.nodes.new("ShaderNodeTexNoise")
    tex.inputs["Scale"].default_value = 1.6
    tex.inputs["Detail"].default_value = 3.0
    nt.links.new(_object_coords(nt), tex.inputs["Vector"])
    ramp = nt.nodes.new("ShaderNodeValToRGB")
    ramp.color_ramp.elements[0].position = 0.3
    ramp.color_ramp.elements[0].color = (*worn, 1)
    ramp.color_ramp.elements[1].position = 0.5
    ramp.color_ramp.elements[1].color = (*paint, 1)
    nt.links.new(tex.outputs["Fac"], ramp.inputs["Fac"])
    nt.links.new(ramp.outputs["Color"], bsdf.inputs["Base Color"])


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
        _asphalt_detail(m, b, dark)
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
    for name, paint in (("paint_white", (0.75, 0.75, 0.72)), ("paint_yellow", (0.75, 0.55, 0.08)),
                        ("paint_crosswalk", (0.78, 0.78, 0.75)), ("paint_stop", (0.78, 0.78, 0.75))):
        m, b = make(name, paint, rough=0.6 - 0.4 * wet)
        _worn(m, b, paint, tuple(0.35 * c + 0.04 for c in paint))
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
    m, b = make("sign", (0.8, 0.8, 0.8), rough=0.35)
    _object_color(m, b)
    make("bollard", (0.12, 0.12, 0.13), rough=0.6)
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
    make("rim", (0.55, 0.55, 0.57), rough=0.3, metallic=1.0)
    make("trim", (0.03, 0.03, 0.035), rough=0.7)
    m, b = make("headlight", (0.9, 0.9, 0.9), rough=0.1)
    if night:
        _emission(b, (1.0, 0.95, 0.85), 40.0)
    m, b = make("taillight", (0.5, 0.02, 0.02), rough=0.2)
    if night:
        _emission(b, (1.0, 0.05, 0.02), 10.0)
    for name, base in EGO_MATERIALS.items():
        mats[name] = mats[base].copy()
        mats[name].name = name
    for name, m in mats.items():
        m.pass_index = CLASS_IDS[MATERIAL_CLASSES[name]]
        # glowing windows and lamps are seen, not sampled as lights: the street lights and
        # headlights are real lamps, and thousands of emissive triangles would slow every sample
        m.cycles.emission_sampling = "NONE"
    return mats
