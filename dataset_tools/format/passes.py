"""Reading a rendered frame's EXR passes: per camera distance, semantic and instance, and the
top-down layers ('all.' first hit from above, 'ground.' with overhead occluders hidden).

    p = read_frame_passes(frame_dir)   # FramePasses(meta, rig, cameras {name: passes}, topdown)
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .exr import read_exr_checked
from .layout import DatasetError, FrameFiles
from .meta import FrameMeta, read_meta


def find_channel(channels: dict, path, *names, required=True):
    """The channel whose name (or its last dotted part, or its layer with one channel) is one of
    `names`, case-insensitively."""
    low = {k.lower(): k for k in channels}
    for n in names:
        n = n.lower()
        if n in low:
            return channels[low[n]]
        hits = [k for lk, k in low.items() if lk.rsplit(".", 1)[-1] == n or lk.split(".", 1)[0] == n]
        if len(hits) == 1:
            return channels[hits[0]]
    if required:
        raise DatasetError(f"{path}: no channel '{names[0]}' (has: {', '.join(sorted(channels))})")
    return None


def _labels_int(a, path, what) -> np.ndarray:
    a = np.asarray(a)
    if a.dtype.kind == "f":
        if not np.all(np.isfinite(a)):
            raise DatasetError(f"{path}: channel '{what}' has NaN or inf")
        a = np.rint(a)
    return a.astype(np.int64)


def read_camera_passes(path) -> dict:
    """distance (H, W) float32, semantic and instance (H, W) int64 from a cam_<name>.exr."""
    ch = read_exr_checked(path)
    dist = find_channel(ch, path, "distance")
    if np.isnan(dist).any():
        raise DatasetError(f"{path}: channel 'distance' has NaN")
    return {
        "distance": np.asarray(dist, np.float32),
        "semantic": _labels_int(find_channel(ch, path, "semantic"), path, "semantic"),
        "instance": _labels_int(find_channel(ch, path, "instance"), path, "instance"),
    }


def read_topdown(frame_dir) -> dict:
    """Top-down passes: semantic/instance with overhead occluders hidden ('semantic', 'instance',
    from the 'ground.' layer) and as first seen from above ('semantic_all', 'instance_all', from
    'all.'), (rows, cols) int64; 'height' / 'height_all' float32 where present."""
    path = FrameFiles(frame_dir).topdown
    ch = read_exr_checked(path)
    out = {}
    for layer, suffix in (("all", "_all"), ("ground", "")):
        sub = {k.split(".", 1)[1]: v for k, v in ch.items() if k.lower().startswith(layer + ".")}
        if not sub:
            raise DatasetError(f"{path}: no '{layer}.' layer (has: {', '.join(sorted(ch))})")
        out["semantic" + suffix] = _labels_int(find_channel(sub, path, "semantic"), path, f"{layer}.semantic")
        out["instance" + suffix] = _labels_int(find_channel(sub, path, "instance"), path, f"{layer}.instance")
        h = find_channel(sub, path, "height", required=False)
        if h is not None:
            out["height" + suffix] = np.asarray(h, np.float32)
    return out


class FramePasses(NamedTuple):
    meta: FrameMeta
    rig: object  # geometry Rig, its cameras at the rendered image size
    cameras: dict  # {name: read_camera_passes}
    topdown: dict  # read_topdown


def read_frame_passes(frame_dir) -> FramePasses:
    """meta.json, the rig (its cameras resized to the rendered image size when they differ), every
    rig camera's passes and the top-down passes of a rendered frame."""
    files = FrameFiles(frame_dir)
    meta = read_meta(files.dir)
    rig = meta.camera_rig()
    cameras = {rc.name: read_camera_passes(files.camera_exr(rc.name)) for rc in rig}
    sizes = {n: p["distance"].shape for n, p in cameras.items()}
    if any(sizes[rc.name] != (rc.camera.height, rc.camera.width) for rc in rig):
        from geometry.rig import Rig, RigCamera

        rig = Rig([RigCamera(rc.name, rc.camera.resized(sizes[rc.name][1], sizes[rc.name][0]), rc.cam_to_ego) for rc in rig], rig.name)
    return FramePasses(meta, rig, cameras, read_topdown(files.dir))
