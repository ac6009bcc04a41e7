"""Small OpenEXR helpers: write named channels atomically, read them back as a dict.

Channel dtypes are kept: float16 (half), float32, uint32 (integer labels stay exact).
A multi-layer file is just dotted channel names ("all.semantic", "position.X").
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import OpenEXR

from common.files import write_bytes_atomic, write_with

_DTYPES = (np.float16, np.float32, np.uint32)


def write_exr(path, channels: dict[str, np.ndarray], compression=None) -> None:
    """Write 2D arrays of equal shape as one EXR, atomically (temp file + rename)."""
    path = Path(path)
    if not channels:
        raise ValueError(f"{path}: no channels to write")
    shapes = {np.asarray(a).shape for a in channels.values()}
    if len(shapes) != 1 or len(next(iter(shapes))) != 2:
        raise ValueError(f"{path}: channels must be 2D arrays of one shape, got {sorted(shapes)}")
    data = {}
    for name, a in channels.items():
        a = np.asarray(a)
        if a.dtype not in _DTYPES:
            raise ValueError(f"{path}: channel '{name}' has dtype {a.dtype}; use float16, float32 or uint32")
        data[name] = np.ascontiguousarray(a)
    header = {
        "compression": compression if compression is not None else OpenEXR.ZIP_COMPRESSION,
        "type": OpenEXR.scanlineimage,
    }

    def write(tmp):
        with OpenEXR.File(header, data) as f:
            f.write(str(tmp))

    write_with(path, write)


def read_exr(path, part: int = 0) -> dict[str, np.ndarray]:
    """Every channel of one part of an EXR as a 2D array (name -> array)."""
    out = {}
    with OpenEXR.File(str(path), separate_channels=True) as f:
        for name, ch in f.parts[part].channels.items():
            out[name] = ch.pixels
    return out


def encode_png(a: np.ndarray) -> bytes:
    """A PNG of a 2D (gray, uint8 or uint16) or (H, W, 3) RGB array, with no text chunks (no date),
    so equal pixels give equal bytes."""
    import cv2

    a = np.ascontiguousarray(a[..., ::-1] if a.ndim == 3 else a)
    ok, buf = cv2.imencode(".png", a)
    if not ok:
        raise OSError(f"PNG encoding failed for an array of {a.shape} {a.dtype}")
    return buf.tobytes()


def write_png_atomic(path, image: np.ndarray) -> None:
    """RGB uint8 (H, W, 3) or one-channel uint8/uint16 (H, W) -> PNG, atomically."""
    write_bytes_atomic(path, encode_png(image))
