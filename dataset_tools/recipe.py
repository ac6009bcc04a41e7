"""Scene recipes (scenes/*.yaml): schema, defaults and validation.

A recipe is a mapping of sections; every key is optional except `family`. Unknown keys and bad
values raise RecipeError with one line naming the file and the field. See README.md, "Recipes".
"""

from __future__ import annotations

import copy
from pathlib import Path

import yaml

FAMILIES = ("highway", "intersection", "t_junction", "roundabout", "urban_block", "parking_lot")
VEHICLE_KINDS = ("car", "suv", "van", "truck", "bus")
WEATHER_PRESETS = ("clear_noon", "low_sun", "overcast", "rain", "fog", "night")


class RecipeError(ValueError):
    """A recipe that cannot build a scene: the message names the file and field."""


def _num(lo, hi, integer=False):
    return ("int" if integer else "num", lo, hi)


# section -> key -> (kind, ...) ; default values below
SCHEMA = {
    "name": ("str",),
    "family": ("choice", FAMILIES),
    "seed": _num(0, 2**31 - 1, True),
    "layout": {
        "length": _num(60, 2000),  # m of main road
        "lanes_per_direction": _num(1, 4, True),
        "lane_width": _num(2.5, 5.0),
        "curvature": _num(-0.02, 0.02),  # 1/m, highway only (0 = straight)
        "median": ("choice", ("none", "double_solid", "barrier")),
        "shoulder": _num(0.0, 4.0),
        "ring_radius": _num(10.0, 40.0),  # roundabout: centre line of the ring
        "block_length": _num(40.0, 200.0),  # urban_block: spacing of side streets
        "bay_rows": _num(1, 6, True),  # parking_lot: rows of bays on each side of the aisle
        "bays_per_row": _num(4, 40, True),
        "occupancy": _num(0.0, 1.0),  # parking_lot: fraction of bays holding a car
    },
    "roadside": {
        "sidewalk_width": _num(0.0, 6.0),  # 0 = no sidewalk/curb
        "trees": _num(0.0, 1.0),  # trees per 10 m of road edge
        "overhanging": _num(0.0, 1.0),  # fraction of trees whose canopy reaches over the road
        "buildings": _num(0.0, 1.0),  # fraction of the roadside lined with buildings
        "building_height": ("range", 4.0, 120.0),
        "street_lights": _num(0.0, 1.0),  # lights per 10 m of road edge
        "bridges": _num(0, 6, True),  # overpasses crossing the main road
    },
    "traffic": {
        "density": _num(0.0, 3.0),  # vehicles per 30 m of lane
        "seed": _num(0, 2**31 - 1, True),  # traffic only (default: the recipe's seed)
        "kinds": ("kinds",),
        "speed_kmh": ("range", 0.0, 150.0),
    },
    "ego": {
        "lane": _num(0, 3, True),  # 0 = rightmost lane of the ego's direction
        "speed_kmh": _num(0.0, 150.0),
        "start": _num(-500.0, 500.0),  # m along the route from its middle
    },
    "weather": {
        "preset": ("choice", WEATHER_PRESETS),
        "sun_elevation_deg": _num(-30.0, 90.0),
        "sun_azimuth_deg": _num(-360.0, 360.0),
        "sun_strength": _num(0.0, 20.0),
        "sky_strength": _num(0.0, 5.0),
        "fog_density": _num(0.0, 0.2),
        "wetness": _num(0.0, 1.0),
        "lights_on": ("bool",),
    },
    "frames": {
        "count": _num(1, 10000, True),
        "rate_hz": _num(0.1, 100.0),
    },
}

DEFAULTS = {
    "seed": 0,
    "layout": {
        "length": 300.0, "lanes_per_direction": 2, "lane_width": 3.5, "curvature": 0.0,
        "median": "double_solid", "shoulder": 1.0, "ring_radius": 16.0, "block_length": 80.0,
        "bay_rows": 2, "bays_per_row": 12, "occupancy": 0.6,
    },
    "roadside": {
        "sidewalk_width": 0.0, "trees": 0.3, "overhanging": 0.3, "buildings": 0.0,
        "building_height": [6.0, 20.0], "street_lights": 0.1, "bridges": 0,
    },
    "traffic": {"density": 0.6, "kinds": list(VEHICLE_KINDS), "speed_kmh": [30.0, 60.0]},
    "ego": {"lane": 0, "speed_kmh": 40.0, "start": 0.0},
    "weather": {"preset": "clear_noon"},
    "frames": {"count": 4, "rate_hz": 2.0},
}


def _check(value, spec, where):
    kind = spec[0]
    if kind == "str":
        if not isinstance(value, str) or not value:
            raise RecipeError(f"{where}: must be a non-empty string")
        return value
    if kind == "bool":
        if not isinstance(value, bool):
            raise RecipeError(f"{where}: must be true or false, got {value!r}")
        return value
    if kind == "choice":
        if value not in spec[1]:
            raise RecipeError(f"{where}: must be one of {', '.join(spec[1])}, got {value!r}")
        return value
    if kind in ("num", "int"):
        lo, hi = spec[1], spec[2]
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        if kind == "int":
            ok = ok and float(value).is_integer()
        if not ok or not lo <= value <= hi:
            what = "a whole number" if kind == "int" else "a number"
            raise RecipeError(f"{where}: must be {what} in [{lo}, {hi}], got {value!r}")
        return int(value) if kind == "int" else float(value)
    if kind == "range":
        lo, hi = spec[1], spec[2]
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            value = [value, value]
        if (not isinstance(value, list) or len(value) != 2
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
                or not lo <= value[0] <= value[1] <= hi):
            raise RecipeError(f"{where}: must be [min, max] with {lo} <= min <= max <= {hi}, got {value!r}")
        return [float(v) for v in value]
    if kind == "kinds":
        if (not isinstance(value, list) or not value
                or any(v not in VEHICLE_KINDS for v in value)):
            raise RecipeError(f"{where}: must be a non-empty list of {', '.join(VEHICLE_KINDS)}, got {value!r}")
        return list(value)
    raise AssertionError(kind)


def validate_recipe(d, source: str = "recipe", overrides: dict | None = None) -> dict:
    """Checked recipe with defaults filled in. `overrides` (same shape) are merged first."""
    if not isinstance(d, dict):
        raise RecipeError(f"{source}: must be a mapping of sections")
    d = copy.deepcopy(d)
    for sec, vals in (overrides or {}).items():
        if isinstance(vals, dict):
            base = d.setdefault(sec, {})
            if not isinstance(base, dict):
                raise RecipeError(f"{source}: {sec}: must be a mapping")
            base.update(vals)
        else:
            d[sec] = vals
    if "family" not in d:
        raise RecipeError(f"{source}: family: missing (one of {', '.join(FAMILIES)})")
    out = copy.deepcopy(DEFAULTS)
    out["name"] = Path(source).stem
    for key, value in d.items():
        if key not in SCHEMA:
            raise RecipeError(f"{source}: {key}: unknown section (known: {', '.join(SCHEMA)})")
        spec = SCHEMA[key]
        if isinstance(spec, dict):
            if not isinstance(value, dict):
                raise RecipeError(f"{source}: {key}: must be a mapping")
            for k, v in value.items():
                if k not in spec:
                    raise RecipeError(f"{source}: {key}.{k}: unknown field (known: {', '.join(spec)})")
                out[key][k] = _check(v, spec[k], f"{source}: {key}.{k}")
        else:
            out[key] = _check(value, spec, f"{source}: {key}")
    out["traffic"].setdefault("seed", out["seed"])
    lay = out["layout"]
    one_lane = {"roundabout": "the ring", "parking_lot": "the aisle"}
    if out["family"] in one_lane and out["ego"]["lane"] != 0:
        raise RecipeError(f"{source}: ego.lane: must be 0 for {out['family']} (the ego drives "
                          f"{one_lane[out['family']]}), got {out['ego']['lane']}")
    if out["ego"]["lane"] >= lay["lanes_per_direction"]:
        raise RecipeError(f"{source}: ego.lane: {out['ego']['lane']} but the road has "
                          f"{lay['lanes_per_direction']} lane(s) per direction")
    return out


def read_yaml(path, error=ValueError):
    """A YAML file's content; an unreadable or malformed file raises `error` with one line naming it."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise error(f"{path}: cannot read ({exc.strerror})") from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise error(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None


def load_recipe(path, overrides: dict | None = None) -> dict:
    return validate_recipe(read_yaml(path, RecipeError), str(path), overrides)
