"""Per-camera training targets of a frame, derived once from its EXR passes into one small file.

    <frame>/camera_targets.npy    one (H, W) numpy array of a structured dtype at the rendered
                                  fisheye size, two fields per camera <name>:
        distance_<name>   uint16, ray distance in centimetres (the EXR `distance` pass);
                          0 where the ray hits nothing (sky, outside the lens) or beyond 655.34 m
        semantic_<name>   uint8, fine semantic class (the EXR `semantic` pass; `ego` = the car's body)

The model's loader (`model.feature_targets`) needs only these two passes of the EXR, at a few
hundred pixels per camera (one per feature pixel). They are cut to 3 bytes a pixel (a fifth of the
EXR) and left uncompressed, so `read_camera_targets` memory-maps the file and a sample reads only
the pixels it samples (a compressed file would cost a whole decompression per sample).
The file is written by the fuse stage (`dataset_tools.fuse.fuse_dataset`, atomically), never by a
reader: `camera_targets` reads it, and derives the targets in memory, writing nothing, for a data
set fused before the file existed (slower: `python -m dataset_tools fuse DATA` writes them).
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from common.files import write_bytes_atomic

from .exr import read_exr
from .layout import CAMERA_TARGETS, DatasetError, FrameFiles

DISTANCE_SCALE = 100.0  # stored units per metre (centimetres)
NO_HIT = 0  # stored distance where the ray hits nothing (or beyond the uint16 range)
_MAX_CM = np.iinfo(np.uint16).max - 1


def targets_path(frame_dir) -> Path:
    return Path(frame_dir) / CAMERA_TARGETS


def encode_distance(distance_m: np.ndarray) -> np.ndarray:
    """float ray distance (m; sky is 1e10) -> uint16 centimetres, NO_HIT where none or out of range."""
    cm = np.rint(np.asarray(distance_m, np.float64) * DISTANCE_SCALE)
    ok = np.isfinite(cm) & (cm >= 1) & (cm <= _MAX_CM)
    return np.where(ok, cm, NO_HIT).astype(np.uint16)


def decode_distance(cm: np.ndarray) -> np.ndarray:
    """uint16 centimetres -> float32 metres, NaN where NO_HIT."""
    d = np.asarray(cm).astype(np.float32) / np.float32(DISTANCE_SCALE)
    return np.where(cm == NO_HIT, np.float32(np.nan), d)


def _channel(channels: dict, path: Path, name: str) -> np.ndarray:
    if name not in channels:
        raise DatasetError(f"{path}: no channel '{name}' (has: {', '.join(sorted(channels))})")
    return np.asarray(channels[name])


def derive_camera_targets(frame_dir, cameras) -> np.ndarray:
    """The (H, W) structured array {distance_<name>: uint16 cm, semantic_<name>: uint8 fine class}
    from each camera's EXR (the cameras' images must be of one size)."""
    files = FrameFiles(frame_dir)
    out = {}
    for name in cameras:
        path = files.camera_exr(name)
        if not path.is_file():
            raise DatasetError(f"{path}: missing (the camera targets are derived from the EXR passes)")
        try:
            ch = read_exr(path)
        except Exception as exc:  # OpenEXR raises plain Exceptions on damaged files
            raise DatasetError(f"{path}: not a readable EXR ({type(exc).__name__})") from None
        dist, sem = _channel(ch, path, "distance"), _channel(ch, path, "semantic")
        if dist.shape != sem.shape:
            raise DatasetError(f"{path}: channels 'distance' {dist.shape} and 'semantic' {sem.shape} differ in size")
        sem = np.rint(sem).astype(np.int64) if sem.dtype.kind == "f" else sem.astype(np.int64)
        if sem.min(initial=0) < 0 or sem.max(initial=0) > 255:
            raise DatasetError(f"{path}: channel 'semantic' holds ids outside 0..255")
        if out and dist.shape != next(iter(out.values())).shape:
            raise DatasetError(f"{path}: {dist.shape[1]}x{dist.shape[0]} pixels, the frame's other cameras differ")
        out[f"distance_{name}"] = encode_distance(dist)
        out[f"semantic_{name}"] = sem.astype(np.uint8)
    shape = next(iter(out.values())).shape
    table = np.zeros(shape, np.dtype([(k, v.dtype) for k, v in out.items()]))
    for k, v in out.items():
        table[k] = v
    return table


def write_camera_targets(frame_dir, table: np.ndarray) -> None:
    buf = io.BytesIO()
    np.save(buf, table, allow_pickle=False)
    write_bytes_atomic(targets_path(frame_dir), buf.getvalue())


def camera_targets_bytes(frame_dir, cameras) -> bytes:
    """The frame's camera_targets.npy as bytes for `cameras` (a shard member): the file when it holds
    them, else derived from the EXRs (nothing is written into the frame)."""
    if read_camera_targets(frame_dir, cameras) is not None:
        return targets_path(frame_dir).read_bytes()
    buf = io.BytesIO()
    np.save(buf, derive_camera_targets(frame_dir, cameras), allow_pickle=False)
    return buf.getvalue()


def decode_camera_targets(data: bytes, source, cameras) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """read_camera_targets of a camera_targets.npy held in memory (bytes or a memoryview, e.g. of a
    mapped shard); every camera must be there. The table is a read-only view of `data`, not a copy
    (a sample reads a few hundred of its pixels, as from the memory-mapped file)."""
    try:
        fmt = np.lib.format
        head = io.BytesIO(bytes(data[:4096]))  # magic and header (np.save writes a few hundred bytes at most)
        read_header = {(1, 0): fmt.read_array_header_1_0, (2, 0): fmt.read_array_header_2_0}.get(fmt.read_magic(head))
        if read_header is None:  # a version np.save writes only for odd field names: np.load's copy
            table = np.load(io.BytesIO(data), allow_pickle=False)
        else:
            shape, fortran, dtype = read_header(head)
            if dtype.hasobject or fortran:
                raise ValueError("not a plain C-order array")
            table = np.frombuffer(data, dtype, count=int(np.prod(shape)), offset=head.tell()).reshape(shape)
    except (OSError, ValueError, EOFError, TypeError) as exc:
        raise DatasetError(f"{source}: not a readable camera targets file ({type(exc).__name__})") from None
    fields = table.dtype.names or ()
    missing = [n for n in cameras if f"distance_{n}" not in fields or f"semantic_{n}" not in fields]
    if table.ndim != 2 or missing:
        raise DatasetError(f"{source}: not a camera targets file for cameras {', '.join(cameras)}")
    return _per_camera(table, cameras)


def _per_camera(table: np.ndarray, cameras) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    return {n: (table[f"distance_{n}"], table[f"semantic_{n}"]) for n in cameras}


def read_camera_targets(frame_dir, cameras) -> dict[str, tuple[np.ndarray, np.ndarray]] | None:
    """{name: (distance uint16 cm, semantic uint8 fine)} (H, W) memory-mapped views of the file;
    None when the file is missing or lacks one of `cameras`."""
    path = targets_path(frame_dir)
    if not path.is_file():
        return None
    try:
        table = np.load(path, mmap_mode="r", allow_pickle=False)
    except (OSError, ValueError, EOFError) as exc:
        raise DatasetError(f"{path}: not a readable camera targets file ({type(exc).__name__}); delete it to derive it again") from None
    fields = table.dtype.names or ()
    if table.ndim != 2 or any(table.dtype[k] != np.uint16 for k in fields if k.startswith("distance_")):
        raise DatasetError(f"{path}: not a camera targets file ((H, W) of distance_<camera> uint16 and semantic_<camera> uint8); delete it to derive it again")
    if not all(f"distance_{n}" in fields and f"semantic_{n}" in fields for n in cameras):
        return None
    return _per_camera(table, cameras)


def camera_targets(frame_dir, cameras) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The frame's targets for `cameras`: the file's, else derived from the EXRs in memory (the data
    set is not written)."""
    found = read_camera_targets(frame_dir, cameras)
    if found is not None:
        return found
    return _per_camera(derive_camera_targets(frame_dir, cameras), cameras)
