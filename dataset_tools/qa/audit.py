"""Line-of-sight audit of the fused visibility labels.

    python -m dataset_tools audit <dataset> [--threshold 0.0005] [--metric unexplained] [--many 2.0]
                                  [--no-pixels] [--config cfg.yaml] [--json out.json]

Independent of the fisheye passes: from each camera centre (meta.json's rig) a radial sweep over
the frame's top-down height map ('ground.height', overhead occluders hidden; the ego's own box left
out) finds, per cell, the lowest height a camera can see there. A cell has a line of sight when
some part of it (up to its far edge) is seen by some camera at its surface height; a vehicle when
any of its cells has one (its label is per vehicle). Reported per frame and per distance ring
(max(|x|, |y|) from the ego origin: 0-10, 10-20, 20-25 m):

  visible_no_los  share of the ground and vehicle cells labelled visible (p(o) >= 0.5) that no
                  camera has a line of sight to (should be 0 beyond the grid and the p(o) kernel)
  beyond_kernel   share of the visible cells with no line of sight that are farther than the p(o)
                  kernel radius plus half a cell diagonal from every cell with one (what the
                  kernel and grid discreteness cannot explain)
  unexplained     of those, the share with no camera pixel at all within the kernel radius (a
                  pixel there saw the ground where the 2.5D height map cannot: under a vehicle's
                  body, through a gap): visibility that only the spreading can have made, the
                  label errors. Needs the camera passes (--no-pixels leaves it out)
  los_invisible   share of the ground cells with a line of sight and many expected camera pixels
                  (the pixel footprints of the cameras that see the cell, summed over the p(o)
                  kernel, >= --many * tau) that are labelled invisible (p(o) < 0.5)

The result goes to <dataset>/audit.json (atomically); exit EXIT_PROBLEMS (1) when the overall
--metric (default unexplained) is above --threshold (default 0.0005 of the visible cells).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import NamedTuple

import numpy as np

from common.backend import make_backend
from common.cli import ArgumentParser, print_problems, require_positive
from common.errors import InputError
from common.files import write_json_atomic
from common.resources import dataset_config

from ..format.audit_file import write_audit
from ..format.labels import read_labels
from ..format.meta import read_meta
from ..format.passes import read_frame_passes, read_topdown
from ..format.reader import DatasetIndex
from ..generation.dataset_config import load_labels
from ..labels.label_fusion import FusionConfig, effective_tau, ego_box, ego_mask
from ..labels.visibility import RayTable, count_points, kernel_sum, lift, ray_tables

RINGS = (("0-10", 0.0, 10.0), ("10-20", 10.0, 20.0), ("20-25", 20.0, math.inf))
THRESHOLD = 0.0005
VISIBLE = 0.5
N_AZIMUTH = 4096
Z_EPS = 0.02  # metres a surface may lie below the lowest seen height and still count as seen


def seen_height(grid, top: np.ndarray, origin, n_azimuth: int = N_AZIMUTH) -> np.ndarray:
    """(rows, cols) float32: the lowest height seen from `origin` (ego frame) at the far edge of each
    cell, over the height map `top` (-inf: no blocker) by a radial sweep: along n_azimuth rays the
    steepest slope (height - camera z) / r of the samples before a cell blocks what lies beyond."""
    oz = float(origin[2])
    sweep = _sweep(grid, origin, n_azimuth)
    h = np.append(np.asarray(top, np.float32).reshape(-1), np.float32(-np.inf))[sweep.sample]
    slope = np.maximum.accumulate(((h - oz) / sweep.radii).astype(np.float32), axis=1)
    before = np.where(sweep.blocked, slope[sweep.ray, sweep.last], -np.inf)
    return (oz + sweep.far * before).astype(np.float32)


class _Sweep(NamedTuple):
    sample: np.ndarray  # (n_azimuth, k) flat cell of each sample along each ray (rows * cols: outside)
    radii: np.ndarray  # (k,) the samples' distance from the origin
    ray: np.ndarray  # (rows, cols) the ray through each cell
    last: np.ndarray  # (rows, cols) the last sample before the cell's near corner (clipped)
    blocked: np.ndarray  # (rows, cols) some sample lies before it
    far: np.ndarray  # (rows, cols) the distance to the cell's far edge


_SWEEPS: dict[tuple, _Sweep] = {}


def _sweep(grid, origin, n_azimuth: int) -> _Sweep:
    """The sweep's geometry from one camera origin: the same for every frame of a scene (a rig is
    fixed to the ego), so kept for the last few origins."""
    ox, oy, oz = (float(v) for v in origin)
    key = (ox, oy, grid.x_min, grid.x_max, grid.y_min, grid.y_max, grid.res, n_azimuth)
    if key in _SWEEPS:
        return _SWEEPS[key]
    c = grid.cell_centres()
    dx, dy = c[..., 0] - ox, c[..., 1] - oy
    r_cell = np.hypot(dx, dy)
    step = grid.res / 2
    k = int(np.ceil((r_cell.max() + grid.res) / step))
    az = (np.arange(n_azimuth) + 0.5) * (2 * np.pi / n_azimuth) - np.pi
    radii = (np.arange(k) + 1) * step
    sx = ox + np.cos(az)[:, None] * radii
    sy = oy + np.sin(az)[:, None] * radii
    row, col, inside = grid.cell_of(np.stack([sx, sy], -1))
    sample = np.where(inside, row * grid.cols + col, grid.rows * grid.cols).astype(np.int32)
    j = np.floor((np.arctan2(dy, dx) + np.pi) / (2 * np.pi / n_azimuth)).astype(np.int64) % n_azimuth
    # samples before the cell's near corner block it; the cell's own column does not
    kb = np.floor((r_cell - grid.res * math.sqrt(0.5)) / step).astype(np.int64) - 1
    if len(_SWEEPS) >= 16:  # a scene's cameras, and the next scene's
        _SWEEPS.clear()
    _SWEEPS[key] = _Sweep(sample, radii, j, np.clip(kb, 0, k - 1), kb >= 0, r_cell + grid.res / 2)
    return _SWEEPS[key]


def pixel_solid_angle(table: RayTable) -> np.ndarray:
    """(H, W) solid angle of each pixel (steradians) from the ray table's neighbouring rays."""
    r = table.rays.astype(np.float64)
    du = np.gradient(r, axis=1)
    dv = np.gradient(r, axis=0)
    om = np.linalg.norm(np.cross(du, dv), axis=-1)
    return np.where(table.valid, om, np.nan)


def expected_pixels(grid, rc, table: RayTable, top: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """(rows, cols) camera pixels expected on each cell's (horizontal) surface where `seen`:
    cell area * cos(incidence) / distance^2 over the solid angle of the pixel it projects to."""
    c = grid.cell_centres()
    pts = np.concatenate([c, top[..., None]], -1).reshape(-1, 3)
    uv, valid = rc.project_ego(pts)
    uv, valid = np.asarray(uv), np.asarray(valid).astype(bool)
    h, w = table.shape
    u = np.rint(np.nan_to_num(uv[:, 0], nan=-1)).astype(np.int64)
    v = np.rint(np.nan_to_num(uv[:, 1], nan=-1)).astype(np.int64)
    ok = valid & (u >= 0) & (u < w) & (v >= 0) & (v < h) & seen.reshape(-1)
    om = np.full(u.shape, np.nan)
    om[ok] = pixel_solid_angle_cached(table)[v[ok], u[ok]]
    d = pts - table.origin.astype(np.float64)
    dist = np.linalg.norm(d, axis=-1)
    cos_inc = np.clip(-d[:, 2] / np.maximum(dist, 1e-9), 0, 1)
    px = np.where(ok & np.isfinite(om), grid.res**2 * cos_inc / np.maximum(dist, 1e-9) ** 2 / om, 0.0)
    return px.reshape(grid.shape).astype(np.float32)


_OMEGA: dict[int, tuple[RayTable, np.ndarray]] = {}


def pixel_solid_angle_cached(table: RayTable) -> np.ndarray:
    """pixel_solid_angle, kept per ray table (tables are cached per calibration by
    labels.visibility.camera_table, and dropped from there after 64). The entry holds its table, so
    the table's id cannot be reused by another while the entry lives (an id alone could: a freed
    table's id given to the next scene's camera returned the wrong camera's solid angles)."""
    hit = _OMEGA.get(id(table))
    if hit is None or hit[0] is not table:
        if len(_OMEGA) >= 64:
            _OMEGA.pop(next(iter(_OMEGA)))
        hit = _OMEGA[id(table)] = (table, pixel_solid_angle(table))
    return hit[1]


def ring_masks(grid) -> dict:
    c = grid.cell_centres()
    cheb = np.maximum(np.abs(c[..., 0]), np.abs(c[..., 1]))
    return {name: (cheb >= lo) & (cheb < hi) for name, lo, hi in RINGS}


def pixel_points(rig, cameras: dict, grid, cfg: FusionConfig) -> np.ndarray:
    """(rows, cols) count of the cameras' ground and vehicle pixels on each cell, each at its own
    point (no spreading)."""
    lut = cfg.group_lut()
    total = np.zeros(grid.shape, np.float32)
    for name, table in ray_tables(rig).items():
        p = cameras[name]
        xy, _, _, _ = lift(table, p["distance"], lut[np.clip(p["semantic"], 0, len(lut) - 1)])
        total += count_points(grid, xy)
    return total


def audit_labels(grid, rig, topdown: dict, visibility: np.ndarray, box, cfg: FusionConfig, many: float = 2.0,
                 pixels: np.ndarray | None = None) -> dict:
    """The audit of one frame's labels (see the module doc) from its top-down passes and rig;
    pixels: pixel_points of the frame, for 'unexplained' (None: not reported)."""
    top = topdown["height"].astype(np.float32)
    ego = ego_mask(grid, box)
    ego_grown = ego_mask(grid, (box[0] - 0.2, box[1] + 0.2, box[2] - 0.2, box[3] + 0.2))
    blockers = np.where(ego_grown, -np.inf, top).astype(np.float32)
    vehicle = np.isin(topdown["semantic"], cfg.fine_ids(cfg.vehicle_classes))
    ground = np.isin(topdown["semantic"], cfg.fine_ids(cfg.ground_classes))
    los = np.zeros(grid.shape, bool)
    px = np.zeros(grid.shape, np.float32)
    tables = ray_tables(rig)
    for rc in rig:
        sees = seen_height(grid, blockers, tables[rc.name].origin) <= top + Z_EPS
        los |= sees
        px += expected_pixels(grid, rc, tables[rc.name], top, sees & ground)
    # a vehicle's label is per vehicle: it has a line of sight when any of its cells has one
    inst = topdown["instance"]
    seen_ids = np.unique(inst[los & vehicle])
    los |= vehicle & np.isin(inst, seen_ids)
    los &= ~ego
    tau = effective_tau(cfg, [t.shape for t in tables.values()])
    many_px = kernel_sum(px, cfg.kernel_radius_m / grid.res) >= many * tau
    # p(o) is about the ground and vehicles; the kernel's spill onto a wall's or a pole's cell is not
    visible = (visibility >= VISIBLE) & ~ego & (ground | vehicle)
    hidden = visible & ~los
    near_los = kernel_sum(los.astype(np.float32), cfg.kernel_radius_m / grid.res + math.sqrt(0.5)) > 0
    expect = los & many_px & ground & ~ego
    missed = expect & (visibility < VISIBLE)
    radius = cfg.kernel_radius_m / grid.res
    near_px = np.ones(grid.shape, bool) if pixels is None else kernel_sum(pixels, radius) > 0
    unexplained = hidden & ~near_los & ~near_px

    def shares(m):
        return {
            "visible_no_los": _share(hidden & m, visible & m),
            "beyond_kernel": _share(hidden & ~near_los & m, visible & m),
            "unexplained": _share(unexplained & m, visible & m) if pixels is not None else None,
            "unexplained_cells": int((unexplained & m).sum()),
            "los_invisible": _share(missed & m, expect & m),
            "visible_cells": int((visible & m).sum()), "visible_no_los_cells": int((hidden & m).sum()),
            "beyond_kernel_cells": int((hidden & ~near_los & m).sum()),
            "los_many_cells": int((expect & m).sum()), "los_invisible_cells": int((missed & m).sum()),
        }

    out = shares(np.ones(grid.shape, bool))
    out["rings"] = {name: shares(m) for name, m in ring_masks(grid).items()}
    out["_masks"] = {"hidden": hidden, "missed": missed, "los": los, "unexplained": unexplained}
    return out


def _share(num: np.ndarray, den: np.ndarray) -> float:
    d = int(den.sum())
    return float(num.sum() / d) if d else 0.0


def audit_frame(frame_dir, cfg: FusionConfig | None = None, many: float = 2.0, pixels: bool = True) -> dict:
    """audit_labels of one fused frame on disk (pixels: also read the camera passes for 'unexplained')."""
    cfg = cfg or FusionConfig()
    meta = read_meta(frame_dir)
    grid = meta.grid()
    if pixels:
        meta, rig, cameras, topdown = read_frame_passes(frame_dir)
        points = pixel_points(rig, cameras, grid, cfg)
    else:
        rig, topdown, points = meta.camera_rig(), read_topdown(frame_dir), None
    labels = read_labels(frame_dir)
    return audit_labels(grid, rig, topdown, labels["visibility"], ego_box(meta, cfg), cfg, many, points)


_COUNTS = ("visible_cells", "visible_no_los_cells", "beyond_kernel_cells", "unexplained_cells", "los_many_cells",
           "los_invisible_cells")
METRICS = ("visible_no_los", "beyond_kernel", "unexplained")


def _pooled(parts: list[dict], pixels: bool) -> dict:
    n = {k: sum(p[k] for p in parts) for k in _COUNTS}
    vis = n["visible_cells"]
    return {
        "visible_no_los": n["visible_no_los_cells"] / vis if vis else 0.0,
        "beyond_kernel": n["beyond_kernel_cells"] / vis if vis else 0.0,
        "unexplained": (n["unexplained_cells"] / vis if vis else 0.0) if pixels else None,
        "los_invisible": n["los_invisible_cells"] / n["los_many_cells"] if n["los_many_cells"] else 0.0,
        **n,
    }


def _audit_job(frame_dir, shared) -> dict:
    r = audit_frame(frame_dir, *shared)
    r.pop("_masks")
    return r


def audit_dataset(root, cfg: FusionConfig | None = None, threshold: float = THRESHOLD, many: float = 2.0,
                  metric: str = "unexplained", pixels: bool = True, progress: bool = True,
                  workers: int | None = None) -> dict:
    """Audit every frame of a fused data set (in `workers` processes); returns the audit.json document."""
    from tqdm import tqdm

    if metric == "unexplained" and not pixels:
        raise InputError("audit: --metric unexplained needs the camera passes (drop --no-pixels)")
    cfg = cfg or FusionConfig()
    idx = DatasetIndex(root)
    refs = list(idx.all_frames())
    results = make_backend("local", workers).map(_audit_job, [str(r.dir) for r in refs], shared=(cfg, many, pixels))
    frames = {ref.name: r for ref, r in zip(refs, tqdm(results, total=len(refs), desc="audit", unit="frame",
                                                         disable=not progress))}
    rings = {name: _pooled([f["rings"][name] for f in frames.values()], pixels) for name, _, _ in RINGS}
    overall = _pooled(list(frames.values()), pixels)
    return {"frames": frames, "rings": rings, "overall": overall, "metric": metric, "threshold": float(threshold),
            "passed": overall[metric] <= threshold, "many": float(many),
            "ring_distance": "max(|x|, |y|) from the ego origin, m"}


def format_report(r: dict) -> str:
    pct = lambda v: "-" if v is None else f"{v:.4%}"  # noqa: E731
    lines = [f"{'ring':<8} {'visible':>8} {'no LoS':>8} {'beyond k':>9} {'unexpl.':>9} {'LoS+many':>9} {'invisible':>9}"]
    for name, v in [*r["rings"].items(), ("all", r["overall"])]:
        lines.append(f"{name:<8} {v['visible_cells']:>8} {pct(v['visible_no_los']):>8} {pct(v['beyond_kernel']):>9} "
                     f"{pct(v['unexplained']):>9} {v['los_many_cells']:>9} {pct(v['los_invisible']):>9}")
    worst = sorted(r["frames"].items(), key=lambda kv: -kv[1]["visible_no_los"])[:5]
    lines.append("worst frames (visible, no line of sight): " + ", ".join(f"{n} {f['visible_no_los']:.3%}" for n, f in worst))
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = ArgumentParser(prog="python -m dataset_tools audit",
                                 description="Line-of-sight audit of the visibility labels; writes <dataset>/audit.json.")
    ap.add_argument("dataset")
    ap.add_argument("--threshold", type=float, default=THRESHOLD,
                    help=f"exit 1 when the overall METRIC is above this share of the visible cells (default {THRESHOLD})")
    ap.add_argument("--metric", choices=METRICS, default="unexplained",
                    help="what --threshold limits (default unexplained; see the module doc)")
    ap.add_argument("--no-pixels", action="store_true", help="do not read the camera passes (no 'unexplained')")
    ap.add_argument("--many", type=float, default=2.0, help="'many pixels': expected kernel pixels >= MANY * tau (default 2)")
    ap.add_argument("--config", type=dataset_config, help="dataset config whose labels: section the data set was fused with (tau, kernel)")
    ap.add_argument("--json", help="also write the report here")
    ap.add_argument("--workers", type=int, default=None, help="processes (default 1)")
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    require_positive("--workers", args.workers)
    cfg = load_labels(args.config) if args.config else FusionConfig()
    return print_problems(run_audit(args.dataset, cfg, args.threshold, args.many, args.metric, not args.no_pixels,
                                    progress=not args.no_progress, json_path=args.json, workers=args.workers))


def run_audit(root, cfg: FusionConfig, threshold: float = THRESHOLD, many: float = 2.0, metric: str = "unexplained",
              pixels: bool = True, progress: bool = True, json_path=None, workers: int | None = None) -> list[str]:
    """The audit stage: audit_dataset, written to <root>/audit.json (and `json_path`), its table
    printed; the problems: one line when the overall `metric` is above `threshold`."""
    r = audit_dataset(root, cfg, threshold, many, metric, pixels, progress=progress, workers=workers)
    path = write_audit(root, r)
    if json_path:
        write_json_atomic(Path(json_path), r)
    print(format_report(r))
    line = (f"{metric} {r['overall'][metric]:.4%} of the visible cells (threshold {threshold:.4%}); written {path}")
    if r["passed"]:
        print(f"ok: {line}")
        return []
    return [f"audit: FAIL: {line}"]
