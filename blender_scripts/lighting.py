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


def resolve_weather(weather: dict, rng) -> dict:
    """The preset's parameters with the recipe's overrides; a random sun azimuth unless given."""
    out = dict(PRESETS[weather.get("preset", "clear_noon")])
    out["preset"] = weather.get("preset", "clear_noon")
    out["sun_azimuth_deg"] = float(rng.uniform(0, 360))
    out.update({k: v for k, v in weather.items() if k != "preset"})
    return out


def sun_direction(elevation_deg: float, azimuth_deg: float) -> Vector:
    """Unit vector toward the sun, as Cycles' Nishita sky places it (rotation measured from +y)."""
    el, rot = math.radians(elevation_deg), math.radians(azimuth_deg)
    return Vector((-math.cos(el) * math.sin(rot), math.cos(el) * math.cos(rot), math.sin(el)))


def fog_color(w: dict) -> tuple:
    """The haze's colour: light grey by day, as dark as the sky and sun leave it at dusk and night
    (a night haze lit like a day's would paint the sky grey)."""
    ambient = min(1.0, (w["sky_strength"] + 0.1 * max(w["sun_strength"], 0.0)) / 0.3)
    return tuple(c * ambient for c in (0.55, 0.57, 0.6))


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
    nt.links.new(mix.outputs["Color"], bg.inputs["Color"])
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


def add_street_lamps(scene, lamps, power: float = 4500.0, limit: int = 40) -> None:
    """Point lights at street-light bulbs (night); the nearest `limit` to the origin."""
    lamps = sorted(lamps, key=lambda p: p[0] ** 2 + p[1] ** 2)[:limit]
    for i, p in enumerate(lamps):
        light = bpy.data.lights.new(f"lamp{i}", "POINT")
        light.energy = power
        light.color = (1.0, 0.82, 0.6)
        light.shadow_soft_size = 0.2
        obj = bpy.data.objects.new(f"lamp{i}", light)
        obj.location = p
        scene.collection.objects.link(obj)


def add_headlights(scene, vehicle_obj, length: float, width: float, power: float = 400.0, front_x: float | None = None):
    """Two spot lights on a vehicle's front (at x = front_x, default length / 2 from its origin),
    parented to it (night)."""
    for side in (-1, 1):
        light = bpy.data.lights.new(f"{vehicle_obj.name}_hl{side:+d}", "SPOT")
        light.energy = power
        light.spot_size = math.radians(60)
        light.spot_blend = 0.5
        obj = bpy.data.objects.new(light.name, light)
        obj.parent = vehicle_obj
        obj.location = ((length / 2 if front_x is None else front_x) + 0.05, side * (width / 2 - 0.3), 0.6)
        # spot points along its local -z: turn it to look forward and slightly down
        obj.rotation_euler = (0.0, math.radians(-85), 0.0)
        scene.collection.objects.link(obj)


def setup_fog(scene, density: float, color) -> None:
    """Homogeneous fog in the compositor: rgb = fog + (rgb - fog) exp(-density * distance).

    A volume in the world would make Cycles' label passes noisy (sample 0 can stop in the fog);
    the ray distance pass gives the exact attenuation of a homogeneous medium instead (no light
    scattered into the beam from the sun, which is fine for overcast fog)."""
    scene.use_nodes = density > 0
    if density <= 0:
        return
    scene.view_layers[0].use_pass_z = True  # the Render Layers node shows only enabled passes
    nt = scene.node_tree
    rl, comp = nt.nodes["Render Layers"], nt.nodes["Composite"]
    mul = nt.nodes.new("CompositorNodeMath")
    mul.operation = "MULTIPLY"
    mul.inputs[1].default_value = -density
    exp = nt.nodes.new("CompositorNodeMath")
    exp.operation = "EXPONENT"
    mix = nt.nodes.new("CompositorNodeMixRGB")
    mix.inputs[1].default_value = (*color, 1.0)
    nt.links.new(rl.outputs["Depth"], mul.inputs[0])
    nt.links.new(mul.outputs[0], exp.inputs[0])
    nt.links.new(exp.outputs[0], mix.inputs[0])
    nt.links.new(rl.outputs["Image"], mix.inputs[2])
    nt.links.new(mix.outputs[0], comp.inputs[0])
