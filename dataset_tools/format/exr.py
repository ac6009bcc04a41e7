"""Small OpenEXR helpers: write named channels atomically, read them back as a dict (read_exr_checked:
a missing or damaged file is one DatasetError line).

Channel dtypes are kept: float16 (half), float32, uint32 (integer labels stay exact).
A multi-layer file is just dotted channel names ("all.semantic", "position.X").
"""

from __future__ import annotations

import os
import sys
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import OpenEXR

from common.files import write_with

from .layout import DatasetError

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


@contextmanager
def _quiet_c_output():
    """Silence what the OpenEXR C++ library prints on a damaged file (its error comes back as an
    exception, which we report as one line)."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, 1)
        os.dup2(null, 2)
        yield
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, null):
            os.close(fd)


def read_exr_checked(path) -> dict:
    """Every channel of an EXR; a missing or damaged file is one DatasetError line."""
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: missing")
    try:
        with _quiet_c_output():
            return read_exr(path)
    except Exception as exc:  # OpenEXR raises plain Exceptions on damaged files
        raise DatasetError(f"{path}: not a readable EXR (truncated or corrupt: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__})") from None
