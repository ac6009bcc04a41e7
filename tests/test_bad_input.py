"""Bad input anywhere gets one clear error naming the file or field (the CLIs print it as one line)."""

import pytest

from common.errors import ConfigError as FusionConfigError
from dataset_tools.labels.fusion import FusionConfig
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
