"""PNG files of a data set: encode (no text chunks, so equal pixels give equal bytes), write
atomically, read back with a one-line DatasetError for a missing, damaged or wrongly typed file."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from common.files import write_bytes_atomic

from .layout import DatasetError


def encode_png(a: np.ndarray) -> bytes:
    """A PNG of a 2D (gray, uint8 or uint16) or (H, W, 3) RGB array, with no text chunks (no date),
    so equal pixels give equal bytes."""
    a = np.ascontiguousarray(a[..., ::-1] if a.ndim == 3 else a)
    ok, buf = cv2.imencode(".png", a)
    if not ok:
        raise OSError(f"PNG encoding failed for an array of {a.shape} {a.dtype}")
    return buf.tobytes()


def write_png_atomic(path, image: np.ndarray) -> None:
    """RGB uint8 (H, W, 3) or one-channel uint8/uint16 (H, W) -> PNG, atomically."""
    write_bytes_atomic(path, encode_png(image))


def read_png(path, dtype=None, channels: int | None = None) -> np.ndarray:
    """A PNG as stored (uint8 or uint16; RGB order for colour); checks dtype and channel count."""
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: missing")
    return _checked(cv2.imread(str(path), cv2.IMREAD_UNCHANGED), path, dtype, channels)


def decode_png(data: bytes, source, dtype=None, channels: int | None = None) -> np.ndarray:
    """read_png of a PNG held in memory (a shard member); `source` names it in errors."""
    a = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED) if data else None
    return _checked(a, source, dtype, channels)


def _checked(a, path, dtype, channels) -> np.ndarray:
    if a is None:
        raise DatasetError(f"{path}: not a readable PNG")
    if a.ndim == 3:
        a = a[..., 2::-1] if a.shape[2] >= 3 else a
    if dtype is not None and a.dtype != np.dtype(dtype):
        raise DatasetError(f"{path}: pixel type {a.dtype}, expected {np.dtype(dtype)}")
    if channels is not None and (1 if a.ndim == 2 else a.shape[2]) != channels:
        raise DatasetError(f"{path}: {1 if a.ndim == 2 else a.shape[2]} channels, expected {channels}")
    return np.ascontiguousarray(a)
