"""The tolerance IoU of lane markings: a marking predicted within one cell counts."""

import math

import torch

from model.metrics import BevMetrics, iou_from_confusion, confusion, iou_from_tolerance, tolerance_counts
from model.inference import decode

NAMES = ["invalid", "vehicle", "lane_marking", "street", "background"]
MARK = 2


def scene():
    """A 12 x 12 street with a true marking line down column 5 (rows 1..10), all visible."""
    target = torch.full((12, 12), 3)
    target[1:11, 5] = MARK
    return target, torch.ones(12, 12)


def strict_iou(pred, target, vis):
    return float(iou_from_confusion(confusion(pred, target, vis))[MARK])


def test_a_line_one_cell_off_is_a_miss_strictly_and_a_hit_with_tolerance():
    target, vis = scene()
    pred = torch.full((12, 12), 3)
    pred[1:11, 6] = MARK
    assert strict_iou(pred, target, vis) == 0.0
    assert tolerance_counts(pred, target, vis, MARK).tolist() == [10, 0, 0]
    assert iou_from_tolerance(tolerance_counts(pred, target, vis, MARK)) == 1.0


def test_two_cells_off_is_a_miss_either_way():
    target, vis = scene()
    pred = torch.full((12, 12), 3)
    pred[1:11, 7] = MARK
    assert tolerance_counts(pred, target, vis, MARK).tolist() == [0, 10, 10]
    assert iou_from_tolerance(tolerance_counts(pred, target, vis, MARK)) == 0.0


def test_counts_of_a_partial_prediction_with_a_stray_cell():
    target, vis = scene()
    pred = torch.full((12, 12), 3)
    pred[1:5, 5] = MARK  # exact on rows 1..4
    pred[5, 4] = MARK  # diagonal neighbour of (6, 5) and beside (5, 5): within one cell
    pred[10, 10] = MARK  # far from the line: a false positive
    # TP 5; FP 1; FN: true cells with no prediction within one cell: rows 1..6 are covered
    # ((6, 5) by (5, 4)), rows 7..10 are not -> 4
    c = tolerance_counts(pred, target, vis, MARK)
    assert c.tolist() == [5, 1, 4]
    assert iou_from_tolerance(c) == 5 / 10
    assert strict_iou(pred, target, vis) == 4 / (6 + 10 - 4)  # never above the tolerance IoU


def test_invisible_and_invalid_cells_are_not_scored():
    target, vis = scene()
    vis[:, 6:] = 0.2  # the column a shifted line would sit in is not seen
    pred = torch.full((12, 12), 3)
    pred[1:11, 6] = MARK
    assert tolerance_counts(pred, target, vis, MARK).tolist() == [0, 0, 10]  # the predictions are unscored, the truth missed
    target[:, 5] = 0  # now the true line is invalid too: nothing to score
    c = tolerance_counts(pred, target, vis, MARK)
    assert c.tolist() == [0, 0, 0] and math.isnan(iou_from_tolerance(c))


def test_bev_metrics_report_it_beside_the_strict_iou_over_a_batch():
    target, vis = scene()
    pred = torch.full((12, 12), 3)
    pred[1:11, 6] = MARK
    logits = torch.nn.functional.one_hot(torch.stack([pred, target]) - 1, 4).permute(0, 3, 1, 2).float()
    m = BevMetrics(NAMES)
    m.update(decode({"semantic": logits, "occlusion": torch.full((2, 12, 12), 3.0)}),
             {"semantic": torch.stack([target, target]), "visibility": torch.stack([vis, vis])})
    res = m.compute()
    assert res["iou/lane_marking"] == 10 / 30  # the exact frame's 10 of 10 + 10 wrong + 10 missed
    assert res["iou_tol/lane_marking"] == 1.0
    assert "iou_tol/lane_marking" not in BevMetrics(["invalid", "vehicle", "street"]).compute()
