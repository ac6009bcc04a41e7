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


def _jpeg_header(width: int, height: int, progressive: bool = False, exif: bytes = b"") -> bytes:
    """A JPEG that is only its headers (APP0, an APP1 of `exif`, SOF0 or SOF2 of width x height)."""
    import struct

    def seg(marker, data):
        return b"\xff" + bytes([marker]) + struct.pack(">H", len(data) + 2) + data

    sof = struct.pack(">BHHB", 8, height, width, 3) + b"".join(bytes([i, 0x11, 0]) for i in (1, 2, 3))
    return (b"\xff\xd8" + seg(0xE0, b"JFIF\x00\x01\x01\x00\x00\x01\x00\x01\x00\x00") + (seg(0xE1, exif) if exif else b"")
            + b"\xff\xff" + seg(0xC2 if progressive else 0xC0, sof) + b"\xff\xd9")


def test_image_header_size_is_read_without_decoding(tmp_path):
    """The size check reads the header itself (PNG IHDR, JPEG SOFn after any segments), as PIL reads it."""
    import cv2
    from PIL import Image

    from dataset_tools.stitch import header_size

    img = np.random.default_rng(0).integers(0, 255, (37, 53, 3), np.uint8)
    cv2.imwrite(str(tmp_path / "a.png"), img)
    cv2.imwrite(str(tmp_path / "b.jpg"), img)
    cv2.imwrite(str(tmp_path / "c.jpg"), img, [cv2.IMWRITE_JPEG_PROGRESSIVE, 1])
    exif = Image.Exif()
    exif[0x010F] = "x" * 3000  # an APP1 of 3 kB before the frame header
    Image.fromarray(img).save(tmp_path / "d.jpg", exif=exif)
    for name in ("a.png", "b.jpg", "c.jpg", "d.jpg"):
        with Image.open(tmp_path / name) as im:
            assert header_size(tmp_path / name) == im.size == (53, 37), name
    (tmp_path / "e.jpg").write_bytes(_jpeg_header(60000, 40000, progressive=True, exif=b"Exif\x00\x00" + b"\x00" * 500))
    assert header_size(tmp_path / "e.jpg") == (60000, 40000)
    Image.fromarray(img).save(tmp_path / "f.bmp")
    (tmp_path / "g.png").write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00")  # cut short
    assert header_size(tmp_path / "f.bmp") is None and header_size(tmp_path / "g.png") is None


def test_a_decompression_bomb_is_refused_naming_its_size_and_pil_is_left_alone(tmp_path, monkeypatch):
    """read_image refused a bomb by switching PIL's process-wide Image.MAX_IMAGE_PIXELS off and on
    around Image.open; it checks the header's size first and never touches PIL's setting."""
    import cv2
    import pytest
    from PIL import Image

    from dataset_tools.stitch import StitchError, read_image
    from tests.robust_cases import png_header

    limit, seen = Image.MAX_IMAGE_PIXELS, []
    real_open = Image.open

    def spy(*args, **kwargs):
        seen.append(Image.MAX_IMAGE_PIXELS)
        return real_open(*args, **kwargs)

    monkeypatch.setattr(Image, "open", spy)
    (tmp_path / "bomb.png").write_bytes(png_header(60000, 40000))
    (tmp_path / "bomb.jpg").write_bytes(_jpeg_header(60000, 40000))
    for name in ("bomb.png", "bomb.jpg"):
        with pytest.raises(StitchError, match=rf"{name}: 60000x40000 pixels, more than an image may have"):
            read_image(tmp_path / name)
    assert not seen, "a bomb is refused before PIL opens it"
    cv2.imwrite(str(tmp_path / "ok.png"), np.zeros((40, 64, 3), np.uint8))
    assert read_image(tmp_path / "ok.png").shape == (40, 64, 3)
    assert seen == [limit] and Image.MAX_IMAGE_PIXELS == limit, "PIL's own limit is never switched off"
