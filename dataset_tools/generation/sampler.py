"""Sampled scenes: recipes drawn from documented distributions instead of written by hand.

    recipes = sample_recipes({"count": 200, "seed": 1, "families": ["highway"], "weather": None})

A dataset config asks for them with `- {sample: {count: 200, seed: 1, ...}, split: train}`
(generation.dataset_config). A test block with `training_layouts: true` draws each scene's layout from the
config's training scenes instead, under new weather, traffic and ego drive (`relit_recipes`: the
paper's "easy" split). Scene k of a block is drawn from its own stream `(STREAM, seed, k)`, so the
same seed gives the same recipes, growing `count` keeps the first scenes, and blocks with different
seeds are independent. Every drawn recipe goes through recipe.validate_recipe. The ranges are
the tables below (docs/scene-variety.md lists them); they stay inside recipe.SCHEMA's bounds and
inside what each family's layout builder supports (roundabouts and parking lots: ego lane 0).
"""

from __future__ import annotations

import numpy as np

from common.errors import ConfigError
from common.schema import Bool, List, Name, Num, Section, Str

from .recipe import FAMILIES, VEHICLE_KINDS, WEATHER_PRESETS, bridge_stations, junction_crossings, validate_recipe

STREAM = 0x5CE7E  # keeps these streams apart from every other use of the same seed
MAX_SEED = 2**31 - 1

SAMPLE = Section({
    "count": Num(1, 100_000, integer=True),
    "seed": Num(0, MAX_SEED, integer=True),
    "families": List(Str(choices=FAMILIES), default=None, nullable=True),  # default: every family not held out
    "weather": List(Str(choices=WEATHER_PRESETS), default=None, nullable=True),  # default: every preset not held out
    "frames": Num(1, 10000, integer=True, default=4),  # frames per scene
    "rate_hz": Num(0.1, 100.0, default=2.0),
    "prefix": Name(default=None, nullable=True),  # scene names <prefix>_<k:04d>; default s<seed>
    "rig_jitter": Num(0.0, 1.0, default=0.0),  # scale of the per-scene rig jitter (0: the nominal rig)
    # test splits: each scene a training scene's layout (family, seed, layout, roadside) under a new
    # weather preset, new traffic and a new ego drive
    "training_layouts": Bool(default=False),
})

# lanes per direction, as (values, weights)
LANES = {
    "highway": ((1, 2, 3, 4), (1, 3, 3, 1)),
    "intersection": ((1, 2, 3), (2, 3, 1)),
    "t_junction": ((1, 2), (3, 2)),
    "urban_block": ((1, 2, 3), (2, 3, 1)),
    "roundabout": ((1, 2), (3, 1)),  # lanes of the arms; the ring is two lanes wide
    "parking_lot": ((1,), (1,)),
}
SIDEWALK_P = {"highway": 0.0, "intersection": 0.8, "t_junction": 0.7, "urban_block": 1.0,
              "roundabout": 0.6, "parking_lot": 0.3}  # chance of sidewalks (width U(1.5, 5) m)
BUILDINGS = {"highway": (0.0, 0.0), "intersection": (0.0, 0.6), "t_junction": (0.0, 0.5),
             "urban_block": (0.5, 0.95), "roundabout": (0.0, 0.4), "parking_lot": (0.0, 0.4)}
BRIDGES = {"highway": (0, 1, 2), "urban_block": (0, 0, 1)}  # drawn uniformly from the tuple; others 0
TRAFFIC_SPEED = {"highway": (60.0, 120.0), "intersection": (20.0, 60.0), "t_junction": (20.0, 60.0),
                 "urban_block": (20.0, 55.0), "roundabout": (15.0, 35.0), "parking_lot": (5.0, 15.0)}
DENSITY = {"parking_lot": (0.1, 0.5)}  # vehicles per 30 m of lane; others (0.2, 1.6)
# per preset: sun elevation (deg), sun strength, sky strength, fog density, wetness, chance of lights on
WEATHER = {
    "clear_noon": dict(elev=(35, 80), sun=(3.0, 5.0), sky=(0.25, 0.5), fog=(0.0, 0.0), wet=(0.0, 0.1), lights=0.0),
    "low_sun": dict(elev=(3, 15), sun=(2.0, 4.0), sky=(0.35, 0.7), fog=(0.0, 0.002), wet=(0.0, 0.2), lights=0.3),
    "overcast": dict(elev=(20, 70), sun=(0.2, 0.8), sky=(0.3, 0.55), fog=(0.0, 0.003), wet=(0.0, 0.4), lights=0.1),
    "rain": dict(elev=(20, 60), sun=(0.1, 0.4), sky=(0.15, 0.35), fog=(0.0, 0.008), wet=(0.6, 1.0), lights=0.4),
    "fog": dict(elev=(10, 50), sun=(0.3, 1.0), sky=(0.3, 0.5), fog=(0.01, 0.05), wet=(0.0, 0.5), lights=0.3),
    "night": dict(elev=(-20, -6), sun=(0.0, 0.05), sky=(0.0, 0.04), fog=(0.0, 0.003), wet=(0.0, 0.5), lights=1.0),
}


def _u(rng, lo, hi, nd=3) -> float:
    return round(float(rng.uniform(lo, hi)), nd)


def draw_recipe(rng: np.random.Generator, family: str, preset: str, frames: int, rate_hz: float) -> dict:
    """One recipe (unvalidated) of `family` under `preset`, every other field drawn from `rng`."""
    seed, traffic_seed = (int(v) for v in rng.integers(0, MAX_SEED, 2))
    lanes_v, lanes_w = LANES[family]
    lanes = int(rng.choice(lanes_v, p=np.array(lanes_w) / sum(lanes_w)))
    highway = family == "highway"
    layout = {
        "lanes_per_direction": lanes,
        "lane_width": _u(rng, 3.0, 3.8, 2),
        "curvature": _u(rng, -0.008, 0.008, 4) if highway and rng.random() < 0.6 else 0.0,
        "median": str(rng.choice(("none", "double_solid", "barrier") if highway else ("none", "double_solid"))),
        "shoulder": _u(rng, 0.5, 3.0, 2) if highway else _u(rng, 0.0, 1.0, 2),
        "ring_radius": _u(rng, 12.0, 28.0, 1),
        "block_length": _u(rng, 45.0, 120.0, 1),
        "bay_rows": int(rng.integers(1, 4)),
        "bays_per_row": int(rng.integers(8, 25)),
        "occupancy": _u(rng, 0.2, 0.95, 2),
    }
    b_lo, b_hi = BUILDINGS[family]
    h_lo = _u(rng, 4.0, 12.0, 1)
    roadside = {
        "sidewalk_width": _u(rng, 1.5, 5.0, 2) if rng.random() < SIDEWALK_P[family] else 0.0,
        "trees": _u(rng, 0.0, 1.0, 2),
        "overhanging": _u(rng, 0.0, 0.8, 2),
        "buildings": _u(rng, b_lo, b_hi, 2),
        "building_height": [h_lo, round(min(120.0, h_lo + float(rng.uniform(4.0, 40.0))), 1)],
        "street_lights": _u(rng, 0.0, 0.3, 2),
        "bridges": int(rng.choice(BRIDGES.get(family, (0,)))),
    }
    s_lo, s_hi = TRAFFIC_SPEED[family]
    v_lo = float(rng.uniform(s_lo, (s_lo + s_hi) / 2))
    v_hi = min(s_hi, v_lo + float(rng.uniform(5.0, 30.0)))
    kinds = [k for k in VEHICLE_KINDS if k == "car" or rng.random() < 0.7]
    traffic = {"density": _u(rng, *DENSITY.get(family, (0.2, 1.6)), 2), "seed": traffic_seed,
               "kinds": kinds, "speed_kmh": [round(v_lo, 1), round(v_hi, 1)]}
    one_lane = family in ("roundabout", "parking_lot")
    ego = {"lane": 0 if one_lane else int(rng.integers(0, lanes)),
           "speed_kmh": _u(rng, max(3.0, v_lo * 0.8), v_hi, 1),
           "start": _u(rng, -30.0, 10.0, 1) if family in ("intersection", "t_junction") else _u(rng, -40.0, 40.0, 1)}
    w = WEATHER[preset]
    weather = {"preset": preset, "sun_elevation_deg": _u(rng, *w["elev"], 1), "sun_azimuth_deg": _u(rng, 0.0, 360.0, 1),
               "sun_strength": _u(rng, *w["sun"], 3), "sky_strength": _u(rng, *w["sky"], 3),
               "fog_density": _u(rng, *w["fog"], 4), "wetness": _u(rng, *w["wet"], 2),
               "lights_on": bool(rng.random() < w["lights"])}
    return {"family": family, "seed": seed, "layout": layout, "roadside": roadside, "traffic": traffic,
            "ego": ego, "weather": weather, "frames": {"count": int(frames), "rate_hz": float(rate_hz)}}


def scene_stream(seed: int, k: int) -> np.random.Generator:
    return np.random.default_rng([STREAM, int(seed), int(k)])


def sample_recipes(spec: dict, source: str = "sample", families=None, weather=None) -> list[dict]:
    """The validated recipes of a sample block (spec as SAMPLE validates it). `families`/`weather`
    are the choices when the spec names none."""
    fams = spec.get("families") or list(families or FAMILIES)
    presets = spec.get("weather") or list(weather or WEATHER_PRESETS)
    prefix = spec.get("prefix") or f"s{spec['seed']}"
    out = []
    for k in range(spec["count"]):
        rng = scene_stream(spec["seed"], k)
        family = str(rng.choice(fams))
        preset = str(rng.choice(presets))
        d = draw_recipe(rng, family, preset, spec.get("frames", 4), spec.get("rate_hz", 2.0))
        d["name"] = f"{prefix}_{k:04d}"
        if spec.get("rig_jitter"):
            d["rig_jitter"] = float(spec["rig_jitter"])
        out.append(buildable(d, f"{source}[{k}]"))
    return out


def buildable(d: dict, source: str) -> dict:
    """The validated recipe, made one whose layout builds: overpasses are drawn only where one fits
    (a short block of a wide street has no room between its junctions: `min() arg is an
    empty sequence` in the layout builder). Draws nothing from the scene's stream, so the other
    recipes of a block stay as they were."""
    r = validate_recipe(d, source)
    if r["roadside"]["bridges"] and junction_crossings(r) and not bridge_stations(r):
        d = {**d, "roadside": {**d["roadside"], "bridges": 0}}
        r = validate_recipe(d, source)
    return r


def relit_recipes(spec: dict, bases: list[dict], source: str = "sample", weather=None) -> list[dict]:
    """The validated recipes of a `training_layouts` block: scene k takes the family, seed, layout
    and roadside of one of `bases` (the training recipes; drawn from the scene's stream, among the
    spec's families if it names any) and draws the rest as `sample_recipes` does: a weather preset
    other than the base's, new traffic (its own seed), a new ego lane, speed and start."""
    fams = spec.get("families")
    bases = [b for b in bases if not fams or b["family"] in fams]
    if not bases:
        raise ConfigError(f"{source}.training_layouts: no training scene" + (f" of the families {fams}" if fams else "") + " to take a layout from")
    presets = spec.get("weather") or list(weather or WEATHER_PRESETS)
    prefix = spec.get("prefix") or f"s{spec['seed']}"
    out = []
    for k in range(spec["count"]):
        rng = scene_stream(spec["seed"], k)
        base = bases[int(rng.integers(0, len(bases)))]
        others = [p for p in presets if p != base["weather"]["preset"]] or presets
        d = draw_recipe(rng, base["family"], str(rng.choice(others)), spec.get("frames", 4), spec.get("rate_hz", 2.0))
        d.update(seed=base["seed"], layout=dict(base["layout"]), roadside=dict(base["roadside"]), name=f"{prefix}_{k:04d}")
        lanes = 1 if base["family"] in ("roundabout", "parking_lot") else base["layout"]["lanes_per_direction"]
        d["ego"]["lane"] = int(rng.integers(0, lanes))
        if spec.get("rig_jitter"):
            d["rig_jitter"] = float(spec["rig_jitter"])
        out.append(buildable(d, f"{source}[{k}]"))
    return out
