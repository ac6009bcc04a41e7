"""Bad input anywhere gets one clear error naming the file or field (the CLIs print it as one line)."""

import pytest

from common.errors import ConfigError as FusionConfigError
from dataset_tools.labels.label_fusion import FusionConfig
from dataset_tools.format.reader import DatasetError, DatasetIndex
from geometry.cameras import CameraError, camera_from_dict


def test_camera_size_that_is_not_a_number():
    with pytest.raises(CameraError, match="pinhole: 'width' must be a whole number of pixels"):
        camera_from_dict({"model": "pinhole", "width": "abc", "height": 4, "fx": 1, "fy": 1, "cx": 1, "cy": 1})


@pytest.mark.parametrize("labels, message", [
    ({"spread_step_m": -1}, r"labels.spread_step_m: must be a number in \[0.0, 10.0\]"),
    ({"ego_box": [1, 2, 3]}, "labels.ego_box: must be a list of 4"),
    ({"ego_box": [3, 2, -1, 1]}, "labels: ego_box: must be"),
    ({"reference_pixels": 0}, "labels.reference_pixels: must be a whole number > 0"),
])
def test_fusion_config_fields(labels, message):
    with pytest.raises(FusionConfigError, match=message):
        FusionConfig.from_dict(labels, "small.yaml: labels")


def test_unknown_split(tiny_dataset):
    with pytest.raises(DatasetError, match="no split 'val'"):
        DatasetIndex(tiny_dataset).frames("val")


@pytest.mark.parametrize("labels, field", [({"tau": -1}, "labels.tau"), ({"class_names": "road"}, "labels.class_names"),
                                           ({"bogus": 1}, "labels")])
def test_bad_labels_section_stops_the_dataset_before_anything_renders(tmp_path, labels, field):
    """A mistake in a dataset config's `labels:` section is found when the config is loaded: one
    line naming the file and the field, exit 2, and no Blender started, no frame rendered."""
    import subprocess
    import sys

    import yaml

    from common.cli import EXIT_BAD_INPUT
    from dataset_tools.generation.dataset_config import load_config

    cfg = tmp_path / "bad.yaml"
    cfg.write_text(yaml.safe_dump({"fisheye_size": [64, 40], "topdown": {"size": 64}, "render": {"quality": "draft"},
                                   "frames": 1, "scenes": [{"recipe": "scenes/highway_straight.yaml"}],
                                   "labels": labels}))
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, "-m", "dataset_tools", "dataset", "--config", str(cfg), "--out", str(out),
                        "--no-progress"], capture_output=True, text=True, timeout=120)
    assert r.returncode == EXIT_BAD_INPUT, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    assert "bad.yaml" in lines[0] and field in lines[0], lines[0]
    assert not out.exists(), "nothing written, nothing rendered"
    assert "dataset: render" not in r.stdout
    with pytest.raises(FusionConfigError, match=field):  # the one loader every command uses
        load_config(cfg)
