"""Weather and light: Blender's physical (Nishita) sky, a sun lamp, fog, wet roads, night lights.

A preset gives every parameter; a recipe's `weather` section overrides any of them.
"""

from __future__ import annotations

import math

import bpy
from mathutils import Vector

PRESETS = {
    #             sun elev, sun strength, sky strength, overcast mix, fog, wet, lights
    "clear_noon": dict(sun_elevation_deg=62.0, sun_strength=4.0, sky_strength=0.35, overcast=0.0,
                       fog_density=0.0, wetness=0.0, lights_on=False),
    "low_sun": dict(sun_elevation_deg=7.0, sun_strength=3.0, sky_strength=0.5, overcast=0.0,
                    fog_density=0.0, wetness=0.0, lights_on=False),
    "overcast": dict(sun_elevation_deg=45.0, sun_strength=0.4, sky_strength=0.4, overcast=0.8,
                     fog_density=0.0, wetness=0.0, lights_on=False),
    "rain": dict(sun_elevation_deg=40.0, sun_strength=0.2, sky_strength=0.25, overcast=0.9,
                 fog_density=0.004, wetness=0.9, lights_on=False),
    "fog": dict(sun_elevation_deg=30.0, sun_strength=0.6, sky_strength=0.4, overcast=0.7,
                fog_density=0.03, wetness=0.2, lights_on=False),
    "night": dict(sun_elevation_deg=-12.0, sun_strength=0.02, sky_strength=0.005, overcast=0.0,
                  fog_density=0.0, wetness=0.0, lights_on=True),
}

# share of the sky under cloud, uniform in (lo, hi) per preset (night: too dark to tell)
CLOUDS = {"clear_noon": (0.0, 0.45), "low_sun": (0.1, 0.6), "overcast": (0.5, 1.0), "rain": (0.7, 1.0),
          "fog": (0.3, 0.8), "night": (0.0, 0.0)}


def resolve_weather(weather: dict, rng) -> dict:
    """The preset's parameters with the recipe's overrides; a random sun azimuth unless given."""
    out = dict(PRESETS[weather.get("preset", "clear_noon")])
    out["preset"] = weather.get("preset", "clear_noon")
    out["sun_azimuth_deg"] = float(rng.uniform(0, 360))
    lo, hi = CLOUDS[out["preset"]]
    out["clouds"] = float(rng.uniform(lo, hi))  # drawn after the azimuth: earlier draws unchanged
    out["cloud_seed"] = float(rng.uniform(0, 100))
    out.update({k: v for k, v in weather.items() if k != "preset"})
    return out


def sun_direction(elevation_deg: float, azimuth_deg: float) -> Vector:
    """Unit vector toward the sun, as Cycles' Nishita sky places it (rotation measured from +y)."""
    el, rot = math.radians(elevation_deg), math.radians(azimuth_deg)
    return Vector((-math.cos(el) * math.sin(rot), math.cos(el) * math.cos(rot), math.sin(el)))


NIGHT_GLOW = (0.004, 0.0033, 0.0025)  # a lit town's haze at night (sodium and LED light scattered back)


def fog_color(w: dict) -> tuple:
    """The haze's colour: light grey by day, as dark as the sky and sun leave it at dusk and night
    (a night haze lit like a day's would paint the sky grey). The sky fades by a decade per 4
    degrees of sun below the horizon (dark by -12, the end of nautical twilight); with the town's
    lights on, the haze keeps their dim glow."""
    ambient = min(1.0, (w["sky_strength"] + 0.1 * max(w["sun_strength"], 0.0)) / 0.3)
    ambient *= 10.0 ** (max(min(w["sun_elevation_deg"], 0.0), -12.0) / 4.0)
    glow = NIGHT_GLOW if w.get("lights_on") and w["sun_elevation_deg"] < 0 else (0.0, 0.0, 0.0)
    return tuple(c * ambient + g for c, g in zip((0.55, 0.57, 0.6), glow))


def setup_world(scene, w: dict) -> None:
    world = bpy.data.worlds.new("sky")
    scene.world = world
    world.use_nodes = True
    nt = world.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputWorld")
    sky = nt.nodes.new("ShaderNodeTexSky")
    sky.sky_type = "NISHITA"
    sky.sun_disc = False  # the sun lamp gives the sun; a disc would only add noise
    sky.sun_elevation = math.radians(max(w["sun_elevation_deg"], -10.0))
    sky.sun_rotation = math.radians(w["sun_azimuth_deg"])
    sky.air_density = 1.0
    sky.dust_density = 1.0 + 6.0 * w["overcast"]
    sky.ozone_density = 1.0
    bg = nt.nodes.new("ShaderNodeBackground")
    bg.inputs["Strength"].default_value = w["sky_strength"]
    # overcast: mix the physical sky with a flat grey
    mix = nt.nodes.new("ShaderNodeMixRGB")
    mix.inputs["Fac"].default_value = w["overcast"]
    mix.inputs["Color2"].default_value = (0.6, 0.62, 0.65, 1.0)
    nt.links.new(sky.outputs["Color"], mix.inputs["Color1"])
    nt.links.new(_clouds(nt, mix.outputs["Color"], w), bg.inputs["Color"])
    nt.links.new(bg.outputs["Background"], out.inputs["Surface"])
    # The sun is a lamp, so the sky is smooth: a small importance map samples it as well as the
    # automatic 1024 one, which Cycles rebuilds whenever a light changes (0.6 s on 2 cores; the
    # label renders turn the lights off and on every frame).
    world.cycles.sampling_method = "MANUAL"
    world.cycles.sample_map_resolution = 256
    setup_fog(scene, w["fog_density"], w.get("fog_color", fog_color(w)))

    if w["sun_elevation_deg"] <= 0:
        return  # a sun below the horizon lights nothing; as a lamp it would only cost shadow rays
    sun = bpy.data.lights.new("sun", "SUN")
    sun.energy = w["sun_strength"]
    sun.angle = math.radians(0.6 if w["overcast"] < 0.5 else 15.0)  # soft shadows under cloud
    if w["sun_elevation_deg"] < 15:
        sun.color = (1.0, 0.75, 0.5)
    obj = bpy.data.objects.new("sun", sun)
    obj.rotation_mode = "QUATERNION"
    obj.rotation_quaternion = sun_direction(w["sun_elevation_deg"], w["sun_azimuth_deg"]).to_track_quat("Z", "Y")
    scene.collection.objects.link(obj)


def _math(nt, op, a, b=None):
    node = nt.nodes.new("ShaderNodeMath")
    node.operation = op
    for i, v in enumerate((a, b)):
        if v is None:
            continue
        if isinstance(v, (int, float)):
            node.inputs[i].default_value = v
        else:
            nt.links.new(v, node.inputs[i])
    return node.outputs[0]


def _clouds(nt, sky, w: dict):
    """The sky with clouds over `w["clouds"]` of it: a fractal noise on a plane above the camera
    (so they flatten and shrink toward the horizon, where they fade out), lit by the sun on top and
    greyer in their thick parts; returns the colour socket (the sky unchanged when clear)."""
    cover = float(w.get("clouds", 0.0))
    if cover <= 0:
        return sky
    coord = nt.nodes.new("ShaderNodeTexCoord")  # in a world: the view direction
    sep = nt.nodes.new("ShaderNodeSeparateXYZ")
    nt.links.new(coord.outputs["Generated"], sep.inputs[0])
    z = _math(nt, "MAXIMUM", sep.outputs["Z"], 0.04)
    uv = nt.nodes.new("ShaderNodeCombineXYZ")
    nt.links.new(_math(nt, "DIVIDE", sep.outputs["X"], z), uv.inputs["X"])
    nt.links.new(_math(nt, "DIVIDE", sep.outputs["Y"], z), uv.inputs["Y"])
    uv.inputs["Z"].default_value = float(w.get("cloud_seed", 0.0))
    noise = nt.nodes.new("ShaderNodeTexNoise")
    noise.inputs["Scale"].default_value = 0.8
    noise.inputs["Detail"].default_value = 8.0
    noise.inputs["Roughness"].default_value = 0.6
    nt.links.new(uv.outputs[0], noise.inputs["Vector"])
    edge = 0.62 - 0.28 * cover  # noise above it is cloud: more cover, lower edge
    dens = nt.nodes.new("ShaderNodeMapRange")
    dens.inputs["From Min"].default_value = edge
    dens.inputs["From Max"].default_value = edge + 0.12
    nt.links.new(noise.outputs["Fac"], dens.inputs["Value"])
    fade = nt.nodes.new("ShaderNodeMapRange")  # thin out toward the horizon
    fade.inputs["From Min"].default_value = 0.02
    fade.inputs["From Max"].default_value = 0.25
    nt.links.new(sep.outputs["Z"], fade.inputs["Value"])
    mask = _math(nt, "MULTIPLY", dens.outputs["Result"], fade.outputs["Result"])
    # brightness in the sky texture's units (the background strength multiplies both)
    lit = min(4.0, 0.55 * max(w["sun_strength"], 0.0) / math.pi / max(w["sky_strength"], 1e-3) + 0.6)
    thick = nt.nodes.new("ShaderNodeMapRange")  # thick cloud is darker underneath
    thick.inputs["From Min"].default_value = edge
    thick.inputs["From Max"].default_value = edge + 0.35
    thick.inputs["To Min"].default_value = lit
    thick.inputs["To Max"].default_value = lit * 0.55
    nt.links.new(noise.outputs["Fac"], thick.inputs["Value"])
    col = nt.nodes.new("ShaderNodeMix")
    col.data_type = "RGBA"
    nt.links.new(mask, col.inputs["Factor"])
    nt.links.new(sky, col.inputs[6])
    grey = nt.nodes.new("ShaderNodeCombineColor")
    for ch, k in zip(("Red", "Green", "Blue"), (0.97, 0.98, 1.0)):
        nt.links.new(_math(nt, "MULTIPLY", thick.outputs["Result"], k), grey.inputs[ch])
    nt.links.new(grey.outputs[0], col.inputs[7])
    return col.outputs[2]


def add_street_lamps(scene, lamps, power: float = 4500.0, limit: int = 40) -> None:
    """Lights at street-light bulbs (night; (x, y, z) at `power` W or (x, y, z, watts)), the nearest
    `limit` to the origin: spots pointing down with a wide soft cone, as a lamp head shades what is
    above it (a point light would light its own pole and arm white)."""
    lamps = sorted(lamps, key=lambda p: p[0] ** 2 + p[1] ** 2)[:limit]
    for i, p in enumerate(lamps):
        light = bpy.data.lights.new(f"lamp{i}", "SPOT")  # a spot points along its local -z: down
        light.spot_size = math.radians(160)
        light.spot_blend = 0.4
        light.energy = p[3] if len(p) > 3 else power
        light.color = (1.0, 0.82, 0.6)
        light.shadow_soft_size = 0.2
        obj = bpy.data.objects.new(f"lamp{i}", light)
        obj.location = p[:3]
        scene.collection.objects.link(obj)


def add_headlights(scene, vehicle_obj, length: float, width: float, power: float = 400.0, front_x: float | None = None):
    """Two spot lights on a vehicle's front (at x = front_x, default length / 2 from its origin),
    parented to it (night)."""
    for side in (-1, 1):
        light = bpy.data.lights.new(f"{vehicle_obj.name}_hl{side:+d}", "SPOT")
        light.energy = power
        light.spot_size = math.radians(45)
        light.spot_blend = 0.9  # soft edges: little light on the road just ahead, most of it far
        obj = bpy.data.objects.new(light.name, light)
        obj.parent = vehicle_obj
        obj.location = ((length / 2 if front_x is None else front_x) + 0.05, side * (width / 2 - 0.3), 0.6)
        # spot points along its local -z: turn it to look forward and slightly down
        obj.rotation_euler = (0.0, math.radians(-87), 0.0)
        scene.collection.objects.link(obj)


SKY_HAZE_M = 400.0  # the depth of haze in front of the sky (a light haze leaves the blue sky and clouds visible)


def setup_fog(scene, density: float, color) -> None:
    """Homogeneous fog in the compositor: rgb = fog + (rgb - fog) exp(-density * min(distance, SKY_HAZE_M)).

    A volume in the world would make Cycles' label passes noisy (sample 0 can stop in the fog);
    the ray distance pass gives the exact attenuation of a homogeneous medium instead (no light
    scattered into the beam from the sun, which is fine for overcast fog)."""
    scene.use_nodes = density > 0
    if density <= 0:
        return
    scene.view_layers[0].use_pass_z = True  # the Render Layers node shows only enabled passes
    nt = scene.node_tree
    rl, comp = nt.nodes["Render Layers"], nt.nodes["Composite"]
    near = nt.nodes.new("CompositorNodeMath")  # the sky is as far as the haze is deep, not infinitely far
    near.operation = "MINIMUM"
    near.inputs[1].default_value = SKY_HAZE_M
    mul = nt.nodes.new("CompositorNodeMath")
    mul.operation = "MULTIPLY"
    mul.inputs[1].default_value = -density
    exp = nt.nodes.new("CompositorNodeMath")
    exp.operation = "EXPONENT"
    mix = nt.nodes.new("CompositorNodeMixRGB")
    mix.inputs[1].default_value = (*color, 1.0)
    nt.links.new(rl.outputs["Depth"], near.inputs[0])
    nt.links.new(near.outputs[0], mul.inputs[0])
    nt.links.new(mul.outputs[0], exp.inputs[0])
    nt.links.new(exp.outputs[0], mix.inputs[0])
    nt.links.new(rl.outputs["Image"], mix.inputs[2])
    nt.links.new(mix.outputs[0], comp.inputs[0])
