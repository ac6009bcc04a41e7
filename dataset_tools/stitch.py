"""Bird's-eye stitch: the images of a rig projected onto the ground plane, on a metric BEV grid.

    python -m dataset_tools stitch IMAGES --rig RIG --out bev.png [--bound 10 --res 0.02]
    python -m dataset_tools stitch DATA/<scene>/<frame> --out bev.png          # a rendered frame, its own rig

IMAGES is a folder with one image per rig camera (`<camera>.png|jpg`, or `cam_<camera>.png` as our
frames have them). Every BEV cell centre (x, y, height) is projected into each camera with
geometry's `project_ego`; the cell takes the bilinear colour of the camera that sees it nearest its
optical axis. The standard check of a surround-view calibration: straight lines stay straight,
squares stay square and adjacent cameras agree where they overlap.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from common.cli import ArgumentParser, run_cli
from common.errors import InputError
from geometry.bev import BevGrid
from geometry.rig import Rig, load_rig

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


class StitchError(InputError):
    pass


def ground_points(grid: BevGrid, height: float = 0.0) -> np.ndarray:
    """(rows, cols, 3) ego points of the grid's cell centres at z = height."""
    xy = grid.cell_centres()
    return np.concatenate([xy, np.full(xy.shape[:2] + (1,), float(height))], -1)


def bilinear(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Colours (..., C) of an (H, W, C) image at pixel positions uv (..., 2), centres at integers;
    positions are clamped to the image."""
    h, w = image.shape[:2]
    u = np.clip(uv[..., 0], 0, w - 1)
    v = np.clip(uv[..., 1], 0, h - 1)
    u0 = np.minimum(np.floor(u).astype(np.int64), w - 2 if w > 1 else 0)
    v0 = np.minimum(np.floor(v).astype(np.int64), h - 2 if h > 1 else 0)
    du, dv = (u - u0)[..., None], (v - v0)[..., None]
    u1, v1 = np.minimum(u0 + 1, w - 1), np.minimum(v0 + 1, h - 1)
    img = image.astype(np.float64)
    top = img[v0, u0] * (1 - du) + img[v0, u1] * du
    bottom = img[v1, u0] * (1 - du) + img[v1, u1] * du
    return top * (1 - dv) + bottom * dv


def rig_of_images(rig: Rig, images: dict, paths: dict | None = None) -> Rig:
    """The rig with each camera brought to its image's size (`Camera.for_image`: an image of another
    size than its calibration is a resize of it, its camera goes with it; an image that cannot be a
    resize of it, such as 1 x 1 for 960 x 640, is refused naming the image, `paths[name]`)."""
    from geometry.cameras import CameraError
    from geometry.rig import RigCamera

    cams = []
    for rc in rig:
        h, w = np.asarray(images[rc.name]).shape[:2]
        try:
            cams.append(RigCamera(rc.name, rc.camera.for_image(w, h), rc.cam_to_ego))
        except CameraError as exc:
            raise StitchError(f"{(paths or {}).get(rc.name, rc.name)}: {exc}") from None
    return Rig(cams, rig.name, rig.origins)


def stitch(rig: Rig, images: dict, grid: BevGrid, height: float = 0.0, nearest: bool = False):
    """-> (bev (rows, cols, C) uint8, source (rows, cols) int: index of the camera in rig order, -1
    where none sees the cell). An image of another size than its camera is taken as a resize of it
    (`rig_of_images`: refused where it cannot be one).
    `nearest`: take the nearest pixel (for label images: class ids, one channel or more)."""
    pts = ground_points(grid, height)
    best = np.full(grid.shape, np.inf)
    source = np.full(grid.shape, -1, dtype=np.int64)
    bev = None
    for i, rc in enumerate(rig):
        image = np.asarray(images[rc.name])
        image = image[..., None] if image.ndim == 2 else image[..., :3]
        if bev is None:
            bev = np.zeros(grid.shape + image.shape[2:], dtype=np.float64)
        cam = rc.camera
        if image.shape[:2] != (cam.height, cam.width):
            try:
                rc = type(rc)(rc.name, cam.for_image(image.shape[1], image.shape[0]), rc.cam_to_ego)
            except ValueError as exc:  # CameraError
                raise StitchError(f"{rc.name}: {exc}") from None
        uv, valid = rc.project_ego(pts)
        p_cam = pts @ rc.ego_to_cam[:3, :3].T + rc.ego_to_cam[:3, 3]
        angle = np.arccos(np.clip(p_cam[..., 2] / np.linalg.norm(p_cam, axis=-1), -1, 1))
        take = valid & rc.camera.inside(uv) & (angle < best)
        best = np.where(take, angle, best)
        source = np.where(take, i, source)
        if nearest:
            q = np.rint(uv[take]).astype(np.int64)
            bev[take] = image[np.clip(q[:, 1], 0, image.shape[0] - 1), np.clip(q[:, 0], 0, image.shape[1] - 1)]
        else:
            bev[take] = bilinear(image, uv[take])
    bev = np.clip(np.rint(bev), 0, 255).astype(np.uint8)
    return (bev[..., 0] if bev.shape[-1] == 1 else bev), source


MAX_IMAGE_PIXELS = 100_000_000  # an image whose header promises more is refused before it is decoded


def image_paths(folder: Path, names) -> dict:
    """Camera name -> its image in `folder` (`<camera>.png|jpg|jpeg` or `cam_<camera>.png`)."""
    out = {}
    for n in names:
        found = [folder / f"{prefix}{n}{s}" for prefix in ("", "cam_") for s in IMAGE_SUFFIXES]
        found = [p for p in found if p.is_file()]
        if not found:
            raise StitchError(f"{folder}: no image for camera '{n}' (expected {n}.png, {n}.jpg or cam_{n}.png)")
        out[n] = found[0]
    return out


JPEG_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}  # frame headers (size)


def header_size(path: Path) -> tuple[int, int] | None:
    """(width, height) as a PNG's or JPEG's header gives it, read without decoding anything (and
    without PIL, whose Image.open refuses a large image with its own unnamed error); None for
    another format or a header cut short (PIL then says what is wrong)."""
    import struct

    with open(path, "rb") as f:
        head = f.read(24)
        if head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR" and len(head) == 24:
            w, h = struct.unpack(">II", head[16:24])
            return w, h
        if head[:2] != b"\xff\xd8":
            return None
        f.seek(2)
        while True:  # JPEG segments up to the first frame header (SOFn: precision, height, width)
            if f.read(1) != b"\xff":
                return None
            m = f.read(1)
            while m == b"\xff":  # fill bytes before a marker
                m = f.read(1)
            if not m:
                return None
            m = m[0]
            if m == 0x01 or 0xD0 <= m <= 0xD8:  # markers without a length
                continue
            seg = f.read(2)
            if len(seg) < 2:
                return None
            n = struct.unpack(">H", seg)[0]
            if m in JPEG_SOF:
                sof = f.read(5)
                if len(sof) < 5:
                    return None
                h, w = struct.unpack(">HH", sof[1:5])
                return w, h
            if m == 0xDA or n < 2:  # image data before any frame header: not a JPEG we can size
                return None
            f.seek(n - 2, 1)


def read_image(path: Path) -> np.ndarray:
    """An image file as (H, W, 3) uint8 RGB: 16-bit images scaled to 8 bits (not clipped), grey
    images made RGB; a file that is not an image, or whose header promises more than
    MAX_IMAGE_PIXELS pixels (a decompression bomb), is refused naming it, before anything is
    decoded (`header_size`; PIL's own limit, a process-wide setting, is left as it is)."""
    import warnings

    from PIL import Image

    def too_many(w, h):
        return StitchError(f"{path}: {w}x{h} pixels, more than an image may have ({MAX_IMAGE_PIXELS})")

    try:
        size = header_size(path)
        if size and size[0] * size[1] > MAX_IMAGE_PIXELS:
            raise too_many(*size)
        with warnings.catch_warnings():  # PIL warns above its own limit, below ours: the size is checked
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            im = Image.open(path)
        with im:
            w, h = im.size
            if w * h > MAX_IMAGE_PIXELS:  # a format header_size does not read
                raise too_many(w, h)
            if im.mode in ("I;16", "I;16B", "I;16L", "I;16N", "I"):  # 16-bit grey: scale 0..65535 to 0..255
                a = np.asarray(im).astype(np.float64)
                a = np.clip(np.rint(a / 257.0), 0, 255).astype(np.uint8)
                return np.repeat(a[..., None], 3, axis=-1)
            return np.asarray(im.convert("RGB"))
    except Image.DecompressionBombError as exc:  # a format header_size does not read, beyond PIL's limit
        raise StitchError(f"{path}: more pixels than an image may have ({MAX_IMAGE_PIXELS}): {exc}"[:300]) from None
    except OSError as exc:
        raise StitchError(f"{path}: not a readable image ({exc})") from None


def read_images(folder: Path, names) -> dict:
    return {n: read_image(p) for n, p in image_paths(folder, names).items()}


def rig_for(folder: Path, rig_path: str | None) -> Rig:
    """The --rig file, else the rig a rendered frame folder was rendered with (its meta.json)."""
    if rig_path:
        return load_rig(rig_path)
    from .format.layout import META
    from .format.meta import read_meta

    if not (folder / META).is_file():
        raise StitchError(f"{folder}: not a rendered frame (no {META}); give --rig")
    try:
        return read_meta(folder).camera_rig()
    except InputError as exc:  # e.g. the meta.json of another simulator's frame
        raise StitchError(f"{exc}; not a frame rendered here? give --rig") from None


MAX_BOUND_M = 500.0  # --bound: half the grid's side at most, metres
MAX_CELLS_PER_SIDE = 8192  # --bound / --res: a grid of at most 8192 x 8192 cells


def stitch_grid(bound: float, res: float, height: float = 0.0) -> BevGrid:
    """The stitch's grid from --bound, --res (and --height), each checked and named when wrong."""
    import math

    if not (math.isfinite(bound) and 0 < bound <= MAX_BOUND_M):
        raise StitchError(f"--bound: must be a number of metres in (0, {MAX_BOUND_M:g}], got {bound}")
    if not (math.isfinite(res) and 0 < res <= bound):
        raise StitchError(f"--res: must be a number of metres in (0, --bound], got {res}")
    if not math.isfinite(height) or abs(height) > 100:
        raise StitchError(f"--height: must be a number of metres in [-100, 100], got {height}")
    if 2 * bound / res > MAX_CELLS_PER_SIDE:
        raise StitchError(f"--bound/--res: {2 * bound:g} m at {res:g} m is {2 * bound / res:.0f} cells a side, "
                          f"more than {MAX_CELLS_PER_SIDE} (a coarser --res or a smaller --bound)")
    try:
        return BevGrid.from_dict({"bound": bound, "res": res})
    except ValueError as exc:
        raise StitchError(f"--bound/--res: {exc}") from None


def main(argv=None) -> int:
    from common.files import write_bytes_atomic

    p = ArgumentParser(prog="python -m dataset_tools stitch", description="Bird's-eye stitch of a rig's images on the ground plane.")
    p.add_argument("images", help="a folder with one image per rig camera (<camera>.png|jpg), or a rendered frame folder")
    p.add_argument("--rig", help="rig file (any format geometry.load_rig reads; default: the rendered frame's own rig)")
    p.add_argument("--out", required=True, help="output PNG")
    p.add_argument("--bound", type=float, default=10.0, help="half size of the square grid, metres (default 10)")
    p.add_argument("--res", type=float, default=0.02, help="cell size, metres (default 0.02)")
    p.add_argument("--height", type=float, default=0.0, help="height of the plane above the ego origin, metres (default 0)")
    a = p.parse_args(argv)
    folder = Path(a.images)
    if not folder.is_dir():
        raise StitchError(f"{folder}: no such folder")
    grid = stitch_grid(a.bound, a.res, a.height)
    rig = rig_for(folder, a.rig)
    rig.print_description(a.rig or folder)
    paths = image_paths(folder, rig.names)
    images = {n: read_image(p) for n, p in paths.items()}
    bev, source = stitch(rig_of_images(rig, images, paths), images, grid, a.height)
    import io

    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(bev).save(buf, format="PNG")
    write_bytes_atomic(Path(a.out), buf.getvalue())
    print(f"written {a.out}: {grid.rows}x{grid.cols} cells of {grid.res} m, {100 * np.mean(source >= 0):.0f}% seen")
    return 0


if __name__ == "__main__":
    run_cli(main)
