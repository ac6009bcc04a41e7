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
from dataset_tools.generation.dataset_config import load_config
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


def build_sampled(count: int, seed: int, families=None, frames: int = 4) -> tuple[int, list[str]]:
    """Build layout, traffic and ego route of `count` sampled recipes (no rendering) -> (built,
    failures as 'name family: error')."""
    fails = []
    for r in sample_recipes(_spec(count=count, seed=seed, frames=frames, **({"families": families} if families else {}))):
        try:
            lay = build_layout(r, scene_rng(r["seed"], 1))
            place_traffic(lay, r, scene_rng(r["traffic"]["seed"], 3))
            assert all(abs(v) < 1e5 for t in (0.0, 0.5) for v in ego_pose(lay, r, t))
        except Exception as exc:  # noqa: BLE001 - every failure is a finding
            fails.append(f"{r['name']} {r['family']}: {type(exc).__name__}: {exc}")
    return count, fails


def test_many_sampled_recipes_of_every_family_build():
    """About 1 in 400 sampled urban blocks (a short block of a wide street with a bridge)
    failed in the layout builder (`min() arg is an empty sequence`): invisible in 30 recipes, certain
    in thousands. The sampler now draws only what builds. Here 200 recipes of every family and 150
    urban blocks (the failing family; 45 s on an idle 2-core machine, 2026-11-28, since the layouts
    grew roadside detail); SAMPLED_LAYOUTS=5000 for the issue's 5,000 (measured 2026-11-25: 5,000 of
    every family and 1,666 urban blocks, all built, in 333 s at nice 19 on the shared 2-core
    machine)."""
    import os
    import time

    n = int(os.environ.get("SAMPLED_LAYOUTS", "200"))
    t0 = time.perf_counter()
    _, fails = build_sampled(n, 880088)
    _, fails_ub = build_sampled(max(150, n // 3), 34, families=["urban_block"])
    print(f"\n{n} + {max(150, n // 3)} sampled layouts built in {time.perf_counter() - t0:.1f} s")
    assert not fails + fails_ub, fails + fails_ub


def test_a_block_with_no_room_for_a_bridge_is_drawn_without_one():
    """The issue's scene: an urban block with 3 lanes each way, a 55 m block, 4.2 m pavements and a
    bridge. Built as written it fails with one clear line; the sampler draws no bridge there."""
    from dataset_tools.generation.recipe import bridge_stations
    from dataset_tools.generation.sampler import buildable

    drawn = sample_recipes(_spec(count=1500, seed=880088, frames=4, families=["urban_block"]))
    no_room = [d for d in drawn if not bridge_stations(d)]  # about 1 in 100 (those drawn with a bridge failed before)
    assert 3 <= len(no_room) <= 60 and all(d["roadside"]["bridges"] == 0 for d in no_room)
    d = no_room[0]
    d["roadside"]["bridges"] = 1  # as it could be drawn
    r = validate_recipe(d, "issue34")
    assert bridge_stations(r) == []
    with pytest.raises(ValueError, match="roadside.bridges: 1, but no overpass fits between the junctions"):
        build_layout(r, scene_rng(r["seed"], 1))
    fixed = buildable(d, "issue34")
    assert fixed["roadside"]["bridges"] == 0 and {**fixed, "roadside": r["roadside"]} == r
    build_layout(fixed, scene_rng(fixed["seed"], 1))


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


def test_a_scene_that_fails_to_build_does_not_stop_the_others():
    """`generate` stopped the whole data set at the first scene whose layout failed. The
    driver's pool slots now give that scene up (its error names the scene and its recipe), finish
    every other scene, and the run exits 1 (generation.driver.render); the same command redoes only
    what is missing. Fake workers here: the logic, without Blender."""
    import queue
    from types import SimpleNamespace

    from dataset_tools.generation.driver import WorkerFailed, _drive

    started = []

    class Fake:
        def __init__(self):
            started.append(self)

        def run(self, task):
            if task.scene == "bad":
                raise WorkerFailed("bad (recipe DATA/recipes/bad.yaml): ValueError: roadside.bridges: 1, but no overpass fits")
            for f in task.frames:
                yield {"frame": f}

        def close(self):
            pass

    q = queue.Queue()
    for scene, frames in [("a", [0, 1]), ("bad", [0]), ("bad", [1]), ("b", [0, 1, 2])]:
        q.put(SimpleNamespace(scene=scene, frames=frames))
    got, errors, failed = [], [], set()
    _drive(q, Fake, lambda task, msg: got.append((task.scene, msg["frame"])), errors, True, failed)
    assert got == [("a", 0), ("a", 1), ("b", 0), ("b", 1), ("b", 2)]
    assert failed == {"bad"} and len(errors) == 1 and "bad (recipe DATA/recipes/bad.yaml)" in str(errors[0])
    assert len(started) == 2  # a fresh worker after the failed one (it ends after reporting)


def test_generate_with_blender_gives_up_a_scene_that_fails_to_build_and_resumes(tmp_path):
    """The fake-worker test above, with the real Blender worker: of two scenes, one is the issue's
    kind of urban block (validated, but no room for its bridge: the layout builder raises in the
    worker). generate names that scene and its recipe, renders the other, exits 1; the same command
    again, once the recipe is fixed, renders only the failed scene."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    from dataset_tools.generation.recipe import bridge_stations

    root = Path(__file__).resolve().parents[1]
    bad = {"family": "urban_block", "seed": 880, "layout": {"lanes_per_direction": 3, "lane_width": 3.73, "block_length": 50, "length": 332},
           "roadside": {"sidewalk_width": 2.31, "trees": 0.3, "buildings": 0.5, "building_height": [8, 20], "bridges": 1},
           "traffic": {"density": 0.3}, "ego": {"lane": 1, "speed_kmh": 30}, "weather": {"preset": "clear_noon"}, "frames": {"count": 1}}
    (tmp_path / "block.yaml").write_text(yaml.safe_dump(bad))
    cfg = {"name": "fails", "rig": str(root / "configs/rigs/default.yaml"), "fisheye_size": [64, 40],
           "topdown": {"size": 64, "height_m": 60.0, "bound": 25.0}, "render": {"quality": "draft"}, "frames": 1,
           "scenes": [{"recipe": str(root / "scenes/highway_straight.yaml"), "name": "good", "split": "train"},
                      {"recipe": str(tmp_path / "block.yaml"), "name": "bad_block", "split": "train"}]}
    (tmp_path / "ds.yaml").write_text(yaml.safe_dump(cfg))
    assert bridge_stations(load_config(tmp_path / "ds.yaml")["scenes"][1]["recipe"]) == []  # it validates, and cannot be built
    out = tmp_path / "out"

    def generate():
        return subprocess.run([sys.executable, "-m", "dataset_tools", "generate", "--config", str(tmp_path / "ds.yaml"), "--out", str(out),
                               "--no-progress", "--workers", "1"], cwd=root, capture_output=True, text=True, timeout=600)

    def rendered():
        return sorted((d["scene"], d["frame"]) for d in map(json.loads, (out / "manifest.jsonl").read_text().splitlines()))

    r = generate()
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
    lines = r.stderr.strip().splitlines()
    assert lines[0].startswith(f"generate: bad_block (recipe {out / 'recipes' / 'bad_block.yaml'}): ValueError: roadside.bridges: 1, "
                               "but no overpass fits"), lines
    assert "1 scene(s) failed, the others are rendered" in lines[-1] and len(lines) == 2, lines
    assert "roadside.bridges" in (out / "worker_errors.log").read_text()  # the trace, kept aside
    assert rendered() == [("good", 0)] and not (out / "bad_block").exists()
    good = {p: p.stat().st_mtime_ns for p in (out / "good").rglob("*") if p.is_file()}
    assert any(p.name == "cam_front.png" for p in good) and any(p.name == "meta.json" for p in good)

    bad["roadside"]["bridges"] = 0  # the scene fixed: the same command finishes the data set, and renders only it
    (tmp_path / "block.yaml").write_text(yaml.safe_dump(bad))
    r = generate()
    assert r.returncode == 0, r.stderr[-3000:]
    assert rendered() == [("bad_block", 0), ("good", 0)]
    assert {p: p.stat().st_mtime_ns for p in (out / "good").rglob("*") if p.is_file()} == good, "the finished scene is not redone"
    assert (out / "bad_block" / "000000" / "cam_front.png").is_file()
