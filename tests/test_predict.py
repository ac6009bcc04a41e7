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
        np.testing.assert_array_equal(ours["semantic"], theirs["semantic"])
        np.testing.assert_array_equal(ours["occlusion_logit"], theirs["occlusion_logit"])
        assert (tmp_path / "pred" / f"{ref.dir.name}.png").stat().st_size > 10_000

    # real images through an imported rig (cv2.fisheye cameras, 960x640, another mount): runs, writes both files
    _run("predict.py", "--checkpoint", ckpt, "--frames", SV, "--rig", SV / "rig.yaml", "--out", tmp_path / "real")
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
    import predict
    from geometry.rig import load_rig

    rig = load_rig(SV / "rig.yaml")
    half = predict.rig_of_images(rig, {n: np.zeros((320, 480, 3), np.uint8) for n in rig.names})
    for n in rig.names:
        a, b = rig[n].camera, half[n].camera
        assert (b.width, b.height) == (480, 320) and b.fx == a.fx / 2 and b.cx == (a.cx + 0.5) / 2 - 0.5 and b.k == a.k
        np.testing.assert_array_equal(half[n].cam_to_ego, rig[n].cam_to_ego)
    same = predict.rig_of_images(rig, {n: np.zeros((640, 960, 3), np.uint8) for n in rig.names})
    assert same.to_dict() == rig.to_dict()
