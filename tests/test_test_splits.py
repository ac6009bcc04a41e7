"""The paper's test splits as many sampled scenes (configs/dataset/medium.yaml, demo.yaml), checked
with the generation planner, without rendering: enough scenes per split, each split's definition,
no seed shared with training, the held-out split unchanged, the render cost unchanged."""

from __future__ import annotations

import collections

import pytest
import yaml

from blender_scripts.build_scene import scene_rng
from blender_scripts.layouts import build_layout
from blender_scripts.traffic import ego_pose, place_traffic
from common.errors import ConfigError
from dataset_tools.generation.dataset_config import load_config
from dataset_tools.generation.driver import plan
from dataset_tools.generation.sampler import SAMPLE, sample_recipes

TEST_SPLITS = ("easy", "medium", "hard")
URBAN = {"urban_block", "intersection", "t_junction"}
LAYOUT_KEYS = ("family", "seed", "layout", "roadside")


def planned(path):
    cfg = load_config(path)
    jobs = plan(cfg, (0, 1))
    scenes = collections.defaultdict(list)
    for s in cfg["scenes"]:
        scenes[s["split"]].append(s["recipe"])
    return cfg, collections.Counter(s["split"] for s, _ in jobs), scenes


def check_splits(scenes, min_scenes: int, max_frames: int):
    train = scenes["train"]
    train_layouts = {r["seed"]: r for r in train}
    train_seeds = {v for r in train for v in (r["seed"], r["traffic"]["seed"])}
    for split in TEST_SPLITS:
        rs = scenes[split]
        assert len(rs) >= min_scenes, split
        assert all(r["frames"]["count"] <= max_frames for r in rs), split
        assert not {r["traffic"]["seed"] for r in rs} & train_seeds, split  # new traffic everywhere
    # easy: a training layout (the same family, seed, layout and roadside) under new weather and traffic
    for r in scenes["easy"]:
        base = train_layouts[r["seed"]]
        assert all(r[k] == base[k] for k in LAYOUT_KEYS), r["name"]
        assert r["weather"]["preset"] != base["weather"]["preset"], r["name"]
        assert r["ego"]["lane"] < r["layout"]["lanes_per_direction"]
    assert len({r["seed"] for r in scenes["easy"]}) >= min_scenes // 2  # several training layouts, not one
    # medium: unseen highways; hard: unseen urban layouts with junctions; neither shares a layout seed
    assert {r["family"] for r in scenes["medium"]} == {"highway"}
    assert {r["family"] for r in scenes["hard"]} == URBAN
    for split in ("medium", "hard", "heldout"):
        assert not {v for r in scenes[split] for v in (r["seed"], r["traffic"]["seed"])} & train_seeds, split
    # the test scenes of the three splits are different scenes
    keys = [(r["seed"], r["traffic"]["seed"]) for s in TEST_SPLITS for r in scenes[s]]
    assert len(set(keys)) == len(keys)
    # every easy and hard scene builds its layout, traffic and an ego route (numpy, what Blender runs)
    for r in scenes["easy"] + scenes["hard"][:3]:
        lay = build_layout(r, scene_rng(r["seed"], 1))
        place_traffic(lay, r, scene_rng(r["traffic"]["seed"], 3))
        assert all(abs(v) < 1e5 for v in ego_pose(lay, r, 0.5)), r["name"]


def test_medium_preset_plans_many_scenes_per_test_split_at_the_same_render_cost():
    cfg, frames, scenes = planned("configs/dataset/medium.yaml")
    check_splits(scenes, min_scenes=8, max_frames=4)
    assert {s: len(scenes[s]) for s in scenes} == {"train": 160, "easy": 10, "medium": 10, "hard": 10, "heldout": 16}
    # the frames rendered: 412 as before (the test splits were one scene of 20 frames each; the training
    # split 80 scenes of 4 frames until 2026-12-06), more scene builds
    assert frames == {"train": 320, "easy": 20, "medium": 20, "hard": 20, "heldout": 32}
    # training scenes: seed 1's block, 2 frames each (its first 80 the recipes of the 80 x 4 block); held-out as it was
    two = {"frames": 2, "rate_hz": 0.5, "rig_jitter": 1.0}
    assert scenes["train"] == sample_recipes(SAMPLE.validate({"count": 160, "seed": 1, **two}, "x"))
    old80 = sample_recipes(SAMPLE.validate({"count": 80, "seed": 1, **two, "frames": 4}, "x"))
    assert [{**r, "frames": {**r["frames"], "count": 2}} for r in old80] == scenes["train"][:80]
    assert scenes["heldout"] == sample_recipes(SAMPLE.validate({"count": 16, "seed": 1001, **two, "prefix": "heldout"}, "x"))
    assert all(r.get("rig_jitter") == 1.0 for s in TEST_SPLITS for r in scenes[s])


def test_demo_preset_keeps_its_size_with_sampled_test_splits():
    cfg, frames, scenes = planned("configs/dataset/demo.yaml")
    check_splits(scenes, min_scenes=4, max_frames=1)
    assert frames == {"train": 28, "easy": 4, "medium": 4, "hard": 4}
    assert len(scenes["train"]) == 7 and not any(s["sampled"] for s in cfg["scenes"] if s["split"] == "train")


def _config(tmp_path, scenes):
    path = tmp_path / "cfg.yaml"
    path.write_text(yaml.safe_dump({"rig": "configs/rigs/default.yaml", "scenes": scenes}))
    return path


def test_training_layouts_blocks(tmp_path):
    relit = {"sample": {"count": 6, "seed": 5, "training_layouts": True, "families": ["highway"]}, "split": "easy"}
    # the block may come before the training scenes it draws from; it draws only the families it names
    cfg = load_config(_config(tmp_path, [relit, {"sample": {"count": 30, "seed": 1}, "split": "train"}]))
    easy = [s for s in cfg["scenes"] if s["split"] == "easy"]
    assert [s["name"] for s in cfg["scenes"][:6]] == [f"s5_{k:04d}" for k in range(6)]
    assert {s["recipe"]["family"] for s in easy} == {"highway"} and all(s["training_layout"] for s in easy)
    assert load_config(_config(tmp_path, [relit, {"sample": {"count": 30, "seed": 1}, "split": "train"}]))["scenes"] == cfg["scenes"]
    for scenes, words in [
        ([{**relit, "split": "train"}], "only for a test split"),
        ([relit], "no training scene of the families"),
        ([relit, {"recipe": "scenes/urban_block.yaml"}], "no training scene of the families"),
        ([relit, {"sample": {"count": 30, "seed": 5}}], "already the seed"),
    ]:
        with pytest.raises(ConfigError, match=words):
            load_config(_config(tmp_path, scenes))
