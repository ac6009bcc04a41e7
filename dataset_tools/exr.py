"""Small OpenEXR helpers: write named channels atomically, read them back as a dict.

Channel dtypes are kept: float16 (half), float32, uint32 (integer labels stay exact).
A multi-layer file is just dotted channel names ("all.semantic", "position.X").
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import OpenEXR

_DTYPES = (np.float16, np.float32, np.uint32)


def atomic_path(path) -> Path:
    """A temp name beside `path` (same folder, so the final rename is atomic)."""
    path = Path(path)
    return path.with_name(f".{path.name}.{os.getpid()}.tmp")


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
    tmp = atomic_path(path)
    try:
        with OpenEXR.File(header, data) as f:
            f.write(str(tmp))
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def read_exr(path, part: int = 0) -> dict[str, np.ndarray]:
    """Every channel of one part of an EXR as a 2D array (name -> array)."""
    out = {}
    with OpenEXR.File(str(path), separate_channels=True) as f:
        for name, ch in f.parts[part].channels.items():
            out[name] = ch.pixels
    return out


def write_bytes_atomic(path, data: bytes) -> None:
    path = Path(path)
    tmp = atomic_path(path)
    try:
        tmp.write_bytes(data)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def write_text_atomic(path, text: str) -> None:
    write_bytes_atomic(path, text.encode())


def write_png_atomic(path, rgb: np.ndarray) -> None:
    """RGB uint8 (H, W, 3) -> PNG, atomically."""
    import cv2

    ok, buf = cv2.imencode(".png", np.ascontiguousarray(rgb[..., ::-1]))
    if not ok:
        raise OSError(f"{path}: PNG encoding failed")
    write_bytes_atomic(path, buf.tobytes())
