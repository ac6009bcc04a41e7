"""Visibility p(o) of BEV cells from the fisheye cameras' distance passes (the paper's occlusion map).

Each camera pixel's ray (from `geometry`, computed once per rig) times its rendered distance is a
3D point in the ego frame. Points whose fine class is ground or vehicle are counted per BEV cell,
each pixel's weight is spread along the surface it lies on (spread_counts: never across an
occlusion edge), the counts are summed over a circular kernel, divided by tau and clipped to
[0, 1]. A vehicle seen by at least k pixels in any camera is visible over its whole top-down
footprint. docs/label-fidelity.md derives the rules.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import cv2
import numpy as np

# Distances at or beyond this are "nothing hit" (Cycles writes 1e10 on background).
MAX_DISTANCE = 1e4


@dataclass(frozen=True)
class RayTable:
    """One camera's unit rays in the ego frame, per pixel (zero where the model is not valid)."""

    name: str
    shape: tuple[int, int]  # (H, W) of the camera's image
    origin: np.ndarray  # (3,) camera centre, ego frame, float32
    rays: np.ndarray  # (H, W, 3) float32 unit rays
    valid: np.ndarray  # (H, W) bool: the model maps the pixel to a ray


_TABLES: dict[str, RayTable] = {}


def camera_table(rc) -> RayTable:
    """The ray table of one RigCamera, through geometry (RigCamera.rays_ego); cached per calibration."""
    key = json.dumps({"name": rc.name, **rc.to_dict(), "m": np.asarray(rc.cam_to_ego).round(12).tolist()}, sort_keys=True)
    t = _TABLES.get(key)
    if t is None:
        origin, rays, valid = rc.rays_ego()
        valid = np.asarray(valid).astype(bool)
        rays = np.where(valid[..., None], np.nan_to_num(np.asarray(rays)), 0).astype(np.float32)
        t = RayTable(rc.name, valid.shape, np.asarray(origin, np.float32), rays, valid)
        if len(_TABLES) >= 64:
            _TABLES.pop(next(iter(_TABLES)))
        _TABLES[key] = t
    return t


def ray_tables(rig) -> dict[str, RayTable]:
    """Ray tables of every camera of a geometry Rig, computed once per camera calibration."""
    return {rc.name: camera_table(rc) for rc in rig}


def hits(table: RayTable, distance: np.ndarray, group: np.ndarray | None = None) -> np.ndarray:
    """(H, W) int8: the pixel's group (1 if `group` is None) where its ray is valid and hit
    something, else 0. group: (H, W) int8, 0 for pixels to leave out (e.g. 1 ground, 2 vehicle)."""
    distance = np.asarray(distance)
    if distance.shape != table.shape:
        raise ValueError(f"camera '{table.name}': distance pass is {distance.shape}, the rig says {table.shape}")
    ok = table.valid & (distance > 0) & (distance < MAX_DISTANCE)  # NaN fails both
    g = np.ones(table.shape, np.int8) if group is None else np.asarray(group, np.int8)
    return np.where(ok, g, 0).astype(np.int8)


def lift(table: RayTable, distance: np.ndarray, group: np.ndarray | None = None):
    """Ego-frame (x, y) (M, 2) of the pixels that hit something, their flat pixel indices, ray
    distances and groups (M,)."""
    g = hits(table, distance, group)
    idx = np.flatnonzero(g)
    d = np.asarray(distance, np.float32).reshape(-1)[idx]
    xy = table.origin[:2] + table.rays.reshape(-1, 3)[idx, :2] * d[:, None]
    return xy, idx, d, g.reshape(-1)[idx]


def cell_index(grid, xy: np.ndarray):
    """Flat cell index (row * cols + col) of ego (x, y) points on the grid, and which those are."""
    row, col, inside = grid.cell_of(xy)
    return row[inside] * grid.cols + col[inside], inside


def count_points(grid, xy: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """(rows, cols) float32 (weighted) count of ego (x, y) points per cell."""
    flat, inside = cell_index(grid, xy)
    w = None if weights is None else np.asarray(weights)[inside]
    return np.bincount(flat, w, minlength=grid.rows * grid.cols).reshape(grid.shape).astype(np.float32)


@dataclass(frozen=True)
class SurfaceRule:
    """When two neighbouring pixels lie on one continuous, seen surface (see spread_counts).

    Both hit the same object (instance id). Paint (lane markings, crosswalks, stop lines) is its
    own object lying on the road, so a paint pixel also joins any ground pixel within z_tol of its
    height. On the ground the second point must lie where the surface's slope puts it: heights
    differ by at most z_tol + max_grade * horizontal gap. Ray b then meets the surface through
    point a where the pixel footprint predicts, so the gap is the footprint; across a kerb (its
    shadow starts 0.15 m up and ends on the road) it is not. On a vehicle the 3D gap may be at most
    the footprint of a surface seen at min_grazing_deg or steeper:
    distance * sin(angle between the two rays) / sin(min_grazing_deg) + z_tol."""

    z_tol: float = 0.05
    max_grade: float = 0.02
    min_grazing_deg: float = 15.0


def lift_points(table: RayTable, distance: np.ndarray) -> np.ndarray:
    """(H, W, 3) ego-frame points of every pixel's hit (meaningless where `hits` is 0)."""
    d = np.where(table.valid & (distance < MAX_DISTANCE) & np.isfinite(distance), distance, 0).astype(np.float32)
    return table.origin + table.rays * d[..., None]


def same_surface(pa, pb, ga, ia, ib, paint, ra, rb, da, rule: SurfaceRule) -> np.ndarray:
    """Bool per neighbour pair (a, b), both of group ga (1 ground, 2 vehicle): on one seen surface
    (SurfaceRule). pa, pb: (..., 3) points; ia, ib: instance ids; paint: a or b is paint;
    ra, rb: (..., 3) unit rays; da: distance of a."""
    d = pb - pa
    dz = np.abs(d[..., 2])
    hgap = np.sqrt(d[..., 0] ** 2 + d[..., 1] ** 2)
    tol = np.float32(rule.z_tol)
    ground = (ga == 1) & ((ia == ib) | (paint & (dz <= tol)))
    ground &= dz <= tol + np.float32(rule.max_grade) * hgap
    sin_rays = np.linalg.norm(np.cross(ra, rb), axis=-1)
    footprint = da * sin_rays / np.float32(np.sin(np.radians(rule.min_grazing_deg))) + tol
    vehicle = (ga == 2) & (ia == ib) & (np.sqrt(hgap * hgap + dz * dz) <= footprint)
    return ground | vehicle


def spread_counts(grid, points: np.ndarray, distance: np.ndarray, group: np.ndarray, instance: np.ndarray,
                  rays: np.ndarray, step: float, paint: np.ndarray | None = None,
                  rule: SurfaceRule = SurfaceRule(), max_steps: int = 256) -> np.ndarray:
    """(rows, cols) float32 counts of hit pixels, each pixel's unit weight spread along the surface
    towards its right and lower neighbours.

    Far from a camera one pixel row covers metres of ground (about 2 m at 20 m from a camera 0.6 m
    high), so counting each point in its one cell leaves stripes of empty cells between pixel rows.
    Here half of a pixel's weight goes, in sub-points at most `step` metres apart, along the segment
    to its right neighbour and half along the one to its lower neighbour, when both pixels lie on
    one seen surface (`SurfaceRule`: same group, same object, and the gap that the surface's slope
    and the pixel footprint predict: never across a kerb, a vehicle's edge or between two vehicles);
    otherwise that half stays on the pixel's point. The total weight is the pixel count, so counts
    keep the paper's meaning of pixel occurrences.

    points: (H, W, 3) lifted ego points (lift_points); distance: (H, W) ray distances; group: (H, W)
    int8, 0 for pixels left out, 1 ground, 2 vehicle; instance: (H, W) instance ids; rays: (H, W, 3)
    unit rays (RayTable.rays); paint: (H, W) bool, pixels on paint (None: none).
    """
    h, w = group.shape
    # work in fractional cell coordinates: row = (x_max - x) / res, col = (y_max - y) / res
    rc = np.empty((2, h, w), np.float32)
    rc[0] = (np.float32(grid.x_max) - points[..., 0]) / np.float32(grid.res)
    rc[1] = (np.float32(grid.y_max) - points[..., 1]) / np.float32(grid.res)
    instance = np.asarray(instance)
    paint = np.zeros(group.shape, bool) if paint is None else np.asarray(paint, bool)
    step_c = np.float32(step / grid.res)
    own = (group > 0).astype(np.float32)  # weight left on each pixel's own point
    rows, cols = rc[0].reshape(-1), rc[1].reshape(-1)
    cells, weights = [], []
    for a, b, right in (((slice(None), slice(0, w - 1)), (slice(None), slice(1, w)), True),
                        ((slice(0, h - 1), slice(None)), (slice(1, h), slice(None)), False)):
        dr = rc[0][b] - rc[0][a]
        dc = rc[1][b] - rc[1][a]
        length = np.sqrt(dr * dr + dc * dc)
        # segments within one step stay on the pixel's point: the same cells, far cheaper
        ok = (group[a] > 0) & (group[b] == group[a]) & (length > step_c)
        ra, ca = rc[0][a], rc[1][a]  # and not wholly off the grid on one side
        ok &= (np.minimum(ra, ra + dr) < grid.rows) & (np.maximum(ra, ra + dr) >= 0)
        ok &= (np.minimum(ca, ca + dc) < grid.cols) & (np.maximum(ca, ca + dc) >= 0)
        cand = np.flatnonzero(ok)
        if cand.size:
            pick = lambda x: x.reshape(-1, *x.shape[2:])[cand]  # noqa: E731
            okc = same_surface(pick(points[a]), pick(points[b]), pick(group[a]), pick(instance[a]),
                               pick(instance[b]), pick(paint[a] | paint[b]), pick(rays[a]), pick(rays[b]),
                               pick(distance[a]), rule)
            ok.reshape(-1)[cand[~okc]] = False
        own[a][ok] -= 0.5
        ia = np.flatnonzero(ok)
        if ia.size == 0:
            continue
        n = np.minimum(np.ceil(length.reshape(-1)[ia] / step_c), max_steps).astype(np.int32)
        rep = np.repeat(np.arange(ia.size, dtype=np.int32), n)
        first = np.repeat((np.cumsum(n) - n).astype(np.int32), n)
        nr = n.astype(np.float32)[rep]
        t = (np.arange(rep.size, dtype=np.int32) - first).astype(np.float32)
        t += np.float32(0.5)
        t /= nr
        full = ia + ia // (w - 1) if right else ia  # index in the (sliced) image -> in the whole image
        r = rows[full][rep] + dr.reshape(-1)[ia][rep] * t
        c = cols[full][rep] + dc.reshape(-1)[ia][rep] * t
        cells.append((r, c))
        weights.append(np.float32(0.5) / nr)
    m = group > 0
    cells.append((rc[0][m], rc[1][m]))
    weights.append(own[m])
    r = np.concatenate([x[0] for x in cells])
    c = np.concatenate([x[1] for x in cells])
    wt = np.concatenate(weights)
    inside = (r >= 0) & (r < grid.rows) & (c >= 0) & (c < grid.cols)
    flat = r[inside].astype(np.int32) * grid.cols + c[inside].astype(np.int32)
    return np.bincount(flat, wt[inside], minlength=grid.rows * grid.cols).reshape(grid.shape).astype(np.float32)


def disk_kernel(radius_cells: float) -> np.ndarray:
    """Circular (disk) kernel of 0/1 weights: cells whose centre is within the radius."""
    r = int(np.floor(radius_cells))
    yy, xx = np.mgrid[-r : r + 1, -r : r + 1]
    return (xx * xx + yy * yy <= radius_cells * radius_cells + 1e-9).astype(np.float32)


def kernel_sum(counts: np.ndarray, radius_cells: float) -> np.ndarray:
    """Sum of counts over a disk around each cell (zero outside the grid)."""
    k = disk_kernel(radius_cells)
    return cv2.filter2D(counts.astype(np.float32), cv2.CV_32F, k, borderType=cv2.BORDER_CONSTANT)


def visibility_from_counts(counts: np.ndarray, res: float, kernel_radius_m: float, tau: float) -> np.ndarray:
    """p(o) = clip(points within kernel_radius_m of the cell / tau, 0, 1)."""
    if tau <= 0 or kernel_radius_m <= 0:
        raise ValueError(f"visibility: tau ({tau}) and kernel_radius_m ({kernel_radius_m}) must be positive")
    return np.clip(kernel_sum(counts, kernel_radius_m / res) / tau, 0.0, 1.0).astype(np.float32)


def seen_instances(instance: np.ndarray, mask: np.ndarray | None, min_pixels: int) -> np.ndarray:
    """Instance ids with at least `min_pixels` pixels under `mask` (e.g. vehicle pixels of a camera)."""
    ids = np.asarray(instance)
    ids = (ids if mask is None else ids[mask]).astype(np.int64)
    if ids.size == 0:
        return np.zeros(0, np.int64)
    uniq, n = np.unique(ids, return_counts=True)
    keep = (n >= min_pixels) & (uniq > 0)
    return uniq[keep]


def footprint_mask(topdown_instance: np.ndarray, ids) -> np.ndarray:
    """Cells whose top-down instance is one of `ids`."""
    ids = np.asarray(list(ids), dtype=np.int64)
    if ids.size == 0:
        return np.zeros(topdown_instance.shape, bool)
    return np.isin(topdown_instance.astype(np.int64), ids)
