"""Scene recipes (scenes/*.yaml): schema, defaults and validation.

A recipe is a mapping of sections; every key is optional except `family`. Unknown keys and bad
values raise RecipeError with one line naming the file and the field. See docs/scenes.md, "Recipes".
"""

from __future__ import annotations

import copy
from pathlib import Path

from common.errors import ConfigError
from common.files import read_yaml
from common.schema import Bool, List, Name, Num, Range, Section, Str

FAMILIES = ("highway", "intersection", "t_junction", "roundabout", "urban_block", "parking_lot")
VEHICLE_KINDS = ("car", "suv", "van", "truck", "bus")
WEATHER_PRESETS = ("clear_noon", "low_sun", "overcast", "rain", "fog", "night")

RecipeError = ConfigError  # a recipe is a config: the message names the file and field

SCHEMA = Section({
    "name": Name(default=None),  # default: the file's stem
    "family": Str(choices=FAMILIES),
    "seed": Num(0, 2**31 - 1, integer=True, default=0),
    # scale of the per-scene jitter of the rig (geometry.rig jitter: mounts cm, angles deg, focal %);
    # 0 renders through the nominal rig
    "rig_jitter": Num(0.0, 1.0, default=0.0),
    "layout": Section({
        "length": Num(60, 2000, default=300.0),  # m of main road
        "lanes_per_direction": Num(1, 4, integer=True, default=2),
        "lane_width": Num(2.5, 5.0, default=3.5),
        "curvature": Num(-0.02, 0.02, default=0.0),  # 1/m, highway only (0 = straight)
        "median": Str(choices=("none", "double_solid", "barrier"), default="double_solid"),
        "shoulder": Num(0.0, 4.0, default=1.0),
        "ring_radius": Num(10.0, 40.0, default=16.0),  # roundabout: centre line of the ring
        "block_length": Num(40.0, 200.0, default=80.0),  # urban_block: spacing of side streets
        "bay_rows": Num(1, 6, integer=True, default=2),  # parking_lot: rows of bays on each side of the aisle
        "bays_per_row": Num(4, 40, integer=True, default=12),
        "occupancy": Num(0.0, 1.0, default=0.6),  # parking_lot: fraction of bays holding a car
    }),
    "roadside": Section({
        "sidewalk_width": Num(0.0, 6.0, default=0.0),  # 0 = no sidewalk/curb
        "trees": Num(0.0, 1.0, default=0.3),  # trees per 10 m of road edge
        "overhanging": Num(0.0, 1.0, default=0.3),  # fraction of trees whose canopy reaches over the road
        "buildings": Num(0.0, 1.0, default=0.0),  # fraction of the roadside lined with buildings
        "building_height": Range(4.0, 120.0, default=[6.0, 20.0]),
        "street_lights": Num(0.0, 1.0, default=0.1),  # lights per 10 m of road edge
        "bridges": Num(0, 6, integer=True, default=0),  # overpasses crossing the main road
    }),
    "traffic": Section({
        "density": Num(0.0, 3.0, default=0.6),  # vehicles per 30 m of lane
        "seed": Num(0, 2**31 - 1, integer=True, default=None, nullable=True),  # traffic only (default: the recipe's seed)
        "kinds": List(Str(choices=VEHICLE_KINDS), default=list(VEHICLE_KINDS)),
        "speed_kmh": Range(0.0, 150.0, default=[30.0, 60.0]),
    }),
    "ego": Section({
        "lane": Num(0, 3, integer=True, default=0),  # 0 = rightmost lane of the ego's direction
        "speed_kmh": Num(0.0, 150.0, default=40.0),
        "start": Num(-500.0, 500.0, default=0.0),  # m along the route from its middle
    }),
    "weather": Section({
        "preset": Str(choices=WEATHER_PRESETS, default="clear_noon"),
        "sun_elevation_deg": Num(-30.0, 90.0, default=None, nullable=True),
        "sun_azimuth_deg": Num(-360.0, 360.0, default=None, nullable=True),
        "sun_strength": Num(0.0, 20.0, default=None, nullable=True),
        "sky_strength": Num(0.0, 5.0, default=None, nullable=True),
        "fog_density": Num(0.0, 0.2, default=None, nullable=True),
        "wetness": Num(0.0, 1.0, default=None, nullable=True),
        "lights_on": Bool(default=None, nullable=True),
    }),
    "frames": Section({
        "count": Num(1, 10000, integer=True, default=4),
        "rate_hz": Num(0.1, 100.0, default=2.0),
    }),
})
DEFAULTS = SCHEMA.defaults()


def check_overrides(overrides: dict, where: str) -> None:
    """Each override checked on its own, so a bad one is named where it was written (`where`:
    e.g. `ds.yaml: scenes[3].overrides`), not in the recipe it overrides."""
    if not isinstance(overrides, dict):
        raise RecipeError(f"{where}: must be a mapping of sections")
    for sec, vals in overrides.items():
        field = SCHEMA.fields.get(sec)
        if field is None:
            raise RecipeError(f"{where}.{sec}: unknown field (known: {', '.join(SCHEMA.fields)})")
        if isinstance(field, Section):  # only the fields given (the recipe has the rest)
            Section(field.fields, partial=True).validate(vals, f"{where}.{sec}")
        else:
            field.validate(vals, f"{where}.{sec}")


def validate_recipe(d, source: str = "recipe", overrides: dict | None = None, overrides_at: str | None = None) -> dict:
    """Checked recipe with defaults filled in. `overrides` (same shape) are merged first; with
    `overrides_at` (where they were written) each is checked there first."""
    if not isinstance(d, dict):
        raise RecipeError(f"{source}: must be a mapping of sections")
    d = copy.deepcopy(d)
    if overrides is not None and overrides_at is not None:
        check_overrides(overrides, overrides_at)
    if overrides is not None and not isinstance(overrides, dict):
        raise RecipeError(f"{source}: overrides: must be a mapping of sections")
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
    out = SCHEMA.validate(d, source)
    out["name"] = SCHEMA.fields["name"].validate(out["name"] or Path(source).stem, f"{source}: name")
    for k in [k for k, v in out["weather"].items() if v is None]:
        del out["weather"][k]  # unset: the preset decides
    if out["traffic"]["seed"] is None:
        del out["traffic"]["seed"]
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


def load_recipe(path, overrides: dict | None = None, overrides_at: str | None = None) -> dict:
    return validate_recipe(read_yaml(path), str(path), overrides, overrides_at)


# ---------------------------------------------------------------- where a recipe's roads go (what the layout builder and the sampler share)


def route_length(recipe) -> float:
    """Road length needed so the ego's whole drive stays 120 m clear of the ends."""
    travel = recipe["ego"]["speed_kmh"] / 3.6 * recipe["frames"]["count"] / recipe["frames"]["rate_hz"]
    return max(recipe["layout"]["length"], travel + 2 * abs(recipe["ego"]["start"]) + 240.0)


def junction_crossings(recipe) -> list[float]:
    """x (m, along the main road) of each cross street of a junction family (none for the others)."""
    fam = recipe["family"]
    if fam in ("intersection", "t_junction"):
        return [25.0]
    if fam == "urban_block":
        L, b = route_length(recipe), recipe["layout"]["block_length"]
        return [b / 2 + k * b for k in range(-int(L / b) - 1, int(L / b) + 1) if abs(b / 2 + k * b) < L / 2 - 40]
    return []


def junction_zone(recipe) -> float:
    """Half the length of main road a junction takes (its arms, pavements and crossings)."""
    n, w = recipe["layout"]["lanes_per_direction"], recipe["layout"]["lane_width"]
    return 0.2 + n * w + 0.5 + recipe["roadside"]["sidewalk_width"] + 6.0


def bridge_stations(recipe) -> list[float]:
    """Where along the main road of a junction family an overpass fits (10 m clear of every
    junction): empty where none does, as on a short block of a wide street; such a recipe's
    `roadside.bridges` cannot be built (the sampler draws none there)."""
    import numpy as np

    L, zone = route_length(recipe), junction_zone(recipe)
    skip = [(x + L / 2 - zone, x + L / 2 + zone) for x in junction_crossings(recipe)]
    return [float(s) for s in np.linspace(20, L - 20, 80) if all(not (a - 10 < s < b + 10) for a, b in skip)]
