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
    "branch": "canopy",
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
    "reverse_lamp": "vehicle",
    "trim": "vehicle",
    "rim": "vehicle",
    "grille": "vehicle",
    "plate": "vehicle",
    "interior": "vehicle",
    "skin": "pedestrian",
    "clothes": "pedestrian",
    "trousers": "pedestrian",
    "hair": "pedestrian",
    "signal_housing": "pole",
    "signal_off": "pole",
    "signal_red": "pole",
    "signal_amber": "pole",
    "signal_green": "pole",
    "guardrail": "barrier",
    "hedge": "vegetation",
    "bench_wood": "street_furniture",
    "furniture_metal": "street_furniture",
    "bin": "street_furniture",
    "awning": "building",
    "railing": "building",
    "bike_frame": "bicycle",
    "bike_tyre": "bicycle",
    "bike_metal": "bicycle",
    "moto_body": "motorcycle",
    "moto_seat": "motorcycle",
    "moto_tyre": "motorcycle",
    "moto_metal": "motorcycle",
    "moto_lamp": "motorcycle",
}
LAMP_LENS = (0.6, 0.61, 0.63)  # headlight and reversing-lamp units: chrome and grey plastic under a clear lens
# the ego car's body: the traffic's materials again, painting the fine class `ego`
EGO_MATERIALS = {f"ego_{n}": n for n in ("car_paint", "car_glass", "tyre", "rim", "trim", "headlight", "taillight", "grille",
                                                 "plate", "interior", "reverse_lamp")}
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
    """Base colour varied by a noise texture (generated coordinates) between c0 and c1 (wear, dirt)."""
    nt = m.node_tree
    tex = _noise(nt, scale, detail, coords=False)
    nt.links.new(_ramp(nt, tex.outputs["Fac"], [(0.35, c0), (0.65, c1)]), bsdf.inputs[target])
    return tex


def _object_coords(nt):
    """Object-space coordinates (metres): procedural detail the same size on every mesh (the
    default, generated coordinates, stretch over each object's bounding box)."""
    return nt.nodes.new("ShaderNodeTexCoord").outputs["Object"]


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


def _noise(nt, scale, detail=2.0, coords=True):
    tex = nt.nodes.new("ShaderNodeTexNoise")
    tex.inputs["Scale"].default_value = scale
    tex.inputs["Detail"].default_value = detail
    if coords:
        nt.links.new(_object_coords(nt), tex.inputs["Vector"])
    return tex


def _ramp(nt, fac, stops, interpolation="LINEAR"):
    """A colour ramp on `fac` through [(position, rgb), ...] (two or more stops)."""
    r = nt.nodes.new("ShaderNodeValToRGB")
    r.color_ramp.interpolation = interpolation
    els = r.color_ramp.elements
    while len(els) < len(stops):
        els.new(0.5)
    for e, (pos, rgb) in zip(els, stops):
        e.position = pos
        e.color = (*rgb, 1) if len(rgb) == 3 else (rgb[0],) * 3 + (1,)
    nt.links.new(fac, r.inputs["Fac"])
    return r.outputs["Color"]


def _mix(nt, fac, a, b, blend="MIX"):
    node = nt.nodes.new("ShaderNodeMix")
    node.data_type = "RGBA"
    node.blend_type = blend
    if isinstance(fac, float):
        node.inputs["Factor"].default_value = fac
    else:
        nt.links.new(fac, node.inputs["Factor"])
    for sock, v in ((node.inputs["A"], a), (node.inputs["B"], b)):
        if isinstance(v, tuple):
            sock.default_value = (*v, 1)
        else:
            nt.links.new(v, sock)
    return node.outputs["Result"]


def _wall_coords(nt):
    """(x + y, z, 0) of object space: a 2D texture upright on walls facing x or y."""
    sep = nt.nodes.new("ShaderNodeSeparateXYZ")
    nt.links.new(_object_coords(nt), sep.inputs["Vector"])
    add = nt.nodes.new("ShaderNodeMath")
    add.operation = "ADD"
    nt.links.new(sep.outputs["X"], add.inputs[0])
    nt.links.new(sep.outputs["Y"], add.inputs[1])
    comb = nt.nodes.new("ShaderNodeCombineXYZ")
    nt.links.new(add.outputs[0], comb.inputs["X"])
    nt.links.new(sep.outputs["Z"], comb.inputs["Y"])
    return comb.outputs["Vector"]


def _near(nt, near: float, far: float):
    """1 up to `near` metres from the camera, falling to 0 at `far`: fine texture detail (bricks,
    pavers) fades into its mean colour where pixels can no longer resolve it (no moire)."""
    cam = nt.nodes.new("ShaderNodeCameraData")
    r = nt.nodes.new("ShaderNodeMapRange")
    r.inputs["From Min"].default_value = near
    r.inputs["From Max"].default_value = far
    r.inputs["To Min"].default_value = 1.0
    r.inputs["To Max"].default_value = 0.0
    nt.links.new(cam.outputs["View Distance"], r.inputs["Value"])
    return r.outputs["Result"]


def _bump(m, bsdf, height, strength, distance=0.02):
    nt = m.node_tree
    bump = nt.nodes.new("ShaderNodeBump")
    bump.inputs["Strength"].default_value = strength
    bump.inputs["Distance"].default_value = distance
    nt.links.new(height, bump.inputs["Height"])
    nt.links.new(bump.outputs["Normal"], bsdf.inputs["Normal"])


def _asphalt(m, b, base, wet):
    """Aggregate speckle, large-scale tone, repaired patches, oil stains, a fine bump; puddles."""
    nt = m.node_tree
    tone = _ramp(nt, _noise(nt, 0.35, 3.0).outputs["Fac"], [(0.3, (base * 0.8,) * 3), (0.7, (base * 1.2,) * 3)])
    grit = _ramp(nt, _noise(nt, 45.0, 1.0).outputs["Fac"], [(0.35, (0.75,) * 3), (0.65, (1.25,) * 3)])
    col = _mix(nt, 1.0, tone, grit, "MULTIPLY")
    patch = _ramp(nt, _noise(nt, 0.08, 0.0).outputs["Fac"], [(0.0, (0.0,)), (0.66, (1.0,))], "CONSTANT")
    col = _mix(nt, patch, col, (base * 0.6, base * 0.6, base * 0.62))
    stain = _ramp(nt, _noise(nt, 0.9, 2.0).outputs["Fac"], [(0.0, (0.0,)), (0.72, (0.0,)), (0.78, (0.7,))])
    col = _mix(nt, stain, col, (base * 0.35, base * 0.33, base * 0.32))
    nt.links.new(col, b.inputs["Base Color"])
    _bump(m, b, _noise(nt, 120.0, 1.0).outputs["Fac"], 0.35)
    if wet > 0:
        puddle = _noise(nt, 0.2, 2.0).outputs["Fac"]
        rough = _ramp(nt, puddle, [(0.0, (0.55 - 0.25 * wet,)), (0.6 - 0.12 * wet, (0.55 - 0.25 * wet,)),
                                   (0.63 - 0.12 * wet, (0.03,))])
        nt.links.new(rough, b.inputs["Roughness"])
        b.inputs["Specular IOR Level"].default_value = 0.5


def _pavers(m, b, c0, c1, size=(0.2, 0.1), mortar=0.006):
    """Blocks laid in a brick bond (object space), each a little different, with dark joints."""
    nt = m.node_tree
    brick = nt.nodes.new("ShaderNodeTexBrick")
    brick.inputs["Scale"].default_value = 1.0
    brick.inputs["Brick Width"].default_value = size[0]
    brick.inputs["Row Height"].default_value = size[1]
    brick.inputs["Mortar Size"].default_value = mortar
    brick.inputs["Color1"].default_value = (*c0, 1)
    brick.inputs["Color2"].default_value = tuple(0.8 * v for v in c0) + (1,)
    brick.inputs["Mortar"].default_value = (*c1, 1)
    nt.links.new(_object_coords(nt), brick.inputs["Vector"])
    dirt = _ramp(nt, _noise(nt, 1.5, 3.0).outputs["Fac"], [(0.3, (0.8,)), (0.7, (1.1,))])
    laid = _mix(nt, _near(nt, 3.0 * size[0] / 0.2, 8.0 * size[0] / 0.2), tuple(0.9 * a + 0.1 * c for a, c in zip(c0, c1)),
                brick.outputs["Color"])
    nt.links.new(_mix(nt, 1.0, laid, dirt, "MULTIPLY"), b.inputs["Base Color"])
    _bump(m, b, brick.outputs["Fac"], 0.4, distance=0.01)


def _grass(m, b):
    nt = m.node_tree
    large = _ramp(nt, _noise(nt, 0.6, 3.0).outputs["Fac"], [(0.3, (0.05, 0.13, 0.03)), (0.55, (0.1, 0.22, 0.05)),
                                                              (0.75, (0.2, 0.22, 0.08))])
    blades = _ramp(nt, _noise(nt, 60.0, 1.0).outputs["Fac"], [(0.3, (0.7,)), (0.7, (1.3,))])
    nt.links.new(_mix(nt, 1.0, large, blades, "MULTIPLY"), b.inputs["Base Color"])
    _bump(m, b, _noise(nt, 40.0, 2.0).outputs["Fac"], 0.6, distance=0.05)


def _facade(m, b):
    """The object's colour as plaster with stains, or (on about 40 % of buildings, by the object's
    random number) as brick courses."""
    nt = m.node_tree
    info = nt.nodes.new("ShaderNodeObjectInfo")
    brick = nt.nodes.new("ShaderNodeTexBrick")
    brick.inputs["Scale"].default_value = 1.0
    brick.inputs["Brick Width"].default_value = 0.25
    brick.inputs["Row Height"].default_value = 0.075
    brick.inputs["Mortar Size"].default_value = 0.01
    brick.inputs["Color1"].default_value = (1.0, 1.0, 1.0, 1)
    brick.inputs["Color2"].default_value = (0.8, 0.78, 0.75, 1)
    brick.inputs["Mortar"].default_value = (1.6, 1.6, 1.6, 1)
    nt.links.new(_wall_coords(nt), brick.inputs["Vector"])
    is_brick = nt.nodes.new("ShaderNodeMath")
    is_brick.operation = "LESS_THAN"
    is_brick.inputs[1].default_value = 0.4
    nt.links.new(info.outputs["Random"], is_brick.inputs[0])
    far = nt.nodes.new("ShaderNodeMath")  # brick courses fade with distance (see _near)
    far.operation = "MULTIPLY"
    nt.links.new(is_brick.outputs[0], far.inputs[0])
    nt.links.new(_near(nt, 4.0, 10.0), far.inputs[1])
    pattern = _mix(nt, far.outputs[0], (0.95, 0.93, 0.9), brick.outputs["Color"])
    stains = _ramp(nt, _noise(nt, 0.5, 4.0).outputs["Fac"], [(0.3, (0.75,)), (0.7, (1.05,))])
    col = _mix(nt, 1.0, info.outputs["Color"], pattern, "MULTIPLY")
    nt.links.new(_mix(nt, 1.0, col, stains, "MULTIPLY"), b.inputs["Base Color"])


def _windows(m, b, night: bool = False):
    """Glass dark with a dim interior, some panes with a curtain or a lit room behind; at night
    those rooms glow (warm, each a little brighter or dimmer) and the rest stay dark."""
    nt = m.node_tree
    pane = _noise(nt, 0.9, 0.0).outputs["Fac"]
    nt.links.new(_ramp(nt, pane, [(0.0, (0.02, 0.025, 0.03)), (0.6, (0.03, 0.035, 0.04)), (0.62, (0.25, 0.22, 0.18))],
                       "CONSTANT"), b.inputs["Base Color"])
    if night:
        _emission(b, (1.0, 0.78, 0.5), 1.0)
        lit = nt.nodes.new("ShaderNodeMath")
        lit.operation = "MULTIPLY"
        lit.inputs[1].default_value = 1.5
        nt.links.new(_ramp(nt, pane, [(0.0, (0.0,)), (0.615, (0.0,)), (0.62, (0.35,)), (0.8, (1.0,))]), lit.inputs[0])
        nt.links.new(lit.outputs[0], b.inputs["Emission Strength"])


def _car_paint(m, b):
    """Car paint: the object's colour under a clear coat; metallic where the object colour's alpha
    says so (traffic.COLORS), with a faint flake noise in the base roughness."""
    nt = m.node_tree
    info = nt.nodes.new("ShaderNodeObjectInfo")
    nt.links.new(info.outputs["Color"], b.inputs["Base Color"])
    scale = nt.nodes.new("ShaderNodeMath")
    scale.operation = "MULTIPLY"
    scale.inputs[1].default_value = 0.7
    nt.links.new(info.outputs["Alpha"], scale.inputs[0])
    nt.links.new(scale.outputs[0], b.inputs["Metallic"])
    flakes = nt.nodes.new("ShaderNodeTexNoise")
    flakes.inputs["Scale"].default_value = 400.0
    flakes.inputs["Detail"].default_value = 0.0
    nt.links.new(_object_coords(nt), flakes.inputs["Vector"])
    rough = nt.nodes.new("ShaderNodeMapRange")
    rough.inputs["To Min"].default_value = 0.25
    rough.inputs["To Max"].default_value = 0.45
    nt.links.new(flakes.outputs["Fac"], rough.inputs["Value"])
    nt.links.new(rough.outputs["Result"], b.inputs["Roughness"])
    b.inputs["Coat Weight"].default_value = 1.0
    b.inputs["Coat Roughness"].default_value = 0.03


def _glass(m):
    """Window glass: thin (no refraction), tinted, see-through to the dark interior, reflecting more
    at grazing angles (a little more than glass does at any angle: our scenes lack the bright, busy
    surroundings a real window mirrors, and a window that shows only the dark interior reads as a
    black screen). The label passes still stop at it (the view layer's alpha threshold is 0)."""
    nt = m.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    clear = nt.nodes.new("ShaderNodeBsdfTransparent")
    clear.inputs["Color"].default_value = (0.25, 0.28, 0.3, 1)
    gloss = nt.nodes.new("ShaderNodeBsdfGlossy")
    gloss.inputs["Roughness"].default_value = 0.02
    gloss.inputs["Color"].default_value = (0.9, 0.9, 0.9, 1)
    fres = nt.nodes.new("ShaderNodeLayerWeight")
    fres.inputs["Blend"].default_value = 0.5
    mix = nt.nodes.new("ShaderNodeMixShader")
    nt.links.new(fres.outputs["Fresnel"], mix.inputs["Fac"])
    nt.links.new(clear.outputs["BSDF"], mix.inputs[1])
    nt.links.new(gloss.outputs["BSDF"], mix.inputs[2])
    nt.links.new(mix.outputs["Shader"], out.inputs["Surface"])


def _plate(m, b):
    """A number plate: a light plate with a row of glyph cells, each as grey as thin black strokes
    on white average out (solid black blocks read as buttons and displays, not a plate)."""
    nt = m.node_tree
    brick = nt.nodes.new("ShaderNodeTexBrick")
    brick.inputs["Color1"].default_value = (0.3, 0.3, 0.32, 1)
    brick.inputs["Color2"].default_value = (0.4, 0.4, 0.42, 1)
    brick.inputs["Mortar"].default_value = (0.85, 0.85, 0.8, 1)
    brick.inputs["Scale"].default_value = 1.0
    brick.inputs["Mortar Size"].default_value = 0.014
    brick.inputs["Brick Width"].default_value = 0.05
    brick.inputs["Row Height"].default_value = 0.08
    nt.links.new(_object_coords(nt), brick.inputs["Vector"])
    nt.links.new(brick.outputs["Color"], b.inputs["Base Color"])


def _vehicle_materials(make, night: bool) -> None:
    m, b = make("car_paint", (0.5, 0.5, 0.5), rough=0.3)
    _car_paint(m, b)
    m, _ = make("car_glass", (0.02, 0.025, 0.03), rough=0.05, spec=1.0)
    _glass(m)
    make("cargo", (0.75, 0.75, 0.72), rough=0.6)
    make("tyre", (0.035, 0.035, 0.035), rough=0.85)
    make("rim", (0.6, 0.6, 0.62), rough=0.25, metallic=1.0)
    make("trim", (0.025, 0.025, 0.028), rough=0.6)
    make("grille", (0.015, 0.015, 0.017), rough=0.4)
    make("interior", (0.03, 0.028, 0.027), rough=0.8)
    m, b = make("plate", (0.85, 0.85, 0.8), rough=0.4)
    _plate(m, b)
    # a clear lens over a chrome reflector and a grey housing: it mirrors the sky and, a little,
    # takes the light that falls on it (a pure mirror is a black hole at night, a white block by
    # day reads as a projector or a spotlight)
    m, b = make("headlight", LAMP_LENS, rough=0.12, metallic=0.7)
    b.inputs["Coat Weight"].default_value = 1.0
    if night:
        _emission(b, (1.0, 0.95, 0.85), 40.0)
        _lights_switch(m, b)
    make("reverse_lamp", LAMP_LENS, rough=0.12, metallic=0.7)[1].inputs["Coat Weight"].default_value = 1.0  # never lit
    # a bright red lens over a chrome reflector, as the headlights (docs/rendering.md, "Kept: brighter
    # tail lamps": red 0.8 against 0.45 and 0.18; "Kept: tail lamps over a reflector")
    m, b = make("taillight", (0.8, 0.03, 0.025), rough=0.12, metallic=0.7)
    b.inputs["Coat Weight"].default_value = 1.0
    if night:
        _emission(b, (1.0, 0.05, 0.02), 10.0)
        _lights_switch(m, b)


def _lights_switch(m, b) -> None:
    """Lamps glow only on vehicles whose object property `lights` is 1 (moving traffic and the
    ego; parked cars are dark)."""
    nt = m.node_tree
    attr = nt.nodes.new("ShaderNodeAttribute")
    attr.attribute_type = "OBJECT"
    attr.attribute_name = "lights"
    mul = nt.nodes.new("ShaderNodeMath")
    mul.operation = "MULTIPLY"
    mul.inputs[1].default_value = b.inputs["Emission Strength"].default_value
    nt.links.new(attr.outputs["Fac"], mul.inputs[0])
    nt.links.new(mul.outputs[0], b.inputs["Emission Strength"])


def _people_materials(make) -> None:
    """Skin, hair and clothes; the shade of each drawn per person from the object's random number."""
    for name, stops, rough in (
            ("skin", [(0.0, (0.12, 0.06, 0.04)), (0.5, (0.45, 0.28, 0.2)), (1.0, (0.7, 0.5, 0.4))], 0.6),
            ("hair", [(0.0, (0.01, 0.008, 0.006)), (0.7, (0.08, 0.05, 0.03)), (1.0, (0.45, 0.35, 0.2))], 0.5),
            ("clothes", [(0.0, (0.02, 0.02, 0.025)), (0.3, (0.15, 0.18, 0.3)), (0.5, (0.5, 0.05, 0.05)),
                         (0.7, (0.6, 0.6, 0.58)), (0.85, (0.3, 0.35, 0.2)), (1.0, (0.8, 0.6, 0.2))], 0.85),
            ("trousers", [(0.0, (0.02, 0.02, 0.025)), (0.5, (0.05, 0.08, 0.18)), (1.0, (0.35, 0.3, 0.22))], 0.85)):
        m, b = make(name, stops[0][1], rough=rough)
        nt = m.node_tree
        info = nt.nodes.new("ShaderNodeObjectInfo")
        shift = nt.nodes.new("ShaderNodeMath")  # each material its own draw from the object's number
        shift.operation = "FRACT"
        mul = nt.nodes.new("ShaderNodeMath")
        mul.operation = "MULTIPLY"
        mul.inputs[1].default_value = float(len(name) * 7.31)
        nt.links.new(info.outputs["Random"], mul.inputs[0])
        nt.links.new(mul.outputs[0], shift.inputs[0])
        interp = "CONSTANT" if name == "clothes" else "LINEAR"
        nt.links.new(_ramp(nt, shift.outputs[0], stops, interp), b.inputs["Base Color"])


def _two_wheeler_materials(make) -> None:
    """Bicycles and motorcycles: painted frames and bodies (the object's colour), rubber, metal."""
    for name, cls in (("bike_frame", "bike"), ("moto_body", "moto")):
        m, b = make(name, (0.5, 0.5, 0.5), rough=0.35)
        _object_color(m, b)
        b.inputs["Coat Weight"].default_value = 1.0 if cls == "moto" else 0.3
    make("bike_tyre", (0.03, 0.03, 0.03), rough=0.8)
    make("bike_metal", (0.6, 0.6, 0.62), rough=0.3, metallic=1.0)
    make("moto_seat", (0.02, 0.02, 0.02), rough=0.55)
    make("moto_tyre", (0.03, 0.03, 0.03), rough=0.85)
    make("moto_metal", (0.45, 0.45, 0.47), rough=0.35, metallic=1.0)
    make("moto_lamp", (0.8, 0.82, 0.85), rough=0.05, metallic=0.6)


def _furniture_materials(make) -> None:
    """Traffic lights (the lit lens glows by day too), guard rails, hedges, benches, bins, awnings."""
    make("signal_housing", (0.02, 0.02, 0.022), rough=0.5)
    make("signal_off", (0.03, 0.03, 0.03), rough=0.1, spec=1.0)
    for name, rgb in (("signal_red", (1.0, 0.05, 0.02)), ("signal_amber", (1.0, 0.5, 0.02)),
                      ("signal_green", (0.1, 1.0, 0.5))):
        _, b = make(name, tuple(0.3 * c for c in rgb), rough=0.1)
        _emission(b, rgb, 6.0)
    make("guardrail", (0.55, 0.56, 0.57), rough=0.35, metallic=1.0)
    m, b = make("hedge", (0.04, 0.14, 0.03), rough=0.85)
    _noise_mix(m, b, (0.025, 0.09, 0.02), (0.07, 0.2, 0.04), 3.0)
    _bump(m, b, _noise(m.node_tree, 12.0, detail=3.0).outputs["Fac"], 0.8, distance=0.2)
    make("bench_wood", (0.3, 0.18, 0.09), rough=0.7)
    make("furniture_metal", (0.08, 0.09, 0.09), rough=0.45, metallic=0.8)
    make("bin", (0.05, 0.12, 0.08), rough=0.5)
    m, b = make("awning", (0.5, 0.1, 0.08), rough=0.8)
    _awning(m, b)
    make("railing", (0.05, 0.05, 0.055), rough=0.4, metallic=0.7)


def _awning(m, b) -> None:
    """Awning fabric: stripes of a colour drawn per building (the object's random number) and off-white."""
    nt = m.node_tree
    info = nt.nodes.new("ShaderNodeObjectInfo")
    colour = _ramp(nt, info.outputs["Random"], [(0.0, (0.45, 0.05, 0.04)), (0.25, (0.05, 0.2, 0.1)), (0.5, (0.08, 0.1, 0.3)),
                                                (0.75, (0.5, 0.35, 0.05)), (1.0, (0.2, 0.2, 0.2))], "CONSTANT")
    wave = nt.nodes.new("ShaderNodeTexWave")
    wave.inputs["Scale"].default_value = 2.0
    wave.inputs["Distortion"].default_value = 0.0
    nt.links.new(_object_coords(nt), wave.inputs["Vector"])
    stripes = _ramp(nt, wave.outputs["Fac"], [(0.0, (0.0,)), (0.5, (1.0,))], "CONSTANT")
    nt.links.new(_mix(nt, stripes, colour, (0.75, 0.72, 0.65)), b.inputs["Base Color"])


def build_materials(weather: dict) -> dict[str, bpy.types.Material]:
    wet = float(weather.get("wetness", 0.0))
    night = bool(weather.get("lights_on", False))
    mats = {}

    def make(name, *a, **k):
        m, b = _principled(name, *a, **k)
        mats[name] = m
        return m, b

    # asphalt: grey aggregate with patches, stains and a fine bump; when wet darker and glossier,
    # with mirror-like puddles where a coarse noise dips
    for name, base in (("asphalt", 0.13), ("asphalt_lot", 0.15)):
        m, b = make(name, (base,) * 3, rough=0.9, spec=0.35)
        _asphalt(m, b, base * (1 - 0.45 * wet), wet)
    for name, paint in (("paint_white", (0.75, 0.75, 0.72)), ("paint_yellow", (0.75, 0.55, 0.08)),
                        ("paint_crosswalk", (0.78, 0.78, 0.75)), ("paint_stop", (0.78, 0.78, 0.75))):
        m, b = make(name, paint, rough=0.6 - 0.4 * wet)
        _worn(m, b, paint, tuple(0.35 * c + 0.13 * (1 - 0.45 * wet) for c in paint))
        _bump(m, b, _noise(m.node_tree, 90.0).outputs["Fac"], 0.2)
    m, b = make("pavement", (0.35, 0.34, 0.32), rough=0.9 - 0.4 * wet)
    _pavers(m, b, (0.36, 0.34, 0.31), (0.25, 0.24, 0.22), size=(0.2, 0.1))
    m, b = make("kerb", (0.5, 0.5, 0.48), rough=0.8 - 0.3 * wet)
    _pavers(m, b, (0.52, 0.51, 0.49), (0.3, 0.3, 0.29), size=(1.0, 1.0), mortar=0.01)
    m, b = make("grass", (0.08, 0.2, 0.04), rough=0.95)
    _grass(m, b)
    make("bark", (0.12, 0.08, 0.05), rough=0.9)
    make("branch", (0.12, 0.08, 0.05), rough=0.9)  # bark on the limbs in the crown (class canopy)
    m, b = make("leaves", (0.05, 0.18, 0.03), rough=0.8)
    _noise_mix(m, b, (0.03, 0.12, 0.02), (0.1, 0.25, 0.05), 2.0)
    _bump(m, b, _noise(m.node_tree, 6.0, detail=3.0).outputs["Fac"], 0.8, distance=0.3)
    m, b = make("wall", (0.5, 0.45, 0.4), rough=0.85)
    _facade(m, b)
    m, b = make("window", (0.05, 0.07, 0.09), rough=0.05, spec=1.0)
    _windows(m, b, night)
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
    _vehicle_materials(make, night)
    _people_materials(make)
    _two_wheeler_materials(make)
    _furniture_materials(make)
    for name, base in EGO_MATERIALS.items():
        mats[name] = mats[base].copy()
        mats[name].name = name
    for name, m in mats.items():
        m.pass_index = CLASS_IDS[MATERIAL_CLASSES[name]]
        # glowing windows and lamps are seen, not sampled as lights: the street lights and
        # headlights are real lamps, and thousands of emissive triangles would slow every sample
        m.cycles.emission_sampling = "NONE"
    return mats
