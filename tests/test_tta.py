"""Time to accuracy (experiments.tta): the first validation that reaches every target, a run that
never reaches it counted whole and marked, the median and ratio, bad targets in one line; and a
real train.py run on a constructed data set stopped at its target, whose result is kept and not
trained again."""

from __future__ import annotations

import json

import pytest

from experiments import tta
from tests.test_train import write_config

CURVE = {"steps": [10, 20, 30, 40], "minutes": [1.0, 2.0, 3.0, 4.0],
         "miou": [0.40, 0.61, 0.58, 0.65], "iou/lane_marking": [0.10, 0.15, 0.22, 0.25]}
TARGET = {"miou": 0.60, "iou/lane_marking": 0.20}


def test_the_first_validation_reaching_every_target_counts():
    assert tta.reached(CURVE, TARGET) == 3  # step 20 reaches mIoU only, step 30 markings only
    r = tta.result_of(CURVE, TARGET, finished=False)
    assert r["reached"] and r["minutes"] == 4.0 and r["step"] == 40 and r["scores"] == {"miou": 0.65, "iou/lane_marking": 0.25}
    short = {k: v[:3] for k, v in CURVE.items()}
    assert tta.result_of(short, TARGET, finished=False) is None  # still training
    r = tta.result_of(short, TARGET, finished=True)  # the schedule ended short of it: its whole time
    assert not r["reached"] and r["minutes"] == 3.0 and r["step"] == 30
    assert tta.result_of(None, TARGET, finished=True) is None


def test_median_over_seeds_and_the_ratio():
    def r(minutes, ok=True):
        return {"minutes": minutes, "reached": ok, "step": 100, "scores": {"miou": 0.6}}

    res = {"head": {0: r(10.0), 1: r(14.0), 2: r(12.0)}, "baseline": {0: r(30.0), 1: r(20.0, False), 2: r(24.0)}}
    s = tta.summary(res, TARGET)
    assert s["head"]["minutes"] == 12.0 and s["baseline"]["minutes"] == 24.0 and s["ratio"] == 0.5
    assert s["head"]["all_reached"] and not s["baseline"]["all_reached"]
    assert "not all (a lower bound)" in tta.table(res, s)


@pytest.mark.parametrize("bad", ["miou", "miou=", "=0.5", "miou=high", "miou=0", "miou=1.5"])
def test_a_bad_target_is_one_line(bad):
    with pytest.raises(tta.TtaError, match="--target: .* is not METRIC=VALUE"):
        tta.parse_targets([bad])


def test_a_run_stops_at_its_target_and_is_not_trained_again(tmp_path, capsys):
    from testing.toy_data import write_toy_dataset

    root = write_toy_dataset(tmp_path / "toy", frames=4, image_scale=64 / 480, splits=("train", "heldout"))
    cfg = write_config(tmp_path / "c.yaml", root, train={"epochs": 1000, "log_every": 1}, augment={"enabled": False})
    out = tmp_path / "tta"
    argv = ["--data", str(root), "--baseline", "none", "--seeds", "0", "--out", str(out), "--config", str(cfg),
            "--val-every", "2", "--target", "miou=0.01"]
    tta.POLL_S, poll = 1.0, tta.POLL_S
    try:
        assert tta.main(argv) == 0
    finally:
        tta.POLL_S = poll
    res = json.loads((out / "head_s0.json").read_text())
    assert res["reached"] and res["step"] >= 2 and res["minutes"] > 0 and res["scores"]["miou"] >= 0.01
    steps = json.loads((out / "tta.json").read_text())["summary"]["head"]
    assert steps["runs"] == 1 and steps["all_reached"]
    assert (out / "head_s0" / "latest.pt").is_file()  # stopped by SIGTERM: train.py saved it
    # stopped long before its 1000 epochs; run again: the result is read, nothing trains
    latest = (out / "head_s0" / "latest.pt").stat().st_mtime_ns
    capsys.readouterr()
    assert tta.main(argv) == 0
    assert "tta: head seed 0" not in capsys.readouterr().out
    assert (out / "head_s0" / "latest.pt").stat().st_mtime_ns == latest


def test_data_that_is_no_data_set_is_one_line(tmp_path):
    with pytest.raises(tta.TtaError, match="--data: .* is not a data set"):
        tta.main(["--data", str(tmp_path), "--baseline", "none"])


def test_an_older_reader_gets_the_same_frames_without_the_fields_it_refuses(tmp_path):
    from testing.toy_data import write_toy_dataset

    root = write_toy_dataset(tmp_path / "toy", frames=2, image_scale=64 / 480, splits=("train",))
    metas = sorted(root.glob("*/*/meta.json"))
    known = [k for k in json.loads(metas[0].read_text()) if k != "timings"]
    view = tta.data_view(root, known, tmp_path / "view")
    for meta in metas:
        seen = json.loads((view / meta.relative_to(root)).read_text())
        assert set(seen) == set(known) and seen["scene"] == json.loads(meta.read_text())["scene"]
    files = [p for p in root.rglob("*") if p.is_file() and p.name != "meta.json"]
    assert files and all((view / p.relative_to(root)).read_bytes() == p.read_bytes() for p in files)
    assert all((view / p.relative_to(root)).stat().st_ino == p.stat().st_ino for p in files)  # links, not copies
    assert tta.data_view(root, known, tmp_path / "view") == view  # made once, reused
    assert tta.meta_fields(tta.CODE_DIR) and "sensor" in tta.meta_fields(tta.CODE_DIR)
