"""The evaluation protocol (model.evaluation): IoU on constructed cases, and eval.py end to end on a trained checkpoint."""

import json
import math

import numpy as np
import pytest
import torch

from geometry.bev import BevGrid
from model import evaluation
from model.eval_report import markdown_table

NAMES = ["invalid", "vehicle", "lane_marking", "street", "background"]
GRID = BevGrid(x_min=-4, x_max=4, y_min=-4, y_max=4, res=1.0)  # 8 x 8


def scores_of(pred, truth, vis, occ_logit=None, scene="s0", s=None):
    s = s or evaluation.SplitScores(NAMES, GRID)
    pred, truth, vis = (torch.as_tensor(np.asarray(a)) for a in (pred, truth, vis))
    occ = torch.as_tensor(occ_logit) if occ_logit is not None else torch.where(vis >= 0.5, 5.0, -5.0)
    s.add_frame(pred, occ, truth, vis, "clear_noon", scene)
    return s.result()


def layout():
    truth = np.full((8, 8), 3)
    truth[:, :2] = 4
    truth[2:4, 3:5] = 1
    truth[:, 6] = 2
    return truth


def test_perfect_prediction_scores_one():
    truth = layout()
    r = scores_of(truth, truth, np.ones((8, 8), np.float32))["overall"]
    for n in NAMES[1:]:
        assert r[f"iou/{n}"] == 1.0
    assert math.isnan(r["iou/occlusion"])  # nothing occluded in truth or prediction
    assert r["miou"] == 1.0  # an undefined IoU is left out of the mean, not counted as 0
    vis = np.ones((8, 8), np.float32)
    vis[0] = 0.2
    r = scores_of(truth, truth, vis)["overall"]
    assert r["iou/occlusion"] == 1.0 and r["miou"] == 1.0


def test_absent_class_is_nan_and_left_out_of_miou():
    truth = layout()
    truth[truth == 1] = 3  # no vehicle anywhere
    vis = np.ones((8, 8), np.float32)
    vis[0] = 0.0
    pred = truth.copy()
    pred[5, 2:6] = 4  # 4 street cells predicted background
    r = scores_of(pred, truth, vis)["overall"]
    assert math.isnan(r["iou/vehicle"])
    street, background = 31 / 35, 14 / 18  # 35 visible street cells, 14 visible background
    assert r["iou/street"] == pytest.approx(street) and r["iou/background"] == pytest.approx(background)
    assert r["miou"] == pytest.approx((1 + 1 + street + background) / 4)  # occlusion, markings, street, background
    pred[1, 3] = 1  # a vehicle predicted (on a visible cell) where there is none: now vehicle IoU is 0 and counts
    r = scores_of(pred, truth, vis)["overall"]
    assert r["iou/vehicle"] == 0.0 and r["miou"] < (1 + 1 + street + background) / 4 * 0.85


def test_invalid_and_invisible_cells_are_ignored():
    truth = layout()
    vis = np.ones((8, 8), np.float32)
    pred = truth.copy()
    truth[7, :] = 0  # invalid truth: whatever is predicted there is not scored
    pred[7, :] = 1
    vis[:, 5] = 0.49  # invisible: wrong predictions there are not scored
    pred[:, 5] = 1
    r = scores_of(pred, truth, vis)
    assert r["overall"]["iou/vehicle"] == 1.0 and r["overall"]["iou/street"] == 1.0
    cm = np.array(r["confusion"])
    assert cm[0].sum() == 0 and cm.sum() == 8 * 8 - 8 - 7
    # one wrong visible cell changes the scores: the filter is not hiding everything
    pred[3, 0] = 1
    r = scores_of(pred, truth, vis)["overall"]
    assert r["iou/vehicle"] == pytest.approx(4 / 5) and r["iou/background"] == pytest.approx(13 / 14)


def test_occlusion_iou_and_distance_bands():
    truth = layout()
    vis = np.ones((8, 8), np.float32)
    vis[:2] = 0.0  # truly occluded: rows 0-1
    occ_logit = np.full((8, 8), 5.0, np.float32)
    occ_logit[:3] = -5.0  # predicted occluded: rows 0-2
    r = scores_of(truth, truth, vis, occ_logit)
    assert r["overall"]["iou/occlusion"] == pytest.approx(16 / 24)
    bands = r["bands"]
    assert list(bands) == ["0-10 m", "10-20 m", "20-25 m"]
    assert bands["0-10 m"]["iou/street"] == 1.0 and math.isnan(bands["20-25 m"]["iou/street"])
    assert list(r["weather"]) == ["clear_noon"]


def test_scores_keep_one_confusion_per_scene_and_an_interval_over_scenes():
    """Two scenes of two frames each: per-scene matrices sum to the split's; the interval of a
    two-scene split runs from one scene's IoU to the other's (tests/test_bootstrap.py)."""
    truth, vis = layout(), np.ones((8, 8), np.float32)
    worse = truth.copy()
    worse[2:4, 3:5] = 3  # every vehicle cell predicted street
    half = truth.copy()
    half[2:4, 3] = 3  # half of them
    s = evaluation.SplitScores(NAMES, GRID)
    for scene, pred in (("a", truth), ("a", truth), ("b", half), ("b", worse)):
        r = scores_of(pred, truth, vis, scene=scene, s=s)
    assert list(r["scenes"]) == ["a", "b"]
    assert (np.sum([v["confusion"] for v in r["scenes"].values()], 0) == np.array(r["confusion"])).all()
    assert np.array(r["scenes"]["a"]["confusion"]).sum() == 2 * 64
    assert r["overall"]["iou/vehicle"] == pytest.approx(10 / 16)
    assert r["interval"]["iou/vehicle"] == [pytest.approx(2 / 8), 1.0]  # scene b alone: 2 of 8; scene a: 8 of 8
    assert r["interval"]["iou/lane_marking"] == [1.0, 1.0]


def test_table_has_the_papers_columns_and_intervals():
    truth = layout()
    res = {"easy": scores_of(truth, truth, np.ones((8, 8), np.float32))}
    table = markdown_table(res, "ours")
    assert table.splitlines()[0] == "| Method | Image type | Dataset | Scenes | mIoU | Occlusions | Vehicles | Markings | Street | Background |"
    assert "| ours | Raw distorted | easy | 1 | 1.000 [1.000, 1.000] | - | 1.000 [1.000, 1.000] |" in table
    assert "95 % interval of a bootstrap over the split's scenes" in table


def test_eval_of_a_trained_checkpoint_equals_a_recomputation_from_its_predictions(tiny_dataset, tmp_path):
    """eval.py on a checkpoint trained on real tiny renders; its JSON against an independent
    recomputation (numpy bincount) from the predictions it saved and the label files."""
    import subprocess
    import sys

    from dataset_tools.format.reader import DatasetIndex, downsample_labels, read_frame
    from test_train import label_grid, run_train, write_config

    cfg = write_config(tmp_path / "c.yaml", tiny_dataset, train={"max_steps": 6}, augment={"enabled": False},
                       data={"grid": label_grid(tiny_dataset)})
    run_train(cfg, tmp_path / "run")
    out = tmp_path / "eval"
    r = subprocess.run([sys.executable, "eval.py", "--checkpoint", str(tmp_path / "run" / "latest.pt"), "--split", "all",
                        "--out", str(out), "--save-predictions", "--pictures", "2", "--threads", "1"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "| Method | Image type | Dataset |" in r.stdout
    report = json.loads((out / "metrics.json").read_text())
    assert list(report["splits"]) == ["train"]  # the tiny preset has only training scenes
    res = report["splits"]["train"]
    assert len(list(out.glob("frame_train_*.png"))) == 2 and (out / "confusion_train.png").is_file()
    assert res["inference_ms_per_frame"] > 0

    idx = DatasetIndex(tiny_dataset)
    cm, occ = np.zeros((5, 5), np.int64), np.zeros((2, 2), np.int64)
    refs = idx.frames("train")
    assert res["frames"] == len(refs)
    for ref in refs:
        p = np.load(out / "predictions" / f"{ref.scene}_{ref.frame:06d}.npz")
        f = read_frame(ref)
        sem, vis = f["semantic"].astype(np.int64), f["visibility"]
        if p["semantic"].shape != sem.shape:
            sem, vis = downsample_labels(f["semantic"], vis, sem.shape[0] // p["semantic"].shape[0])
        keep = (sem > 0) & (vis >= 0.5)
        cm += np.bincount(sem[keep] * 5 + p["semantic"][keep], minlength=25).reshape(5, 5)
        occ += np.bincount((vis < 0.5).ravel() * 2 + (p["occlusion_logit"] < 0).ravel(), minlength=4).reshape(2, 2)
    assert res["confusion"] == cm.tolist() and res["occlusion_confusion"] == occ.tolist()
    ious = {}
    for i, n in enumerate(NAMES[1:], 1):
        union = cm[i].sum() + cm[:, i].sum() - cm[i, i]
        ious[n] = cm[i, i] / union if union else float("nan")
    ious["occlusion"] = occ[1, 1] / (occ[1].sum() + occ[:, 1].sum() - occ[1, 1])
    for n, v in ious.items():
        assert res["overall"][f"iou/{n}"] == pytest.approx(v, nan_ok=True), n
    assert res["overall"]["miou"] == pytest.approx(np.nanmean(list(ious.values())))

    # every split carries its scenes' matrices and a 95 % interval of each score
    assert sorted(res["scenes"]) == sorted({ref.scene for ref in refs}) and len(res["scenes"]) == 7
    assert (np.sum([v["confusion"] for v in res["scenes"].values()], 0) == cm).all()
    for key, (low, high) in res["interval"].items():
        assert low <= high, key
    assert "| train | 7 | " in (out / "table.md").read_text()

    # --compare of a checkpoint with itself: the same frames scored twice, a difference of exactly 0
    cmp_out = tmp_path / "cmp"
    r = subprocess.run([sys.executable, "eval.py", "--compare", str(tmp_path / "run"), str(tmp_path / "run" / "latest.pt"),
                        "--out", str(cmp_out), "--threads", "1"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    cmp = json.loads((cmp_out / "comparison.json").read_text())
    diff = cmp["splits"]["train"]["difference"]
    # every score but the markings' tolerance IoU, which has no per-scene confusion to pair
    assert cmp["splits"]["train"]["scenes"] == 7 and set(diff) == set(res["overall"]) - {"iou_tol/lane_marking"}
    for key, d in diff.items():
        assert d["diff"] == 0.0 and d["low"] == 0.0 and d["high"] == 0.0, key
        assert d["a"] == pytest.approx(res["overall"][key], nan_ok=True), key
    assert "| train | 7 | mIoU |" in r.stdout and "| +0.000 | [+0.000, +0.000] | undecided |" in r.stdout
    assert (cmp_out / "a" / "confusion_train.png").is_file() and (cmp_out / "b" / "confusion_train.png").is_file()

    # --precision bf16 fp32: the same checkpoint in bf16 against fp32 (model.precision), recorded per side
    r = subprocess.run([sys.executable, "eval.py", "--compare", str(tmp_path / "run"), str(tmp_path / "run"), "--precision", "bf16", "fp32",
                        "--out", str(tmp_path / "cmp16"), "--threads", "1"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    cmp = json.loads((tmp_path / "cmp16" / "comparison.json").read_text())
    assert (cmp["a"]["precision"], cmp["b"]["precision"]) == ("bf16", "fp32")
    assert cmp["splits"]["train"]["b"]["overall"] == pytest.approx(res["overall"], nan_ok=True)  # B is the fp32 eval
    assert abs(cmp["splits"]["train"]["difference"]["miou"]["diff"]) < 0.1  # rounding, not another model

    # a run folder stands for its latest.pt; the output goes to the run's eval/ by default
    r = subprocess.run([sys.executable, "eval.py", "--checkpoint", str(tmp_path / "run"), "--split", "train", "--pictures", "0",
                        "--threads", "1"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    again = json.loads((tmp_path / "run" / "eval" / "metrics.json").read_text())
    assert again["checkpoint"] == str(tmp_path / "run" / "latest.pt") and again["splits"]["train"]["confusion"] == res["confusion"]

    # bad input: one line naming the problem, exit 2, no traceback
    ckpt = str(tmp_path / "run" / "latest.pt")
    garbage = tmp_path / "garbage.pt"
    garbage.write_text("not a checkpoint")
    for args, message in [
        (["--checkpoint", str(tmp_path / "missing.pt")], "missing.pt: no such checkpoint"),
        (["--checkpoint", str(garbage)], "garbage.pt: not a readable checkpoint"),
        (["--checkpoint", ckpt, "--split", "hard"], "split 'hard' has no frames"),
        (["--checkpoint", ckpt, "--config", "configs/train/pool_max.yaml"], "checkpoint is from another config"),
        (["--checkpoint", ckpt, "--bogus"], "eval.py: unrecognized arguments: --bogus"),
        (["--compare", ckpt, str(tmp_path / "missing.pt")], "missing.pt: no such checkpoint"),
        (["--compare", ckpt, ckpt, "--split", "hard"], "split 'hard' has no frames"),
        (["--compare", ckpt, ckpt, "--checkpoint", ckpt], "argument --checkpoint: not allowed with argument --compare"),
        (["--compare", ckpt], "argument --compare: expected 2 arguments"),
        (["--checkpoint", ckpt, "--precision", "bf16", "fp32"], "--precision: one value, got 2"),
        (["--checkpoint", ckpt, "--precision", "fp16"], "argument --precision: invalid choice: 'fp16'"),
    ]:
        r = subprocess.run([sys.executable, "eval.py", "--out", str(tmp_path / "bad"), *args], capture_output=True, text=True, timeout=300)
        assert r.returncode == 2, (args, r.stderr)
        assert message in r.stderr and len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr, r.stderr


def test_eval_says_once_what_each_camera_of_the_checkpoints_rig_is(tmp_path):
    """eval.py prints, once at start, what each camera of the checkpoint's rig became (Rig.describe);
    --compare for each of A and B."""
    import subprocess
    import sys

    from test_train import rig_lines, toy_rig_run

    root, run, _ = toy_rig_run(tmp_path)
    ckpt = run / "latest.pt"
    r = subprocess.run([sys.executable, "eval.py", "--checkpoint", str(run), "--split", "train", "--out", str(tmp_path / "eval"),
                        "--pictures", "0", "--threads", "1"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    rig_lines(r.stdout, ckpt)
    assert r.stdout.index("rig ") < r.stdout.index("| Method |"), "at start, before the scores"
    r = subprocess.run([sys.executable, "eval.py", "--compare", str(run), str(ckpt), "--split", "train", "--out", str(tmp_path / "cmp"),
                        "--threads", "1"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    lines = [ln for ln in r.stdout.splitlines() if ln.startswith("rig ")]
    rig_lines("\n".join(lines[:4]), ckpt)
    rig_lines("\n".join(lines[4:]), ckpt)
