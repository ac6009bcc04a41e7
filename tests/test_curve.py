"""experiments.curve: validation scores against training time, read from the TensorBoard log that
train.py writes (here written by the same writer class), pauses of a resumed run taken out."""

import subprocess
import sys
from pathlib import Path

import pytest

from experiments import curve
from model.tensorboard_log import TensorBoardLog

ROOT = Path(__file__).resolve().parents[1]


def write_log(run: Path, start: float, steps: range, seconds_per_step: float, val: dict[int, float]):
    """train/loss every 10 steps at `seconds_per_step`, val/miou etc. at the steps of `val`."""
    w = TensorBoardLog(run / "tb")
    for s in steps:
        if s % 10 == 0:
            w.add_scalar("train/loss", 1.0 / (1 + s), s, walltime=start + s * seconds_per_step)
        if s in val:
            t = start + s * seconds_per_step
            w.add_scalar("val/miou", val[s], s, walltime=t)
            w.add_scalar("val/iou/vehicle", val[s] / 2, s, walltime=t)
    w.close()


def test_curve_of_a_run_stopped_and_resumed(tmp_path):
    run = tmp_path / "run"
    write_log(run, 1000.0, range(0, 101), 2.0, {50: 0.30, 100: 0.40})
    # resumed an hour later (a new event file), same pace
    write_log(run, 1000.0 + 3600.0, range(101, 201), 2.0, {150: 0.45, 200: 0.50})
    c = curve.read_curve(run, ["miou", "iou/vehicle"])
    assert c["steps"] == [50, 100, 150, 200]
    assert c["miou"] == pytest.approx([0.30, 0.40, 0.45, 0.50]) and c["iou/vehicle"] == pytest.approx([0.15, 0.20, 0.225, 0.25])
    # 2 s per step throughout: the hour's pause is not training time
    assert c["minutes"] == pytest.approx([s * 2.0 / 60 for s in (50, 100, 150, 200)])
    md = curve.table([c], ["miou", "iou/vehicle"])
    assert "| 200 | 6.7 | 0.500 | 0.250 |" in md


def test_command_writes_a_picture_and_bad_runs_are_one_line(tmp_path):
    run = tmp_path / "run"
    write_log(run, 0.0, range(0, 41), 1.0, {20: 0.2, 40: 0.3})
    out = tmp_path / "curve.png"
    r = subprocess.run([sys.executable, "-m", "experiments.curve", str(run), "--metrics", "miou", "--out", str(out)],
                       cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and "| 40 | 0.7 | 0.300 |" in r.stdout
    for args, message in [([str(tmp_path / "nothing")], "no TensorBoard log"),
                          ([str(run), "--metrics", "iou/lane_marking"], "no validation scores 'val/iou/lane_marking'")]:
        r = subprocess.run([sys.executable, "-m", "experiments.curve", *args], cwd=ROOT, capture_output=True, text=True)
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and message in r.stderr, r.stderr
