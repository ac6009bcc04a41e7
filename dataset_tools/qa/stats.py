"""Data set statistics: class frequencies per split, visibility histogram, coverage by distance and
by camera, as a table and PNG plots.

    python -m dataset_tools stats <dataset> [--out DIR] [--no-cameras]

Pictures and stats.json go to DIR (default <dataset>/stats).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from common.cli import ArgumentParser
from common.files import output_dir, write_figure_atomic, write_json_atomic

from ..format.labels import read_labels
from ..format.meta import read_meta
from ..format.passes import read_frame_passes
from ..format.reader import DatasetIndex
from ..labels.label_fusion import FusionConfig, camera_counts, effective_tau
from ..labels.visibility import ray_tables, visibility_from_counts

RANGE_EDGES = (0, 5, 10, 15, 20, 25, 36)
VIS_BINS = 10


def frame_stats(ref, n_classes: int, cfg: FusionConfig, cameras: bool) -> dict:
    lab = read_labels(ref.dir, n_classes)
    sem, vis = lab["semantic"], lab["visibility"]
    meta, rig, cams, _ = read_frame_passes(ref.dir) if cameras else (read_meta(ref.dir), None, None, None)
    grid = meta.grid()
    c = grid.cell_centres()
    rng = np.hypot(c[..., 0], c[..., 1])
    ring = np.digitize(rng, RANGE_EDGES[1:-1])
    seen = vis >= 0.5
    out = {
        "classes": np.bincount(sem.reshape(-1), minlength=n_classes)[:n_classes],
        "classes_visible": np.bincount(sem[seen], minlength=n_classes)[:n_classes],
        "vis_hist": np.histogram(vis, VIS_BINS, (0.0, 1.0))[0],
        "ring_cells": np.bincount(ring.reshape(-1), minlength=len(RANGE_EDGES) - 1),
        "ring_seen": np.bincount(ring[seen], minlength=len(RANGE_EDGES) - 1),
        "cells": sem.size,
        "camera_seen": {},
    }
    if cameras:
        tables = ray_tables(rig)
        tau = effective_tau(cfg, [t.shape for t in tables.values()])
        for name, t in tables.items():
            counts, _ = camera_counts(t, cams[name], grid, cfg)
            out["camera_seen"][name] = int((visibility_from_counts(counts, grid.res, cfg.kernel_radius_m, tau) >= 0.5).sum())
    return out


def dataset_stats(root, cameras: bool = True, progress: bool = True) -> dict:
    from tqdm import tqdm

    idx = DatasetIndex(root)
    cfg = FusionConfig(class_names=list(idx.class_names))
    n = len(idx.class_names)
    splits = {}
    vis_hist = np.zeros(VIS_BINS, np.int64)
    ring_cells = np.zeros(len(RANGE_EDGES) - 1, np.int64)
    ring_seen = np.zeros(len(RANGE_EDGES) - 1, np.int64)
    cam_seen: dict[str, int] = {}
    cells = 0
    for split, refs in idx.splits.items():
        if not refs:
            continue
        cls = np.zeros(n, np.int64)
        cls_vis = np.zeros(n, np.int64)
        for ref in tqdm(refs, desc=f"stats {split}", unit="frame", disable=not progress):
            s = frame_stats(ref, n, cfg, cameras)
            cls += s["classes"]
            cls_vis += s["classes_visible"]
            vis_hist += s["vis_hist"]
            ring_cells += s["ring_cells"]
            ring_seen += s["ring_seen"]
            cells += s["cells"]
            for k, v in s["camera_seen"].items():
                cam_seen[k] = cam_seen.get(k, 0) + v
        splits[split] = {
            "frames": len(refs),
            "classes": {c: float(v / max(cls.sum(), 1)) for c, v in zip(idx.class_names, cls)},
            "classes_visible": {c: float(v / max(cls_vis.sum(), 1)) for c, v in zip(idx.class_names, cls_vis)},
        }
    ranges = [f"{a}-{b} m" for a, b in zip(RANGE_EDGES[:-1], RANGE_EDGES[1:])]
    return {
        "splits": splits,
        "visibility_hist": {"edges": np.linspace(0, 1, VIS_BINS + 1).tolist(), "fraction": (vis_hist / max(vis_hist.sum(), 1)).tolist()},
        "coverage_by_distance": {r: float(s / c) if c else None for r, s, c in zip(ranges, ring_seen, ring_cells)},
        "coverage_by_camera": {k: float(v / max(cells, 1)) for k, v in cam_seen.items()},
        "coverage": float(ring_seen.sum() / max(ring_cells.sum(), 1)),
    }


def format_table(st: dict) -> str:
    lines = []
    names = list(next(iter(st["splits"].values()))["classes"]) if st["splits"] else []
    lines.append(f"{'split':<8} {'frames':>6} " + " ".join(f"{c:>13}" for c in names))
    for split, s in st["splits"].items():
        lines.append(f"{split:<8} {s['frames']:>6} " + " ".join(f"{s['classes'][c]:>13.2%}" for c in names))
        lines.append(f"{'  seen':<8} {'':>6} " + " ".join(f"{s['classes_visible'][c]:>13.2%}" for c in names))
    lines.append("visibility histogram: " + " ".join(f"{v:.2f}" for v in st["visibility_hist"]["fraction"]))
    lines.append("coverage (p >= 0.5) by distance: " + ", ".join(f"{r} {'-' if v is None else f'{v:.1%}'}" for r, v in st["coverage_by_distance"].items()))
    if st["coverage_by_camera"]:
        lines.append("coverage by camera: " + ", ".join(f"{k} {v:.1%}" for k, v in st["coverage_by_camera"].items()))
    return "\n".join(lines)


def plot(st: dict, out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def save(fig, name):
        write_figure_atomic(fig, out / name)
        return out / name

    files = []
    fig, ax = plt.subplots(figsize=(7, 3.5))
    splits = list(st["splits"])
    names = list(st["splits"][splits[0]]["classes"]) if splits else []
    w = 0.8 / max(len(splits), 1)
    for i, s in enumerate(splits):
        ax.bar(np.arange(len(names)) + i * w, [st["splits"][s]["classes"][c] for c in names], w, label=s)
    ax.set_xticks(np.arange(len(names)) + 0.4 - w / 2, names)
    ax.set_ylabel("share of cells")
    ax.set_yscale("log")
    ax.legend()
    ax.set_title("class frequencies per split")
    files.append(save(fig, "class_frequencies.png"))
    fig, ax = plt.subplots(figsize=(5, 3.5))
    e = st["visibility_hist"]["edges"]
    ax.bar(e[:-1], st["visibility_hist"]["fraction"], width=e[1] - e[0], align="edge")
    ax.set_xlabel("p(o)")
    ax.set_ylabel("share of cells")
    ax.set_title("visibility histogram")
    files.append(save(fig, "visibility_histogram.png"))
    fig, ax = plt.subplots(figsize=(5, 3.5))
    r = st["coverage_by_distance"]
    ax.bar(list(r), [v or 0 for v in r.values()])
    ax.set_ylabel("cells with p(o) >= 0.5")
    ax.set_title("coverage by distance from the ego")
    files.append(save(fig, "coverage_by_distance.png"))
    if st["coverage_by_camera"]:
        fig, ax = plt.subplots(figsize=(5, 3.5))
        ax.bar(list(st["coverage_by_camera"]), list(st["coverage_by_camera"].values()))
        ax.set_ylabel("cells seen (camera alone p >= 0.5)")
        ax.set_title("coverage by camera")
        files.append(save(fig, "coverage_by_camera.png"))
    return files


def main(argv=None) -> int:
    ap = ArgumentParser(prog="python -m dataset_tools stats", description="Class frequencies, visibility histogram, coverage by distance and camera.")
    ap.add_argument("dataset")
    ap.add_argument("--out", help="folder for stats.json and plots (default <dataset>/stats)")
    ap.add_argument("--no-cameras", action="store_true", help="skip coverage by camera (reads no EXR)")
    args = ap.parse_args(argv)
    st = dataset_stats(args.dataset, cameras=not args.no_cameras)
    out = output_dir(Path(args.out) if args.out else Path(args.dataset) / "stats")
    write_json_atomic(out / "stats.json", st)
    plot(st, out)
    print(format_table(st))
    print(f"plots and stats.json: {out}")
    return 0

