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
    fake = np.zeros(1000, np.float32)
    fake[[1, 2, 436, 4, 5]] = [5, 4, 3, 2, 1]  # a station wagon third: a top-5 hit, not a top-1 one
    monkeypatch.setattr(realism, "logits", lambda crops: np.tile(fake, (len(crops), 1)))
    s = realism.score(tmp_path)
    nan = s.pop("road_vehicle_top1_night"), s.pop("road_vehicle_top5_night")
    assert np.isnan(nan).all()  # no night frame
    assert np.isnan(s.pop("road_vehicle_top1_ci")).all() and np.isnan(s.pop("road_vehicle_top5_ci")).all()  # one scene
    steady = {k: s.pop(k) for k in list(s) if k.startswith("steady_")}
    assert s == {"crops": 1, "road_vehicle_top1": 0.0, "road_vehicle_top5": 1.0, "crops_day": 1,
                 "road_vehicle_top1_day": 0.0, "road_vehicle_top5_day": 1.0, "crops_night": 0}
    assert set(steady) == {f"steady_{k}{t}" for k in ("top5", "p") for t in ("", "_day", "_night")}
    assert steady["steady_top5"] == 1.0 and 0 < steady["steady_p"] < 0.1


def test_interval_resamples_scenes_and_covers_the_share():
    # 3 scenes: all hits, half, none (10 crops each): the share is 0.5, scenes differ a lot
    hits = np.array([1] * 10 + [1, 0] * 5 + [0] * 10, bool)
    groups = np.repeat(["a", "b", "c"], 10)
    lo, hi = realism.interval(hits, groups)
    assert lo < 0.5 < hi and hi - lo > 0.3  # wide: three scenes
    same = realism.interval(np.array([1, 0] * 15, bool), groups)
    assert same == [0.5, 0.5]  # every scene alike: no spread


def test_views_mirror_scale_and_shift_the_square(tmp_path):
    frame = _frame(tmp_path)
    [(key, v)] = realism.vehicle_views(frame, ((1.0, 0.0, 0.0, False), (1.0, 0.0, 0.0, True), (2.0, 0.0, 0.0, False),
                                               (1.0, 0.5, 0.0, False)), size=90)
    assert key == "front/5" and v.shape == (4, 90, 90, 3)
    assert (v[0] == realism.vehicle_crops(frame, size=90)[0]).all()  # the first view is the crop of record
    assert (v[1] == v[0][:, ::-1]).all()
    road = (v[2] == 90).all(-1)
    assert road[:, 0].all() and road[:, -1].all() and not road[45, 45]  # twice the side: road round the car
    assert (v[3][45, :40] == (200, 30, 30)).all() and (v[3][45, 50:] == 90).all()  # centre moved right by half


def test_compare_pairs_vehicles_and_reports_b_minus_a(tmp_path, monkeypatch):
    a, b = tmp_path / "a", tmp_path / "b"
    _frame(a)
    _frame(b)
    def logits(crops):  # the same vehicle in both renders; road vehicle (436) wins where the crop's centre is bright red, else class 1
        x = np.stack(crops)
        out = np.zeros((len(x), 1000), np.float32)
        red = x[:, 112, 112, 0] > 150
        out[red, 436], out[~red, 1] = 20.0, 20.0
        return out

    monkeypatch.setattr(realism, "logits", logits)
    img = realism.read_png(b / "s" / "000000" / "cam_front.png", np.uint8, 3).copy()
    img[100:150, 200:290] = (40, 40, 40)  # the car dark in B: no view sees red
    realism.write_png_atomic(b / "s" / "000000" / "cam_front.png", img)
    res = realism.compare(a, b)
    assert res["paired"] == 1 and res["paired_day"] == 1 and "paired_night" not in res
    assert res["steady_top5"] == [1.0, 0.0] and res["steady_top5_diff"] == -1.0
    assert res["steady_p"][0] > 0.9 > 0.1 > res["steady_p"][1]


def test_compare_refuses_a_folder_without_renders(tmp_path, capsys):
    _frame(tmp_path / "a")
    (tmp_path / "b").mkdir()
    assert realism.main(["--compare", str(tmp_path / "a"), str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(tmp_path / "b") in err[0] and "no rendered frames" in err[0]
