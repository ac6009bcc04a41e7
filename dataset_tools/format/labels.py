"""A frame's label PNGs (labels/semantic.png, instance.png, visibility.png): the one encoder
(`write_labels`), decoder (`read_labels`) and check (`label_problems`).

    semantic    uint8, training class id per cell
    instance    uint16, vehicle instance id per cell (0 elsewhere)
    visibility  uint16, round(p(o) * VISIBILITY_SCALE)
"""

from __future__ import annotations

import numpy as np

from common.files import write_bytes_atomic

from .layout import VISIBILITY_SCALE, DatasetError, FrameFiles
from .png import encode_png, read_png

LABEL_DTYPES = {"semantic": np.uint8, "instance": np.uint16, "visibility": np.uint16}


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


def read_labels(frame_dir, num_classes: int | None = None, shape=None) -> dict:
    """semantic (H, W) uint8, instance (H, W) uint16, visibility (H, W) float32 in [0, 1]; the
    first problem label_problems would list raises DatasetError."""
    paths = _paths(FrameFiles(frame_dir))
    arrays = {k: read_png(path, LABEL_DTYPES[k], 1) for k, path in paths.items()}
    problems = _check(arrays, paths, shape, num_classes)
    if problems:
        raise DatasetError(problems[0])
    arrays["visibility"] = arrays["visibility"].astype(np.float32) / VISIBILITY_SCALE
    return arrays
