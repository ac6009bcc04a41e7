"""The bootstrap over scenes (model.bootstrap) on constructed splits whose answer is known by hand."""

import numpy as np
import pytest
import torch

from model import bootstrap
from model.metrics import BevMetrics

NAMES = ["invalid", "vehicle", "lane_marking", "street", "background"]


def scene(tp_vehicle, fn_vehicle, street=100, background=50, markings=10, occ=(80, 5, 5, 10)):
    """One scene's confusion pair: vehicles found tp of tp + fn (the missed ones predicted street)."""
    cm = np.zeros((5, 5), np.int64)
    cm[1, 1], cm[1, 3] = tp_vehicle, fn_vehicle
    cm[2, 2], cm[3, 3], cm[4, 4] = markings, street, background
    return cm, np.array(occ, np.int64).reshape(2, 2)


def stack(*scenes):
    return np.stack([c for c, _ in scenes]), np.stack([o for _, o in scenes])


def test_scores_are_the_protocols():
    """The batched numpy scores equal model.metrics.BevMetrics on the same confusions."""
    cm, occ = scene(30, 10)
    cm[3, 4], cm[0, 0] = 7, 99  # some street predicted background; invalid counts are never scored
    m = BevMetrics(NAMES)
    m.merge_(torch.from_numpy(cm), torch.from_numpy(occ))
    ref = m.compute()
    got = bootstrap.scores(cm, occ, NAMES)
    # the markings' tolerance IoU needs the maps' neighbourhoods, not confusions: it has no interval
    ref.pop("iou_tol/lane_marking")
    assert set(got) == set(ref)
    for k, v in ref.items():
        assert float(got[k]) == pytest.approx(v), k
    cm[1] = 0  # vehicle absent from truth and prediction: NaN, left out of mIoU as BevMetrics does
    m.reset()
    m.merge_(torch.from_numpy(cm), torch.from_numpy(occ))
    assert np.isnan(bootstrap.scores(cm, occ, NAMES)["iou/vehicle"])
    assert float(bootstrap.scores(cm, occ, NAMES)["miou"]) == pytest.approx(m.compute()["miou"])


def test_identical_scenes_give_a_zero_width_interval():
    cms, occs = stack(*[scene(30, 10)] * 6)
    iv = bootstrap.scene_bootstrap(cms, occs, NAMES)
    assert iv["iou/vehicle"] == (0.75, 0.75)
    for key, (low, high) in iv.items():
        assert low == high, key


def test_two_scenes_give_the_hand_computed_interval():
    """Two scenes: a resample is AA (1/4), AB or BA (1/2) or BB (1/4), so the 2.5 % and 97.5 %
    quantiles are exactly the two scenes' own IoUs."""
    a, b = scene(30, 10), scene(10, 30)  # vehicle IoU 0.75 and 0.25; pooled 0.5
    iv = bootstrap.scene_bootstrap(*stack(a, b), NAMES)
    assert iv["iou/vehicle"] == (0.25, 0.75)
    miou_a, miou_b = (float(bootstrap.scores(*s, NAMES)["miou"]) for s in (a, b))
    assert iv["miou"] == (pytest.approx(miou_b), pytest.approx(miou_a))
    assert iv["iou/street"][0] < iv["iou/street"][1]  # the missed vehicles land on street
    assert iv["iou/background"] == (1.0, 1.0)
    # deterministic in its seed; another seed gives the same here (the quantiles are atoms)
    assert bootstrap.scene_bootstrap(*stack(a, b), NAMES) == iv
    assert bootstrap.scene_bootstrap(*stack(a, b), NAMES, seed=5)["iou/vehicle"] == (0.25, 0.75)


def test_resamples_draw_scenes_with_replacement():
    counts = bootstrap.resample_counts(4, n=2000, seed=1)
    assert counts.shape == (2000, 4) and (counts.sum(1) == 4).all()
    assert (counts == 0).any() and (counts >= 2).any()
    assert abs(counts.mean() - 1.0) < 0.05
    assert (bootstrap.resample_counts(4, n=2000, seed=1) == counts).all()


def test_paired_difference_of_a_run_with_itself_is_exactly_zero():
    cms, occs = stack(scene(30, 10), scene(10, 30), scene(5, 5))
    d = bootstrap.paired_bootstrap((cms, occs), (cms, occs), NAMES)
    for key, v in d.items():
        assert v["diff"] == 0.0 and v["low"] == 0.0 and v["high"] == 0.0, key


def test_paired_difference_pairs_the_scenes():
    """B misses two more vehicles than A in every scene. Unpaired, the scenes' spread (IoU 0.25 -
    0.75) would swamp that; paired, every resample has A ahead, so the interval excludes 0."""
    a = stack(scene(30, 10), scene(10, 30), scene(20, 20))
    b = stack(scene(28, 12), scene(8, 32), scene(18, 22))
    d = bootstrap.paired_bootstrap(a, b, NAMES)["iou/vehicle"]
    assert d["a"] == pytest.approx(0.5) and d["b"] == pytest.approx(0.45) and d["diff"] == pytest.approx(0.05)
    assert 0 < d["low"] <= d["diff"] <= d["high"] < 0.1
    assert bootstrap.scene_bootstrap(*a, NAMES)["iou/vehicle"][0] < 0.45  # each alone: intervals overlap
    with pytest.raises(ValueError, match="not scored on the same scenes"):
        bootstrap.paired_bootstrap(a, stack(scene(1, 1)), NAMES)


def test_runs_bootstrap_over_seeds_and_scenes():
    one = stack(scene(30, 10), scene(10, 30))
    r = bootstrap.runs_bootstrap([one], NAMES)
    assert (r["iou/vehicle"]["low"], r["iou/vehicle"]["high"]) == bootstrap.scene_bootstrap(*one, NAMES)["iou/vehicle"]
    # two seeds, identical scenes within each: the spread is the seeds' (0.75 and 0.25)
    s1, s2 = stack(*[scene(30, 10)] * 3), stack(*[scene(10, 30)] * 3)
    r = bootstrap.runs_bootstrap([s1, s2], NAMES)["iou/vehicle"]
    assert r["mean"] == pytest.approx(0.5) and (r["low"], r["high"]) == (0.25, 0.75)
    d = bootstrap.paired_runs_bootstrap([s1, s2], [s1, s2], NAMES)["iou/vehicle"]
    assert d["diff"] == 0.0 and d["low"] == -0.5 and d["high"] == 0.5  # seeds are drawn apart for A and B


def test_paired_seeds_share_a_seeds_luck():
    """Seed 1 is lucky for both rows (vehicle IoU 0.75 against 0.25), and A is 0.05 ahead at each
    seed. Drawn apart, the seeds' spread swamps the 0.05; paired, every resample has A ahead."""
    a1, a2 = stack(*[scene(30, 10)] * 3), stack(*[scene(12, 28)] * 3)  # 0.75, 0.30
    b1, b2 = stack(*[scene(28, 12)] * 3), stack(*[scene(10, 30)] * 3)  # 0.70, 0.25
    apart = bootstrap.paired_runs_bootstrap([a1, a2], [b1, b2], NAMES)["iou/vehicle"]
    paired = bootstrap.paired_runs_bootstrap([a1, a2], [b1, b2], NAMES, paired_seeds=True)["iou/vehicle"]
    assert apart["diff"] == paired["diff"] == pytest.approx(0.05)
    assert apart["low"] < 0 < apart["high"]
    assert paired["low"] == pytest.approx(0.05) and paired["high"] == pytest.approx(0.05)
    with pytest.raises(ValueError, match="as many runs"):
        bootstrap.paired_runs_bootstrap([a1, a2], [b1], NAMES, paired_seeds=True)
