"""The bird's-eye stitch (dataset_tools.stitch) on our real tiny renders: the fisheye semantic pass
stitched onto the label grid agrees with the fused labels on the street, and a wrong rig does not.
(The stitch of real images, with its metric check, is in tests/test_calib_import.py.)"""

import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def test_stitched_semantic_pass_matches_the_labels(tiny_dataset):
    from dataset_tools.format.layout import FrameFiles
    from dataset_tools.format.meta import read_meta
    from dataset_tools.format.passes import read_camera_passes
    from dataset_tools.format.reader import DatasetIndex, read_frame
    from dataset_tools.labels.classes import class_lut
    from dataset_tools.stitch import stitch
    from geometry.rig import Rig, RigCamera

    idx = DatasetIndex(tiny_dataset)
    grid, lut = idx.grid, class_lut()
    street = idx.class_names.index("street")
    near = np.linalg.norm(grid.cell_centres(), axis=-1) < 12
    for ref in idx.frames("train"):
        f = read_frame(ref)
        rig = read_meta(ref.dir).camera_rig()
        sem = {rc.name: lut[read_camera_passes(FrameFiles(ref.dir).camera_exr(rc.name))["semantic"]] for rc in rig}
        bev, seen = stitch(rig, sem, grid, nearest=True)
        cells = (f["semantic"] == street) & (f["visibility"] >= 0.5) & (seen >= 0) & near
        assert cells.sum() > 50
        assert (bev[cells] == street).mean() >= 0.85, ref  # measured 0.89-0.96 (cells of 0.78 m at 64x40 pixels)
        # the same with the front and rear cameras' poses swapped: the street lands elsewhere
        swapped = Rig([RigCamera(rc.name, rc.camera, rig[{"front": "rear", "rear": "front"}.get(rc.name, rc.name)].cam_to_ego) for rc in rig])
        bad, seen2 = stitch(swapped, sem, grid, nearest=True)
        both = cells & (seen2 >= 0)
        assert (bad[both] == street).mean() < (bev[both] == street).mean() - 0.05


def test_stitch_command_on_a_rendered_frame(tiny_dataset, tmp_path):
    from dataset_tools.format.reader import DatasetIndex

    ref = DatasetIndex(tiny_dataset).frames("train")[0]
    out = tmp_path / "bev.png"
    r = subprocess.run([sys.executable, "-m", "dataset_tools", "stitch", str(ref.dir), "--out", str(out), "--bound", "8", "--res", "0.1"],
                       cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    from PIL import Image

    assert Image.open(out).size == (160, 160)
    r = subprocess.run([sys.executable, "-m", "dataset_tools", "stitch", str(ref.dir), "--out", str(out), "--res", "0.3"],
                       cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "--bound/--res" in r.stderr


def test_16_bit_images_are_scaled_not_clipped(tmp_path):
    """A 16-bit PNG was clipped to 8 bits (a real image became 95 % white); it is scaled."""
    import cv2
    import numpy as np

    from dataset_tools.stitch import read_image

    a = (np.arange(40 * 64).reshape(40, 64) * 25).astype(np.uint16)  # 0 .. 63975
    cv2.imwrite(str(tmp_path / "grey16.png"), a)
    cv2.imwrite(str(tmp_path / "colour16.png"), np.stack([a, a // 2, a // 4], -1))  # BGR
    g = read_image(tmp_path / "grey16.png")
    assert g.shape == (40, 64, 3) and g.dtype == np.uint8
    np.testing.assert_array_equal(g[..., 0], np.rint(a / 257.0).astype(np.uint8))
    assert (g == 255).mean() < 0.01
    c = read_image(tmp_path / "colour16.png")
    assert np.abs(c[..., 2].astype(int) - np.rint(a / 257.0)).max() <= 1 and np.abs(c[..., 0].astype(int) - np.rint(a / 4 / 257.0)).max() <= 1


def test_an_image_that_is_no_resize_of_its_camera_is_refused():
    import numpy as np
    import pytest

    from dataset_tools.stitch import StitchError, rig_of_images
    from geometry.rig import load_rig

    rig = load_rig(Path(__file__).parent / "data" / "surround_view" / "rig.yaml")
    images = {n: np.zeros((320, 480, 3), np.uint8) for n in rig.names}
    assert rig_of_images(rig, images)["front"].camera.width == 480
    images["left"] = np.zeros((1, 1, 3), np.uint8)
    with pytest.raises(StitchError, match=r"left.jpg: a 1x1 image is not a resize of the 960x640 camera"):
        rig_of_images(rig, images, {n: f"{n}.jpg" for n in rig.names})
    images["left"] = np.zeros((320, 400, 3), np.uint8)  # another aspect ratio
    with pytest.raises(StitchError, match="not a resize"):
        rig_of_images(rig, images)
