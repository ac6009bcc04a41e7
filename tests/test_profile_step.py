"""bench.profile_step on a toy data set: every part of a step is timed, for every pooling (the
model's own bev_outputs runs the pooling, encoder and heads)."""

import subprocess
import sys
from pathlib import Path

from testing.toy_data import write_toy_dataset

ROOT = Path(__file__).resolve().parents[1]


def test_profile_step_times_every_part_with_another_pooling(tmp_path):
    root = write_toy_dataset(tmp_path / "toy", frames=12, splits=("train",))
    r = subprocess.run([sys.executable, "-m", "bench.profile_step", str(root), "--steps", "3", "--no-profiler",
                        "--set", "train.threads=1", "model.pooling=intrinsics_embedding", "data.input_size=[64,40]",
                        "data.grid={bound: 25.0, res: 0.5}", "model.bev_encoder.widths=[8,16,16]"],
                       cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    for part in ("trunk fwd", "splat fwd", "bev encoder+heads fwd", "bev encoder+heads bwd", "trunk bwd", "whole step"):
        line = next(ln for ln in r.stdout.splitlines() if ln.strip().startswith(part))
        assert float(line.split()[-1]) > 0, line


def test_profile_step_profiles_the_named_config_and_refuses_a_missing_one(tmp_path):
    """--config cpu_medium profiles the default chain's step (its pretrained, partly frozen trunk with its
    depthwise weights kept, BatchNorm, separable decoder), not cpu_default's; a config that is not there is one line and a non-zero exit."""
    root = write_toy_dataset(tmp_path / "toy", frames=12, splits=("train",))
    small = ["train.threads=1", "data.input_size=[64,40]", "data.grid={bound: 25.0, res: 0.5}",
             "model.bev_encoder.widths=[8,16,16]",
             "loss.depth_weight=0", "loss.camera_seg_weight=0"]  # the toy data set has no EXR passes
    # a second --set adds to the first (it once replaced it, dropping the first one's fields)
    r = subprocess.run([sys.executable, "-m", "bench.profile_step", str(root), "--config", "cpu_medium", "--steps", "3",
                        "--no-profiler", "--set", "model.precision=fp32", "--set", *small],
                       cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    first = "cpu_medium.yaml: trunk efficientnet_lite0 (frozen levels 2, depthwise weights frozen), batch norm, input 64x40"
    assert r.stdout.startswith(first + ", precision fp32"), r.stdout[:300]
    assert float(next(ln for ln in r.stdout.splitlines() if ln.strip().startswith("whole step")).split()[-1]) > 0
    missing = tmp_path / "nope.yaml"
    r = subprocess.run([sys.executable, "-m", "bench.profile_step", str(root), "--config", str(missing)],
                       cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert r.returncode != 0 and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "nope.yaml" in r.stderr, r.stderr


def test_trunk_layout_times_both_layouts_and_measures_their_gradients():
    """bench.trunk_layout: a row per layout and precision; fp32's gradients within float32 rounding
    of the float64 copy's, bf16's far further in either layout (the figure model.cpu's rule rests on)."""
    r = subprocess.run([sys.executable, "-m", "bench.trunk_layout", "--images", "2", "--rounds", "1", "--threads", "1"],
                       cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    rows = {tuple(ln.split()[:2]): [float(v) for v in ln.split()[2:]] for ln in r.stdout.splitlines()
            if ln.split()[:1] in (["NCHW"], ["NHWC"])}
    assert set(rows) == {(a, b) for a in ("NCHW", "NHWC") for b in ("fp32", "bf16")}, r.stdout
    for (layout, precision), (ms, err) in rows.items():
        assert ms > 0 and err > 0, (layout, precision)
        assert (err < 1e-2) == (precision == "fp32"), (layout, precision, err)
