"""predict.py: on a rendered frame it computes exactly what eval.py computes; on the real surround-view
images (another rig than the training rig, another camera model) it writes its prediction and picture."""

import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SV = Path(__file__).parent / "data" / "surround_view"


def _trained(tiny_dataset, tmp_path):
    from test_train import label_grid, run_train, write_config

    cfg = write_config(tmp_path / "c.yaml", tiny_dataset, train={"max_steps": 4}, augment={"enabled": False},
                       data={"grid": label_grid(tiny_dataset)})
    run_train(cfg, tmp_path / "run")
    return tmp_path / "run" / "latest.pt"


def _run(*args):
    r = subprocess.run([sys.executable, *map(str, args)], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    return r


def test_predict_equals_eval_on_rendered_frames_and_runs_on_real_images(tiny_dataset, tmp_path):
    from dataset_tools.format.reader import DatasetIndex

    ckpt = _trained(tiny_dataset, tmp_path)
    _run("eval.py", "--checkpoint", ckpt, "--split", "all", "--out", tmp_path / "eval", "--save-predictions", "--pictures", "0",
         "--threads", "1")
    refs = DatasetIndex(tiny_dataset).frames("train")
    scene = refs[0].dir.parent  # a folder of frame folders, each with its meta.json rig
    _run("predict.py", "--checkpoint", ckpt, "--frames", scene, "--out", tmp_path / "pred", "--threads", "1")
    for ref in (r for r in refs if r.dir.parent == scene):
        ours = np.load(tmp_path / "pred" / f"{ref.dir.name}.npz")
        theirs = np.load(tmp_path / "eval" / "predictions" / f"{ref.scene}_{ref.frame:06d}.npz")
        assert sorted(ours.files) == sorted(theirs.files) == ["occlusion_logit", "semantic", "visibility"], "one format"
        for k in ours.files:
            np.testing.assert_array_equal(ours[k], theirs[k])
        assert (tmp_path / "pred" / f"{ref.dir.name}.png").stat().st_size > 10_000

    # one rendered frame folder is one frame (its labels/ folder was taken for a frame)
    one = _run("predict.py", "--checkpoint", ckpt, "--frames", refs[0].dir, "--out", tmp_path / "one", "--threads", "1")
    assert sorted(q.name for q in (tmp_path / "one").iterdir()) == [f"{refs[0].dir.name}.npz", f"{refs[0].dir.name}.png"]
    ours = np.load(tmp_path / "one" / f"{refs[0].dir.name}.npz")
    theirs = np.load(tmp_path / "eval" / "predictions" / f"{refs[0].scene}_{refs[0].frame:06d}.npz")
    np.testing.assert_array_equal(ours["semantic"], theirs["semantic"])
    assert "front: opencv_fisheye (exact, given inline)" in one.stdout  # what each camera became, once
    assert one.stdout.count("front:") == 1

    # real images through an imported rig (cv2.fisheye cameras, 960x640, another mount): runs, writes both
    # files; its cameras are named front, back, left, right: --cameras puts them in the model's order
    r = subprocess.run([sys.executable, "predict.py", "--checkpoint", ckpt, "--frames", SV, "--rig", SV / "rig.yaml",
                        "--out", tmp_path / "real"], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert r.returncode == 2 and "--rig" in r.stderr and "rig.yaml" in r.stderr and "--cameras" in r.stderr, r.stderr
    r = _run("predict.py", "--checkpoint", ckpt, "--frames", SV, "--rig", SV / "rig.yaml", "--out", tmp_path / "real",
             "--cameras", "front,left,back,right")
    assert "back: opencv_fisheye (exact) from back.yaml" in r.stdout
    p = np.load(tmp_path / "real" / "surround_view.npz")
    assert p["semantic"].shape == p["visibility"].shape and p["semantic"].min() >= 1
    assert ((p["visibility"] >= 0) & (p["visibility"] <= 1)).all()
    assert (tmp_path / "real" / "surround_view.png").is_file()


def test_predict_bad_input_is_one_line(tmp_path):
    r = subprocess.run([sys.executable, "predict.py", "--checkpoint", tmp_path / "none.pt", "--frames", SV, "--rig", SV / "rig.yaml",
                        "--out", tmp_path / "o"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode != 0 and "none.pt" in r.stderr and "Traceback" not in r.stderr
    r = subprocess.run([sys.executable, "predict.py", "--checkpoint", tmp_path / "none.pt", "--frames", tmp_path / "nothing",
                        "--out", tmp_path / "o"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode != 0 and "nothing: no such folder" in r.stderr and "Traceback" not in r.stderr


def test_images_of_another_size_bring_their_camera():
    from dataset_tools.stitch import rig_of_images
    from geometry.rig import load_rig

    rig = load_rig(SV / "rig.yaml")
    half = rig_of_images(rig, {n: np.zeros((320, 480, 3), np.uint8) for n in rig.names})
    for n in rig.names:
        a, b = rig[n].camera, half[n].camera
        assert (b.width, b.height) == (480, 320) and b.fx == a.fx / 2 and b.cx == (a.cx + 0.5) / 2 - 0.5 and b.k == a.k
        np.testing.assert_array_equal(half[n].cam_to_ego, rig[n].cam_to_ego)
    same = rig_of_images(rig, {n: np.zeros((640, 960, 3), np.uint8) for n in rig.names})
    assert same.to_dict() == rig.to_dict()


def test_cameras_are_matched_by_name_for_a_pooling_with_per_camera_parameters(tiny_dataset, tmp_path):
    """The README listed the cameras front, rear, left, right, training used front, left,
    rear, right, and predict matched them by position: with weighted_sum pooling (a learned W_i per
    camera, the paper's eq. 2) rear and left would swap silently. Now they are matched by name."""
    import torch

    from dataset_tools.format.reader import DatasetIndex
    from dataset_tools.stitch import read_images
    from geometry.rig import Rig
    from model.checkpoint import build_model
    from model.config import load_config
    from model.inference import PredictError, RigModel
    from test_train import label_grid, write_config

    index = DatasetIndex(tiny_dataset)
    cfg = load_config(write_config(tmp_path / "c.yaml", tiny_dataset, model={"pooling": "weighted_sum"},
                                   data={"grid": label_grid(tiny_dataset)}))
    rig = index.rig
    assert rig.names == ["front", "left", "rear", "right"]
    torch.manual_seed(0)
    model = build_model(cfg, rig)
    with torch.no_grad():  # make each camera's weights its own
        for i in range(len(rig)):
            model.pool.weight[i].mul_(0.25 + 0.5 * i)
    images = read_images(index.frames("train")[0].dir, rig.names)
    want = RigModel(model, cfg, rig.to_dict(), rig)(images).occlusion_logit
    listed = Rig([rig[n] for n in ("front", "rear", "left", "right")], rig.name)  # a rig file in the README's old order
    got = RigModel(model, cfg, rig.to_dict(), listed)(images).occlusion_logit
    torch.testing.assert_close(got, want, rtol=0, atol=0)
    # matching by position (the old behaviour, now only what an explicit --cameras asks for) differs
    swapped = RigModel(model, cfg, rig.to_dict(), listed, cameras=["front", "rear", "left", "right"])(images).occlusion_logit
    assert (swapped - want).abs().max() > 1e-3
    # a rig of 3 cameras is refused naming the option and file
    import pytest

    three = Rig([rig[n] for n in ("front", "left", "rear")], "mine")
    with pytest.raises(PredictError, match=r"--rig my.yaml: 3 cameras \(front, left, rear\), the model was trained with 4"):
        RigModel(model, cfg, rig.to_dict(), three, "--rig my.yaml")


def test_a_frame_of_another_tool_with_sub_folders_is_one_frame(tmp_path):
    """A frame as another simulator writes it (an image per camera, and a depth/ sub-folder of
    images of the same names) given with --rig was taken for a folder of frames: predict.py ran on
    depth/ alone, exit 0. It is one frame; its missing camera image is named."""
    import json
    import shutil

    import yaml

    from test_train import toy_rig_run

    root, run, _ = toy_rig_run(tmp_path)
    src = root / "toy" / "000000"
    rig = tmp_path / "rig.yaml"
    rig.write_text(yaml.safe_dump({"name": "theirs", "cameras": json.loads((src / "meta.json").read_text())["rig"]["cameras"]}))
    frame, plain = tmp_path / "sim" / "f12", tmp_path / "plain" / "f12"
    for d in (frame / "depth", plain):
        d.mkdir(parents=True)
    for cam in ("front", "left", "rear", "right"):
        for d in (frame, plain):
            shutil.copy(src / f"cam_{cam}.png", d / f"{cam}.png")
        shutil.copy(src / "labels" / "semantic.png", frame / "depth" / f"{cam}.png")  # images, but not these cameras'
    for d in (frame, plain):
        _run("predict.py", "--checkpoint", run / "latest.pt", "--frames", d, "--rig", rig, "--out", d.parent / "out", "--threads", "1",
             "--no-pictures")
    assert [p.name for p in (frame.parent / "out").iterdir()] == ["f12.npz"]
    ours, theirs = np.load(frame.parent / "out" / "f12.npz"), np.load(plain.parent / "out" / "f12.npz")
    for k in ours.files:
        np.testing.assert_array_equal(ours[k], theirs[k])
    (frame / "rear.png").unlink()
    r = subprocess.run([sys.executable, "predict.py", "--checkpoint", run / "latest.pt", "--frames", frame, "--rig", rig,
                        "--out", tmp_path / "x"], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and f"{frame}: no image for camera 'rear'" in r.stderr, r.stderr
