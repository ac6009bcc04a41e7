"""The evaluation protocol: IoU on constructed cases, and eval.py end to end on a trained checkpoint."""

import json
import math

import numpy as np
import pytest
import torch

import eval as evaluation
from geometry.bev import BevGrid

NAMES = ["invalid", "vehicle", "lane_marking", "street", "background"]
GRID = BevGrid(x_min=-4, x_max=4, y_min=-4, y_max=4, res=1.0)  # 8 x 8


def scores_of(pred, truth, vis, occ_logit=None):
    s = evaluation.SplitScores(NAMES, GRID)
    pred, truth, vis = (torch.as_tensor(np.asarray(a)) for a in (pred, truth, vis))
    occ = torch.as_tensor(occ_logit) if occ_logit is not None else torch.where(vis >= 0.5, 5.0, -5.0)
    s.update(pred, occ, truth, vis, "clear_noon")
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
    vis = np.ones((8, 8), np.float32)
    vis[0] = 0.2
    r = scores_of(truth, truth, vis)["overall"]
    assert r["iou/occlusion"] == 1.0 and r["miou"] == 1.0


def test_absent_class_is_nan_and_counts_zero_in_miou():
    truth = layout()
    truth[truth == 1] = 3  # no vehicle anywhere
    vis = np.ones((8, 8), np.float32)
    vis[0] = 0.0
    r = scores_of(truth, truth, vis)["overall"]
    assert math.isnan(r["iou/vehicle"])
    assert r["miou"] == pytest.approx(4 / 5)  # the paper's mean over five: an absent class adds 0


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


def test_table_has_the_papers_columns():
    truth = layout()
    res = {"easy": scores_of(truth, truth, np.ones((8, 8), np.float32))}
    table = evaluation.markdown_table(res, "ours")
    assert table.splitlines()[0] == "| Method | Image type | Dataset | mIoU | Occlusions | Vehicles | Markings | Street | Background |"
    assert "| ours | Raw distorted | easy | " in table
