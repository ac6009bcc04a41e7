"""Coverage labels from a supersampled top-down pass: n x n sub-samples per label cell.

A point sample at the cell centre loses a 10-15 cm line that falls between two centres (cells are
12.5 cm). Rendered at n times the label resolution, each cell holds n x n sub-samples at sub-cell
centres; a cell is paint (lane marking, crosswalk, stop line) when paint covers at least
`marking_share` of them, otherwise it takes the class most of them have (vehicles and street by
majority; a tie goes to the class earlier in PRIORITY, then the lower id). Its instance is that
of the first sub-sample of the chosen class, its height the highest of those sub-samples. With
n = 2 and marking_share 0.25 any paint strip wider than res / 2 (6.25 cm) marks every cell row it
crosses.
"""

from __future__ import annotations

import numpy as np

from .classes import CLASS_IDS, NUM_FINE_CLASSES

PAINT = ("lane_marking", "crosswalk", "stop_line")
PRIORITY = ("vehicle", "road", "parking")


def blocks(a: np.ndarray, n: int) -> np.ndarray:
    """(rows * n, cols * n) -> (rows, cols, n * n): each cell's sub-samples, row-major."""
    r, c = a.shape[0] // n, a.shape[1] // n
    if a.shape != (r * n, c * n):
        raise ValueError(f"supersampled pass is {a.shape}, not a multiple of {n}")
    return a.reshape(r, n, c, n).transpose(0, 2, 1, 3).reshape(r, c, n * n)


def reduce_supersampled(semantic: np.ndarray, instance: np.ndarray, height: np.ndarray, n: int,
                        marking_share: float = 0.25):
    """(semantic, instance, height) at the label grid from passes rendered n times finer."""
    if n == 1:
        return semantic, instance, height
    sem = blocks(np.clip(semantic, 0, NUM_FINE_CLASSES - 1).astype(np.int64), n)
    ins, hgt = blocks(instance, n), blocks(height, n)
    rows, cols, k = sem.shape
    flat = (np.arange(rows * cols, dtype=np.int64)[:, None] * NUM_FINE_CLASSES + sem.reshape(-1, k)).reshape(-1)
    counts = np.bincount(flat, minlength=rows * cols * NUM_FINE_CLASSES).astype(np.float32)
    counts = counts.reshape(rows, cols, NUM_FINE_CLASSES)
    # ties: PRIORITY first, then the lower id (bonuses well under one sub-sample)
    bonus = -np.arange(NUM_FINE_CLASSES, dtype=np.float32) * 1e-3
    for i, name in enumerate(PRIORITY):
        bonus[CLASS_IDS[name]] = 0.1 - i * 1e-2
    paint_ids = np.array([CLASS_IDS[p] for p in PAINT])
    paint = counts[..., paint_ids]
    majority = np.argmax(counts + bonus, axis=-1)
    painted = paint.sum(-1) >= marking_share * k - 1e-6
    chosen = np.where(painted, paint_ids[np.argmax(paint + bonus[paint_ids], axis=-1)], majority)
    match = sem == chosen[..., None]
    first = np.argmax(match, axis=-1)[..., None]
    out_i = np.take_along_axis(ins, first, -1)[..., 0]
    out_h = np.where(match, hgt, -np.inf).max(-1).astype(height.dtype)
    return chosen.astype(semantic.dtype), out_i.astype(instance.dtype), out_h
