"""A tiny real render of a sampled scene (Blender): the recipe written into the data set renders
the same scene again alone; the ego car's body is in every camera's semantic pass (its own class,
its mask channel and PNG) and never in the top-down label passes, the labels or the visibility
counts; the scene's jittered rig round-trips through meta.json, the index, the reader and the lift."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from dataset_tools.format.exr import read_exr
from dataset_tools.format.layout import RECIPES_DIR, FrameFiles
from dataset_tools.format.meta import read_meta
from dataset_tools.format.passes import read_frame_passes
from dataset_tools.format.png import read_png
from dataset_tools.generation.recipe import load_recipe
from dataset_tools.labels import label_fusion
from dataset_tools.labels.classes import CLASS_IDS, DEFAULT_CLASS_MAP

ROOT = Path(__file__).resolve().parents[1]
EGO = CLASS_IDS["ego"]


def _config(path: Path, scenes) -> Path:
    path.write_text(yaml.safe_dump({
        "rig": "configs/rigs/default.yaml", "fisheye_size": [96, 60],
        "topdown": {"size": 64, "height_m": 60.0, "bound": 25.0},
        "render": {"samples": 1, "denoise": False, "max_bounces": 1}, "scenes": scenes}))
    return path


def _generate(config, out, *extra):
    r = subprocess.run([sys.executable, "-m", "dataset_tools", "generate", "--config", str(config), "--out", str(out),
                        "--no-progress", "--workers", "1", *extra], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]


@pytest.fixture(scope="module")
def sampled(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("sampled")
    cfg = _config(tmp / "cfg.yaml", [{"sample": {"count": 1, "seed": 5, "frames": 1, "rig_jitter": 1.0,
                                                 "families": ["urban_block"]}, "split": "train"}])
    _generate(cfg, tmp / "ds")
    r = subprocess.run([sys.executable, "-m", "dataset_tools", "fuse", str(tmp / "ds"), "--config", str(cfg)],
                       cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    return tmp / "ds"


def test_written_recipe_renders_the_scene_again_alone(sampled, tmp_path):
    meta = json.loads(FrameFiles(sampled / "s5_0000" / "000000").meta.read_text())
    path = sampled / RECIPES_DIR / "s5_0000.yaml"
    assert load_recipe(path) == meta["recipe"]
    _generate(_config(tmp_path / "again.yaml", [{"recipe": str(path)}]), tmp_path / "again")
    a = read_exr(FrameFiles(sampled / "s5_0000" / "000000").topdown)
    b = read_exr(FrameFiles(tmp_path / "again" / "s5_0000" / "000000").topdown)
    assert np.array_equal(a["ground.semantic"], b["ground.semantic"])
    assert json.loads(FrameFiles(tmp_path / "again" / "s5_0000" / "000000").meta.read_text())["rig"] == meta["rig"]


def test_ego_body_in_every_camera_never_in_labels_or_counts(sampled):
    files = FrameFiles(sampled / "s5_0000" / "000000")
    meta = read_meta(files.dir)
    box = meta.ego["box"]
    assert box[0] < box[1] and box[2] < box[3] and label_fusion.ego_box(meta, label_fusion.FusionConfig()) == tuple(box)
    for name in files.camera_names():
        ch = read_exr(files.camera_exr(name))
        ego = ch["semantic"] == EGO
        assert ego.mean() > 0.01, f"{name}: the ego body is not in the image"
        assert ego[-1].any(), f"{name}: no ego body on the bottom row"
        assert np.array_equal(ch["ego"] > 0.5, ego)
        assert np.array_equal(read_png(files.camera_ego_mask(name), np.uint8, 1) > 0, ego)
    td = read_exr(files.topdown)
    assert not (td["all.semantic"] == EGO).any() and not (td["ground.semantic"] == EGO).any()

    # labels: the ego class maps to invalid; its footprint is invalid; its pixels are never counted
    cfg = label_fusion.FusionConfig()
    assert DEFAULT_CLASS_MAP["ego"] == "invalid" and cfg.group_lut()[EGO] == 0
    meta, rig, cameras, topdown = read_frame_passes(files.dir)
    grid = meta.grid()
    out = label_fusion.fuse_passes(rig, cameras, topdown, grid, cfg, label_fusion.ego_box(meta, cfg))
    foot = label_fusion.ego_mask(grid, box)
    assert foot.any() and (out["semantic"][foot] == 0).all() and (out["visibility"][foot] == 0).all()
    from dataset_tools.labels.visibility import ray_tables

    tables = ray_tables(rig)
    for name, p in cameras.items():
        without = dict(p, distance=np.where(p["semantic"] == EGO, np.inf, p["distance"]).astype(np.float32))
        got, _ = label_fusion.camera_counts(tables[name], p, grid, cfg)
        ref, _ = label_fusion.camera_counts(tables[name], without, grid, cfg)
        assert np.array_equal(got, ref), name


def test_jittered_rig_round_trips_through_meta_index_reader_and_lift(sampled):
    import torch

    from blender_scripts.build_scene import scene_rng
    from dataset_tools.format.reader import DatasetIndex
    from geometry.rig import jitter_rig, load_rig, rig_from_dict
    from model import build_model
    from model.config import validate
    from model.data import BevDataset
    from model.frustum import Frustum

    meta = json.loads(FrameFiles(sampled / "s5_0000" / "000000").meta.read_text())
    nominal = load_rig(ROOT / "configs/rigs/default.yaml").map_cameras(lambda c: c.resized(96, 60))
    want = jitter_rig(nominal, scene_rng(meta["recipe"]["seed"], 6), 1.0)
    got = rig_from_dict(meta["rig"])
    for a, b in zip(want, got):
        assert np.allclose(a.cam_to_ego, b.cam_to_ego, atol=1e-9) and a.camera == b.camera
        n = nominal[a.name]
        assert 0 < np.abs(a.cam_to_ego[:3, 3] - n.cam_to_ego[:3, 3]).max() <= 0.03 + 1e-12
        assert a.camera.fx != n.camera.fx and abs(a.camera.fx / n.camera.fx - 1) <= 0.03 + 1e-12
    index = DatasetIndex(sampled)
    assert index.data["rig"] == meta["rig_nominal"] and index.data["rig"] != meta["rig"]
    (ref,) = index.frames("train")
    assert ref.own_rig
    cfg = validate({"data": {"input_size": [64, 40], "grid": {"bound": 25.0, "res": 50 / 64}},
                    "model": {"encoder": {"widths": [8, 16, 16], "blocks": [1, 1]}, "stride": 4, "context_channels": 8,
                              "depth": {"min": 1.0, "max": 30.0, "bins": 8}, "bev_encoder": {"widths": [8, 16, 16], "blocks": [1, 1]}}})
    sample = BevDataset(index, "train", cfg)[0]
    own_pc, own_intr = Frustum(got, cfg).nominal
    nom_pc, nom_intr = Frustum(index.rig, cfg).nominal
    assert torch.equal(sample["point_cell"], own_pc) and torch.equal(sample["intrinsics"], own_intr)
    assert not torch.equal(own_pc, nom_pc) and not torch.equal(own_intr, nom_intr)
    model = build_model(cfg, index.rig).eval()
    with torch.no_grad():
        own = model(sample["images"][None], sample["point_cell"][None], sample["intrinsics"][None])["semantic"]
        nom = model(sample["images"][None])["semantic"]
    assert own.shape == nom.shape and not torch.allclose(own, nom)


def test_photo_quality_draws_the_camera_effects_per_camera(sampled):
    from dataset_tools.generation.sensor import EFFECTS

    meta = json.loads(FrameFiles(sampled / "s5_0000" / "000000").meta.read_text())
    assert meta["render"]["quality"] == "photo"
    assert set(meta["sensor"]) == {"front", "left", "rear", "right"}
    on = {e for e in EFFECTS if meta["render"]["sensor"][e]}
    assert "noise" in on and "jpeg" not in on
    for params in meta["sensor"].values():
        assert "vignetting" in params and "shot_gain" in params and "jpeg_quality" not in params
    assert meta["sensor"]["front"] != meta["sensor"]["rear"]
