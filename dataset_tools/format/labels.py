"""A frame's label PNGs (labels/semantic.png, instance.png, visibility.png): the one encoder
(`write_labels`), decoder (`read_labels`) and check (`label_problems`; `label_damage`, without
decoding, for a resume).

    semantic    uint8, training class id per cell
    instance    uint16, vehicle instance id per cell (0 elsewhere)
    visibility  uint16, round(p(o) * VISIBILITY_SCALE)
"""

from __future__ import annotations

import numpy as np

from common.files import write_bytes_atomic

from .layout import VISIBILITY_SCALE, DatasetError, FrameFiles
from .png import decode_png, encode_png, read_png

LABEL_DTYPES = {"semantic": np.uint8, "instance": np.uint16, "visibility": np.uint16}
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
PNG_END = b"\x00\x00\x00\x00IEND\xaeB`\x82"  # the IEND chunk every whole PNG ends with


def write_labels(frame_dir, labels: dict) -> None:
    """labels: semantic, instance (integer arrays) and visibility (float p(o), clipped to [0, 1]);
    each PNG atomically, visibility last (its presence marks the frame done)."""
    files = FrameFiles(frame_dir)
    files.labels.mkdir(exist_ok=True)
    vis16 = np.rint(np.clip(labels["visibility"], 0, 1) * VISIBILITY_SCALE).astype(np.uint16)
    write_bytes_atomic(files.semantic, encode_png(np.asarray(labels["semantic"]).astype(np.uint8, copy=False)))
    write_bytes_atomic(files.instance, encode_png(np.asarray(labels["instance"]).astype(np.uint16, copy=False)))
    write_bytes_atomic(files.visibility, encode_png(vis16))


def _paths(files: FrameFiles) -> dict:
    return {"semantic": files.semantic, "instance": files.instance, "visibility": files.visibility}


def _check(arrays: dict, paths: dict, shape, num_classes) -> list[str]:
    problems = []
    if shape is not None:
        problems += [f"{paths[k]}: {a.shape} pixels, the label grid is {tuple(shape)}"
                     for k, a in arrays.items() if a.shape != tuple(shape)]
    elif len({a.shape for a in arrays.values()}) > 1:
        problems.append(f"{paths['semantic'].parent}: label shapes differ ("
                        + ", ".join(f"{k} {a.shape}" for k, a in arrays.items()) + ")")
    sem = arrays.get("semantic")
    if num_classes is not None and sem is not None and sem.max(initial=0) >= num_classes:
        problems.append(f"{paths['semantic']}: class id {int(sem.max())}, beyond the {num_classes} classes of the data set")
    return problems


def _png_damage(path, dtype, shape) -> str | None:
    """Why a label PNG cannot be trusted, from its first 26 and last 12 bytes: missing, empty, not
    a PNG, cut short (no IEND at the end), not one-channel of the label's bit depth, or not
    `shape` (H, W) pixels. None when it looks whole."""
    try:
        with open(path, "rb") as f:
            head = f.read(26)
            size = f.seek(0, 2)
            f.seek(max(0, size - len(PNG_END)))
            tail = f.read()
    except FileNotFoundError:
        return "missing"
    except OSError as exc:
        return f"cannot read ({exc.strerror})"
    if size == 0:
        return "empty (0 bytes)"
    if len(head) < 26 or not head.startswith(PNG_SIGNATURE) or head[12:16] != b"IHDR":
        return "not a PNG"
    if tail != PNG_END:
        return f"cut short ({size} bytes, no PNG end)"
    width, height = int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
    if head[24] != 8 * np.dtype(dtype).itemsize or head[25] != 0:
        return f"bit depth {head[24]}, colour type {head[25]}: not a {np.dtype(dtype)} label"
    if shape is not None and (height, width) != tuple(shape):
        return f"{(height, width)} pixels, the label grid is {tuple(shape)}"
    return None


def label_damage(frame_dir, shape=None) -> str | None:
    """The first label PNG of the frame that is missing or damaged, as `path: what`, checked
    cheaply (`_png_damage`: header, end and size, no decoding); None when all three look whole."""
    for k, path in _paths(FrameFiles(frame_dir)).items():
        what = _png_damage(path, LABEL_DTYPES[k], shape)
        if what:
            return f"{path}: {what}"
    return None


def label_problems(frame_dir, shape=None, num_classes: int | None = None) -> list[str]:
    """One line per problem of the frame's label PNGs: missing or unreadable, wrong pixel type or
    channels, a size other than `shape` (else: sizes that differ), a semantic id >= num_classes."""
    paths = _paths(FrameFiles(frame_dir))
    arrays, problems = {}, []
    for k, path in paths.items():
        try:
            arrays[k] = read_png(path, LABEL_DTYPES[k], 1)
        except DatasetError as exc:
            problems.append(str(exc))
    return problems + _check(arrays, paths, shape, num_classes)


def read_labels(frame_dir, num_classes: int | None = None, shape=None, instance: bool = True) -> dict:
    """semantic (H, W) uint8, instance (H, W) uint16, visibility (H, W) float32 in [0, 1]; the
    first problem label_problems would list raises DatasetError. `instance=False`: the instance
    PNG is not read (a training sample has no use for it)."""
    paths = _paths(FrameFiles(frame_dir))
    return _labels({k: read_png(path, LABEL_DTYPES[k], 1) for k, path in paths.items() if instance or k != "instance"},
                   paths, num_classes, shape)


def decode_labels(blobs: dict, paths: dict, num_classes: int | None = None, shape=None, instance: bool = True) -> dict:
    """read_labels of the PNGs held in memory (`blobs`: semantic, instance, visibility -> bytes;
    `paths`: the same keys -> what names each in errors, e.g. a shard member)."""
    return _labels({k: decode_png(blobs[k], paths[k], LABEL_DTYPES[k], 1) for k in LABEL_DTYPES if instance or k != "instance"},
                   paths, num_classes, shape)


def _labels(arrays: dict, paths: dict, num_classes, shape) -> dict:
    problems = _check(arrays, paths, shape, num_classes)
    if problems:
        raise DatasetError(problems[0])
    arrays["visibility"] = arrays["visibility"].astype(np.float32) / VISIBILITY_SCALE
    return arrays
