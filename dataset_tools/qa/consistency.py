"""Consistency of the fused labels with what the fisheye cameras saw.

    python -m dataset_tools consistency <dataset> [--threshold 0.97] [--min-visibility 0.5] [--json out.json]

Each camera's ground and vehicle pixels are placed in BEV through their distance pass (the same
lift as the visibility) and their training class is compared with the fused label of the cell they
land on, over visible cells (p(o) >= --min-visibility) with a valid label. Per class c the score is
the share of camera pixels of class c that land on a cell labelled c, or within --tolerance cells
of one (default 1: the camera pixel's centre and the cell centre that the top-down pass sampled
can be a cell apart; thin markings would otherwise count as errors at coarse grids). Frames whose
street score is below the threshold are listed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from common.cli import ArgumentParser
from common.errors import InputError
from common.files import write_json_atomic

from ..format.labels import read_labels
from ..format.passes import read_frame_passes
from ..format.reader import DatasetIndex
from ..labels.label_fusion import FusionConfig
from ..labels.visibility import lift, ray_tables


def near_class(semantic: np.ndarray, n: int, cells: int) -> np.ndarray:
    """(n, H, W) bool: class c is within `cells` cells (a square neighbourhood) of each cell."""
    import cv2

    k = np.ones((2 * cells + 1, 2 * cells + 1), np.uint8)
    return np.stack([cv2.dilate((semantic == c).astype(np.uint8), k) > 0 for c in range(n)])


def camera_vs_labels(rig, cameras: dict, semantic: np.ndarray, visibility: np.ndarray, grid, cfg: FusionConfig,
                     min_visibility: float = 0.5, tolerance_cells: int = 1) -> np.ndarray:
    """Confusion (C, C): rows the camera pixels' training class, columns the fused label of their
    cell, or the camera's class itself where a cell within `tolerance_cells` carries it (a pixel
    centre and the cell centre the top-down pass sampled can be up to a cell apart)."""
    n = len(cfg.class_names)
    lut, group_lut = cfg.lut(), cfg.group_lut()
    conf = np.zeros((n, n), np.int64)
    near = near_class(semantic, n, tolerance_cells) if tolerance_cells > 0 else None
    for name, table in ray_tables(rig).items():
        p = cameras[name]
        sem = np.clip(p["semantic"], 0, len(lut) - 1)
        xy, pix, _, _ = lift(table, p["distance"], group_lut[sem])
        row, col, inside = grid.cell_of(xy)
        cam = lut[sem.reshape(-1)[pix[inside]]].astype(np.int64)
        row, col = row[inside], col[inside]
        lab = semantic[row, col].astype(np.int64)
        if near is not None:
            lab = np.where(near[cam, row, col], cam, lab)
        ok = (visibility[row, col] >= min_visibility) & (lab > 0) & (cam > 0)
        conf += np.bincount(cam[ok] * n + lab[ok], minlength=n * n).reshape(n, n)
    return conf


def scores(conf: np.ndarray, class_names) -> dict:
    """Per class: camera pixels of the class on cells labelled the same / camera pixels of the class
    (None where the camera saw none); 'overall': all agreeing pixels / all pixels."""
    out = {}
    for c, name in enumerate(class_names):
        if c == 0:
            continue
        total = conf[c].sum()
        out[name] = float(conf[c, c] / total) if total else None
    out["overall"] = float(np.trace(conf) / conf.sum()) if conf.sum() else None
    return out


def frame_consistency(frame_dir, cfg: FusionConfig | None = None, min_visibility: float = 0.5,
                      tolerance_cells: int = 1) -> dict:
    cfg = cfg or FusionConfig()
    meta, rig, cameras, _ = read_frame_passes(frame_dir)
    labels = read_labels(frame_dir, len(cfg.class_names))
    grid = meta.grid()
    conf = camera_vs_labels(rig, cameras, labels["semantic"], labels["visibility"], grid, cfg, min_visibility,
                            tolerance_cells)
    return {"confusion": conf, "scores": scores(conf, cfg.class_names)}


def dataset_consistency(root, cfg: FusionConfig | None = None, threshold: float = 0.97, min_visibility: float = 0.5,
                        tolerance_cells: int = 1, progress: bool = True) -> dict:
    from tqdm import tqdm

    cfg = cfg or FusionConfig()
    idx = DatasetIndex(root)
    n = len(cfg.class_names)
    total = np.zeros((n, n), np.int64)
    frames, low = {}, []
    for ref in tqdm(idx.all_frames(), desc="consistency", unit="frame", disable=not progress):
        r = frame_consistency(ref.dir, cfg, min_visibility, tolerance_cells)
        total += r["confusion"]
        frames[ref.name] = r["scores"]
        street = r["scores"].get("street")
        if street is not None and street < threshold:
            low.append((ref.name, street))
    return {"scores": scores(total, cfg.class_names), "frames": frames, "below_threshold": low,
            "threshold": threshold, "confusion": total.tolist(), "class_names": list(cfg.class_names)}


def format_report(r: dict) -> str:
    lines = [f"{'class':<14} consistency", "-" * 26]
    for name, v in r["scores"].items():
        lines.append(f"{name:<14} {'-' if v is None else f'{v:.4f}'}")
    lines.append(f"frames: {len(r['frames'])}; street below {r['threshold']}: {len(r['below_threshold'])}")
    lines += [f"  {name}: street {s:.4f}" for name, s in r["below_threshold"]]
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = ArgumentParser(prog="python -m dataset_tools consistency", description="Camera pixels vs fused BEV labels, per class.")
    ap.add_argument("dataset")
    ap.add_argument("--threshold", type=float, default=0.97, help="list frames whose street consistency is below")
    ap.add_argument("--min-visibility", type=float, default=0.5)
    ap.add_argument("--tolerance", type=int, default=1, help="cells a label may be off (default 1)")
    ap.add_argument("--json", help="also write the report here")
    args = ap.parse_args(argv)
    for flag, v in (("--threshold", args.threshold), ("--min-visibility", args.min_visibility)):
        if not 0.0 <= v <= 1.0:  # also NaN
            raise InputError(f"{flag}: must be in [0, 1], got {v}")
    if args.tolerance < 0:
        raise InputError(f"--tolerance: must be >= 0, got {args.tolerance}")
    r = dataset_consistency(args.dataset, threshold=args.threshold, min_visibility=args.min_visibility,
                            tolerance_cells=args.tolerance)
    print(format_report(r))
    if args.json:
        write_json_atomic(Path(args.json), r)
    return 0
