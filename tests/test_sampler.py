"""Sampled scenes (dataset_tools.generation.sampler, config `sample:` blocks): deterministic,
valid, buildable, and held-out splits that never share a seed or a held-out family with training."""

from __future__ import annotations

import collections

import pytest
import yaml

from blender_scripts.build_scene import scene_rng
from blender_scripts.layouts import build_layout
from blender_scripts.traffic import ego_pose, place_traffic
from common.errors import ConfigError
from dataset_tools.generation.config import load_config
from dataset_tools.generation.recipe import FAMILIES, WEATHER_PRESETS, validate_recipe
from dataset_tools.generation.sampler import SAMPLE, sample_recipes


def _spec(**kw):
    return SAMPLE.validate({"count": 120, "seed": 7, **kw}, "test")


def test_sampler_is_deterministic_and_every_recipe_validates():
    a, b = sample_recipes(_spec()), sample_recipes(_spec())
    assert a == b
    assert sample_recipes(_spec(count=30)) == a[:30]  # growing count keeps the first scenes
    c = sample_recipes(_spec(seed=8))
    assert all(x["seed"] != y["seed"] for x, y in zip(a, c))
    for r in a:
        assert validate_recipe(r, "again") == r  # already the checked form: a fixed point
    names = [r["name"] for r in a]
    assert len(set(names)) == len(names) and all(n.startswith("s7_") for n in names)
    # the draws cover the space: every family and preset, varied continuous fields
    assert {r["family"] for r in a} == set(FAMILIES)
    assert {r["weather"]["preset"] for r in a} == set(WEATHER_PRESETS)
    assert len({r["layout"]["lane_width"] for r in a}) > 50
    assert len({r["weather"]["sun_azimuth_deg"] for r in a}) > 50


def test_every_drawn_recipe_builds_a_layout_with_traffic_and_an_ego_route():
    """The drawn values stay inside what each family's layout builder supports (pure numpy: the
    same code Blender runs)."""
    for r in sample_recipes(_spec(count=30, seed=11, frames=2)):
        lay = build_layout(r, scene_rng(r["seed"], 1))
        place_traffic(lay, r, scene_rng(r["traffic"]["seed"], 3))
        for t in (0.0, 0.5):
            assert all(abs(v) < 1e5 for v in ego_pose(lay, r, t)), r["name"]


def _config(tmp_path, scenes, **top):
    path = tmp_path / "cfg.yaml"
    path.write_text(yaml.safe_dump({"rig": "configs/rigs/default.yaml", "scenes": scenes, **top}))
    return path


def test_heldout_seeds_never_overlap_training_and_held_out_families_stay_out(tmp_path):
    cfg = load_config(_config(tmp_path, [
        {"sample": {"count": 80, "seed": 1}, "split": "train"},
        {"sample": {"count": 20, "seed": 2}, "split": "heldout"},
        {"sample": {"count": 10, "seed": 3, "families": ["roundabout"], "weather": ["fog"]}, "split": "heldout"},
        {"recipe": "scenes/test_hard_urban.yaml", "split": "hard"},
    ], hold_out={"families": ["roundabout"], "weather": ["fog"]}))
    by_split = collections.defaultdict(list)
    for s in cfg["scenes"]:
        by_split[s["split"]].append(s["recipe"])
    seeds = lambda rs: {v for r in rs for v in (r["seed"], r["traffic"]["seed"])}  # noqa: E731
    assert not seeds(by_split["train"]) & seeds(by_split["heldout"] + by_split["hard"])
    assert all(r["family"] != "roundabout" and r["weather"]["preset"] != "fog" for r in by_split["train"])
    assert {r["family"] for r in by_split["heldout"]} >= {"roundabout"}
    assert sum(r["weather"]["preset"] == "fog" for r in by_split["heldout"]) >= 10
    assert len(by_split["train"]) == 80 and len(by_split["heldout"]) == 30

    refused = [
        # a test block reusing the training block's seed
        ([{"sample": {"count": 2, "seed": 1}}, {"sample": {"count": 2, "seed": 1}, "split": "heldout"}], {}, "seed"),
        # a training block asking for a held-out family / preset; a named training recipe using one
        ([{"sample": {"count": 2, "seed": 1, "families": ["roundabout"]}}], {"families": ["roundabout"]}, "held out"),
        ([{"sample": {"count": 2, "seed": 1, "weather": ["night"]}}], {"weather": ["night"]}, "held out"),
        ([{"recipe": "scenes/roundabout.yaml"}], {"families": ["roundabout"]}, "held-out"),
        # a named test scene whose seed a sampled training scene uses
        ([{"sample": {"count": 1, "seed": 1}},
          {"recipe": "scenes/test_hard_urban.yaml", "split": "hard",
           "overrides": {"seed": sample_recipes(SAMPLE.validate({"count": 1, "seed": 1}, "x"))[0]["seed"]}}],
         {}, "shares a seed"),
        ([{"recipe": "scenes/roundabout.yaml", "name": "recipes"}], {}, "reserved"),
    ]
    for scenes, hold, words in refused:
        with pytest.raises(ConfigError, match=words):
            load_config(_config(tmp_path, scenes, hold_out=hold))
