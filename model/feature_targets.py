"""Camera-view targets at the feature resolution: the depth bin and the training class of what
each feature pixel's ray hits, for the cameras exactly as the model sees them.

A feature pixel (i, j) of stride s is centred on input-image position (s j + (s - 1) / 2,
s i + (s - 1) / 2) (model.frustum). That position is taken back through the inverse of the
camera's view transform (model.augment.view_matrix: the scale, rotation and crop warp_image
applied to the image) to the model camera's image, rounded to the nearest pixel; for the rectified
baseline that pixel is taken on through the rectifier's own remap table to the fisheye, nearest
again. The target is the rendered pass at that fisheye pixel (dataset_tools.format.camera_targets):

    depth     (N, h, w) int64, the index of the model's ray-distance bin holding the distance;
              -1 where masked: sky / no hit, the ego car's body, outside the bins, padding, or off
              the image after the transform
    semantic  (N, h, w) int64, the training class (0 = invalid: sky, ego body, off the image)
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from dataset_tools.format.camera_targets import NO_HIT, decode_distance
from dataset_tools.labels.classes import CLASS_IDS, DEFAULT_CLASS_MAP, NUM_FINE_CLASSES

from .augment import move_pixels, view_matrix
from .rectified import source_maps

EGO = CLASS_IDS["ego"]


def train_lut(class_names) -> np.ndarray:
    """fine id -> index in `class_names` through the paper's class map (0 where the mapped class
    is not among them)."""
    lut = np.zeros(NUM_FINE_CLASSES, np.int64)
    for fine, coarse in DEFAULT_CLASS_MAP.items():
        lut[CLASS_IDS[fine]] = class_names.index(coarse) if coarse in class_names else 0
    return lut


def _nearest(x: np.ndarray) -> np.ndarray:
    return np.floor(x + 0.5).astype(np.int64)


@lru_cache(maxsize=8)
def _feature_centres(input_size: tuple[int, int], s: int):
    """(u, v, on_input) (h, w): each stride-s feature pixel's centre in the input image, and
    whether it lies on the image rather than the encoder's padding."""
    w_in, h_in = input_size
    v, u = np.meshgrid(np.arange(math.ceil(h_in / s)) * s + (s - 1) / 2, np.arange(math.ceil(w_in / s)) * s + (s - 1) / 2,
                       indexing="ij")
    return u, v, (u <= w_in - 0.5) & (v <= h_in - 0.5)


def source_pixels(frustum, rc, t, rect=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(row, col, valid) (h, w) of the rendered-image pixel each feature pixel of camera `rc`
    (a camera of frustum.rig: the fisheye, or its cylinder with `rect`) samples under view transform `t`."""
    u, v, on_input = _feature_centres(tuple(frustum.input_size), frustum.stride)
    inv = np.linalg.inv(view_matrix(rc.camera, t))
    su, sv = move_pixels(inv, u, v)
    col, row = _nearest(su), _nearest(sv)
    cam = rc.camera
    ok = on_input & (col >= 0) & (col < cam.width) & (row >= 0) & (row < cam.height)
    if rect is not None:
        mx, my = source_maps(rect, rc.name)
        r, c = np.clip(row, 0, cam.height - 1), np.clip(col, 0, cam.width - 1)
        fu, fv = mx[r, c], my[r, c]
        fish = rect.source[rc.name].camera
        col, row = _nearest(fu), _nearest(fv)
        ok &= (fu >= -0.5) & (fv >= -0.5) & (col >= 0) & (col < fish.width) & (row >= 0) & (row < fish.height)
    return np.where(ok, row, 0), np.where(ok, col, 0), ok


def feature_passes(frustum, rc, t, passes, rect=None) -> tuple[np.ndarray, np.ndarray]:
    """(distance (h, w) float32 metres, NaN where none; fine class (h, w) int64, -1 where none) at
    each feature pixel; `passes` = (distance uint16 cm, semantic uint8) of the rendered image."""
    dist_cm, sem = passes
    row, col, ok = source_pixels(frustum, rc, t, rect)
    d = decode_distance(np.where(ok, dist_cm[row, col], NO_HIT))
    return d, np.where(ok, sem[row, col].astype(np.int64), -1)


def distance_bin(distance: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Index of the bin [edge_k, edge_k+1) holding each distance; -1 outside the bins or NaN."""
    k = np.searchsorted(edges, np.nan_to_num(distance, nan=-1.0), side="right") - 1
    return np.where(np.isfinite(distance) & (k >= 0) & (k < len(edges) - 1), k, -1).astype(np.int64)


def camera_targets(frustum, transforms, passes: dict, lut: np.ndarray, rect=None) -> tuple[np.ndarray, np.ndarray]:
    """(depth (N, h, w) int64, semantic (N, h, w) int64) of frustum.rig's cameras under
    `transforms`; `passes` {name: (distance cm, fine semantic)} of the rendered images."""
    depth, semantic = [], []
    for rc, t in zip(frustum.rig, transforms):
        d, fine = feature_passes(frustum, rc, t, passes[rc.name], rect)
        ego = fine == EGO
        depth.append(np.where(ego, -1, distance_bin(d, frustum.edges)))
        semantic.append(np.where(fine >= 0, lut[np.clip(fine, 0, len(lut) - 1)], 0))
    return np.stack(depth), np.stack(semantic)
