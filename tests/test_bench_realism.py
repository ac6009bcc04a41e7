"""The realism bench's parts on a frame made here: which vehicles are cropped (at least MIN_SIDE px
on both sides of their visible box, vehicles only), how, and that the classifier's road-vehicle
classes are ImageNet indices."""

from __future__ import annotations

import numpy as np

from bench import realism
from dataset_tools.format.exr import write_exr
from dataset_tools.format.layout import FrameFiles
from dataset_tools.format.png import write_png_atomic
from dataset_tools.labels.classes import CLASS_IDS


def _frame(tmp_path):
    h, w = 302, 480
    sem = np.full((h, w), CLASS_IDS["road"], np.uint32)
    inst = np.zeros((h, w), np.uint32)
    img = np.full((h, w, 3), 90, np.uint8)
    for iid, cls, (y0, y1, x0, x1), colour in ((5, "vehicle", (100, 150, 200, 290), (200, 30, 30)),  # 50 x 90: cropped
                                                (6, "vehicle", (10, 40, 10, 100), (30, 200, 30)),  # 30 px tall: too small
                                                (7, "pedestrian", (150, 280, 380, 470), (30, 30, 200))):  # not a vehicle
        sem[y0:y1, x0:x1], inst[y0:y1, x0:x1], img[y0:y1, x0:x1] = CLASS_IDS[cls], iid, colour
    files = FrameFiles(tmp_path / "s" / "000000")
    files.dir.mkdir(parents=True)
    write_exr(files.camera_exr("front"), {"semantic": sem, "instance": inst})
    write_png_atomic(files.camera_png("front"), img)
    return files.dir


def test_only_large_enough_vehicles_are_cropped_square_around_their_box(tmp_path):
    crops = realism.vehicle_crops(_frame(tmp_path))
    assert len(crops) == 1
    c = crops[0]
    assert c.shape == (realism.CROP, realism.CROP, 3) and c.dtype == np.uint8
    # a 90 x 50 box in a 90 x 90 square: the car fills the middle rows, the road the top and bottom
    mid, top = c[realism.CROP // 2, realism.CROP // 2], c[5, realism.CROP // 2]
    assert tuple(mid) == (200, 30, 30) and tuple(top) == (90, 90, 90)


def test_road_vehicle_classes_are_imagenet_indices():
    assert all(0 <= k < 1000 for k in realism.ROAD_VEHICLE) and len(realism.ROAD_VEHICLE) >= 20
    assert 705 not in realism.ROAD_VEHICLE  # ImageNet's 'passenger car' is a railway carriage


def test_score_counts_top1_and_top5(tmp_path, monkeypatch):
    _frame(tmp_path)
    monkeypatch.setattr(realism, "top5", lambda crops: np.array([[1, 2, 436, 4, 5]] * len(crops)))
    s = realism.score(tmp_path)
    nan = s.pop("road_vehicle_top1_night"), s.pop("road_vehicle_top5_night")
    assert np.isnan(nan).all()  # no night frame
    assert np.isnan(s.pop("road_vehicle_top1_ci")).all() and np.isnan(s.pop("road_vehicle_top5_ci")).all()  # one scene
    assert s == {"crops": 1, "road_vehicle_top1": 0.0, "road_vehicle_top5": 1.0, "crops_day": 1,
                 "road_vehicle_top1_day": 0.0, "road_vehicle_top5_day": 1.0, "crops_night": 0}


def test_interval_resamples_scenes_and_covers_the_share():
    # 3 scenes: all hits, half, none (10 crops each): the share is 0.5, scenes differ a lot
    hits = np.array([1] * 10 + [1, 0] * 5 + [0] * 10, bool)
    groups = np.repeat(["a", "b", "c"], 10)
    lo, hi = realism.interval(hits, groups)
    assert lo < 0.5 < hi and hi - lo > 0.3  # wide: three scenes
    same = realism.interval(np.array([1, 0] * 15, bool), groups)
    assert same == [0.5, 0.5]  # every scene alike: no spread
