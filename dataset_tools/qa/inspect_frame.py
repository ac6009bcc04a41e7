"""Look at a frame's passes and labels (label QA).

    python -m dataset_tools inspect <frame dir or .exr> [--out DIR]

For an EXR: lists its layers and channels (type, size, range) and writes a PNG of every pass:
rgb, false-colour semantic and instance, distance, position. For a frame directory: the same for
each of its EXRs, plus the fused labels, the visibility heat map, the labels over the top-down view,
and the per-camera BEV footprint map (which camera sees each cell, colour-coded). Pictures go to
DIR (default <frame>/inspect or <name>_inspect beside an EXR).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from common.cli import ArgumentParser
from common.files import output_dir

from ..format.exr import read_exr_checked
from ..format.layout import DatasetError
from ..format.passes import read_frame_passes
from ..format.png import write_png_atomic
from ..labels.classes import colorize, colorize_train
from ..labels.label_fusion import FusionConfig, effective_tau, ego_box, fuse_passes
from ..labels.visibility import visibility_from_counts
CAMERA_COLOURS = np.array([[230, 25, 75], [60, 180, 75], [0, 130, 200], [255, 225, 25], [245, 130, 48],
                           [145, 30, 180], [70, 240, 240], [240, 50, 230]], np.float32)
MIN_SIDE = 256


def enlarge(rgb: np.ndarray) -> np.ndarray:
    """Nearest-neighbour upscale of small pictures so each pixel stays visible."""
    f = max(1, int(np.ceil(MIN_SIDE / max(1, min(rgb.shape[:2])))))
    return np.repeat(np.repeat(rgb, f, 0), f, 1) if f > 1 else rgb


def colour_ids(ids: np.ndarray) -> np.ndarray:
    """A stable pseudo-random colour per id (0 black)."""
    ids = ids.astype(np.uint64)
    h = (ids * np.uint64(2654435761)) & np.uint64(0xFFFFFF)
    rgb = np.stack([(h >> np.uint64(s)) & np.uint64(255) for s in (16, 8, 0)], -1).astype(np.uint8)
    rgb = (rgb // 2 + 64).astype(np.uint8)
    rgb[ids == 0] = 0
    return rgb


def colour_map(x: np.ndarray, lo: float, hi: float, invalid: np.ndarray | None = None) -> np.ndarray:
    t = np.clip((x - lo) / max(hi - lo, 1e-9), 0, 1)
    rgb = cv2.applyColorMap((t * 255).astype(np.uint8), cv2.COLORMAP_TURBO)[..., ::-1]
    if invalid is not None:
        rgb = rgb.copy()
        rgb[invalid] = 0
    return rgb


def distance_picture(d: np.ndarray) -> np.ndarray:
    hit = np.isfinite(d) & (d > 0) & (d < 1e4)
    logd = np.log10(np.where(hit, d, 1.0))
    return colour_map(logd, np.log10(0.5), np.log10(100.0), ~hit)


def position_picture(x, y, z) -> np.ndarray:
    out = []
    for a in (x, y, z):
        ok = np.isfinite(a) & (np.abs(a) < 1e6)
        lo, hi = (np.percentile(a[ok], [1, 99]) if ok.any() else (0, 1))
        out.append(np.clip((a - lo) / max(hi - lo, 1e-9), 0, 1))
    return (np.stack(out, -1) * 255).astype(np.uint8)


def rgb_picture(r, g, b) -> np.ndarray:
    lin = np.clip(np.stack([r, g, b], -1).astype(np.float32), 0, 1)
    return (np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * lin ** (1 / 2.4) - 0.055) * 255).astype(np.uint8)


def describe_exr(path, channels: dict) -> str:
    lines = [f"{path}"]
    layers: dict[str, list[str]] = {}
    for k in sorted(channels):
        layer, _, ch = k.rpartition(".")
        layers.setdefault(layer or "(default)", []).append(ch)
    for layer, chans in layers.items():
        lines.append(f"  layer {layer}: {', '.join(chans)}")
    for k in sorted(channels):
        a = channels[k]
        finite = a[np.isfinite(a)] if a.dtype.kind == "f" else a
        rng = f"{finite.min():.6g} .. {finite.max():.6g}" if finite.size else "no finite values"
        lines.append(f"    {k:<18} {str(a.dtype):<8} {a.shape[1]}x{a.shape[0]}  {rng}")
    return "\n".join(lines)


def pass_pictures(channels: dict) -> dict[str, np.ndarray]:
    """One picture per pass of an EXR (semantic, instance, distance, position, rgb, height),
    per layer prefix ('all.', 'ground.')."""
    by_layer: dict[str, dict] = {}
    for k, a in channels.items():
        layer, _, ch = k.rpartition(".")
        if layer in ("position", "rgb", ""):
            layer, ch = "", k
        by_layer.setdefault(layer, {})[ch] = a
    out = {}
    for layer, ch in by_layer.items():
        pre = f"{layer}_" if layer else ""
        if "semantic" in ch:
            out[pre + "semantic"] = colorize(ch["semantic"])
        if "instance" in ch:
            out[pre + "instance"] = colour_ids(ch["instance"])
        if "distance" in ch:
            out[pre + "distance"] = distance_picture(ch["distance"])
        if "height" in ch:
            out[pre + "height"] = colour_map(ch["height"], -0.5, 8.0)
        if {"position.X", "position.Y", "position.Z"} <= set(ch):
            out[pre + "position"] = position_picture(ch["position.X"], ch["position.Y"], ch["position.Z"])
        if {"R", "G", "B"} <= set(ch):
            out[pre + "rgb"] = rgb_picture(ch["R"], ch["G"], ch["B"])
    return out


def camera_seen(counts: dict, res: float, cfg: FusionConfig, tau: float) -> dict[str, np.ndarray]:
    """{camera: (H, W) bool}: the cells each camera alone sees with p(o) >= 0.5."""
    return {name: visibility_from_counts(c, res, cfg.kernel_radius_m, tau) >= 0.5 for name, c in counts.items()}


def footprint_map(counts: dict, res: float, cfg: FusionConfig, tau: float, names: list[str], seen_by: dict | None = None):
    """(H, W, 3) picture: each cell the mean colour of the cameras that see it with p >= 0.5."""
    seen_by = seen_by or camera_seen({n: counts[n] for n in names}, res, cfg, tau)
    acc = None
    n = None
    for i, name in enumerate(names):
        seen = seen_by[name]
        if acc is None:
            acc = np.zeros(seen.shape + (3,), np.float32)
            n = np.zeros(seen.shape, np.float32)
        acc[seen] += CAMERA_COLOURS[i % len(CAMERA_COLOURS)]
        n += seen
    pic = (acc / np.maximum(n, 1)[..., None]).astype(np.uint8)
    overlap = n >= 2
    pic[overlap] = (pic[overlap] * 0.8).astype(np.uint8)  # cells seen by several cameras a bit darker
    return pic, n


def labels_over_topdown(topdown: dict, semantic_pic: np.ndarray, visibility: np.ndarray) -> np.ndarray:
    """Labels over the top-down view (first hit from above, shaded by height), occluded cells darkened."""
    h = topdown.get("height_all", np.zeros(visibility.shape, np.float32))
    base = colorize(topdown["semantic_all"]).astype(np.float32) * (0.6 + 0.4 * np.clip(h / 8.0, 0, 1))[..., None]
    over = 0.5 * base + 0.5 * semantic_pic.astype(np.float32)
    over *= (0.35 + 0.65 * visibility)[..., None]
    return np.clip(over, 0, 255).astype(np.uint8)


def frame_pictures(frame_dir: Path, cfg: FusionConfig, labels: dict | None = None) -> tuple[dict, dict]:
    """The BEV pictures of a frame at grid size: top-down views with and without occluders, the
    labels, their visibility, labels over the top-down view and the camera footprints (no legend).
    `labels` (semantic, instance, visibility, e.g. the fused PNGs on disk) replaces the freshly
    fused ones in the pictures; the per-camera counts always come from fusing the passes.
    Also returns the data behind them: meta, rig, cameras, topdown, grid, labels (as shown),
    counts, names, tau, seen ({camera: cells it sees}) and n_seen (cameras per cell)."""
    meta, rig, cameras, topdown = read_frame_passes(frame_dir)
    grid = meta.grid()
    lab = fuse_passes(rig, cameras, topdown, grid, cfg, ego_box(meta, cfg))
    shown = {**lab, **(labels or {})}
    sem_pic = colorize_train(shown["semantic"])
    names = list(lab["counts"])
    tau = effective_tau(cfg, [cameras[n]["distance"].shape for n in names])
    seen = camera_seen(lab["counts"], grid.res, cfg, tau)
    foot, n_seen = footprint_map(lab["counts"], grid.res, cfg, tau, names, seen)
    pics = {
        "topdown_all": colorize(topdown["semantic_all"]),
        "topdown_ground": colorize(topdown["semantic"]),
        "labels_semantic": sem_pic,
        "labels_instance": colour_ids(shown["instance"]),
        "labels_visibility": colour_map(shown["visibility"], 0.0, 1.0),
        "labels_over_topdown": labels_over_topdown(topdown, sem_pic, shown["visibility"]),
        "camera_footprints": foot,
    }
    data = {"meta": meta, "rig": rig, "cameras": cameras, "topdown": topdown, "grid": grid, "labels": shown,
            "counts": lab["counts"], "names": names, "tau": tau, "seen": seen, "n_seen": n_seen}
    return pics, data


def legend(pic: np.ndarray, names: list[str]) -> np.ndarray:
    pic = enlarge(pic).copy()
    for i, name in enumerate(names):
        c = tuple(int(v) for v in CAMERA_COLOURS[i % len(CAMERA_COLOURS)][::-1])
        cv2.putText(pic, name, (6, 16 + 16 * i), cv2.FONT_HERSHEY_SIMPLEX, 0.5, c[::-1], 1, cv2.LINE_AA)
    return pic


def inspect_exr(path: Path, out: Path, prefix: str = "") -> str:
    ch = read_exr_checked(path)
    for name, pic in pass_pictures(ch).items():
        write_png_atomic(out / f"{prefix}{name}.png", enlarge(pic))
    return describe_exr(path, ch)


def inspect_frame(frame_dir: Path, out: Path, cfg: FusionConfig | None = None) -> str:
    cfg = cfg or FusionConfig()
    report = []
    for exr in sorted(frame_dir.glob("*.exr")):
        report.append(inspect_exr(exr, out, f"{exr.stem}_"))
    pics, d = frame_pictures(frame_dir, cfg)
    for name in ("labels_semantic", "labels_instance", "labels_visibility", "labels_over_topdown"):
        write_png_atomic(out / f"{name}.png", enlarge(pics[name]))
    write_png_atomic(out / "camera_footprints.png", legend(pics["camera_footprints"], d["names"]))
    lab, grid, n = d["labels"], d["grid"], d["n_seen"]
    vis = lab["visibility"]
    report.append(f"labels {grid.rows}x{grid.cols} at {grid.res} m: " + ", ".join(
        f"{c} {np.mean(lab['semantic'] == i):.1%}" for i, c in enumerate(cfg.class_names)))
    report.append(f"visibility: mean {vis.mean():.3f}, cells p >= 0.5: {np.mean(vis >= 0.5):.1%}; cells seen by "
                  + ", ".join(f"{k} cameras {np.mean(n == k):.1%}" for k in range(int(n.max()) + 1)))
    return "\n".join(report)


def main(argv=None) -> int:
    ap = ArgumentParser(prog="python -m dataset_tools inspect", description="List an EXR's layers and write pictures of every pass and label.")
    ap.add_argument("path", help="a frame directory or one .exr")
    ap.add_argument("--out", help="folder for the pictures")
    args = ap.parse_args(argv)
    p = Path(args.path)
    if p.is_dir():
        out = output_dir(Path(args.out) if args.out else p / "inspect")
        text = inspect_frame(p, out)
    elif p.suffix.lower() == ".exr":
        out = output_dir(Path(args.out) if args.out else p.with_name(f"{p.stem}_inspect"))
        text = inspect_exr(p, out)
    else:
        raise DatasetError(f"{p}: not a frame directory or an .exr file")
    print(text)
    print(f"pictures: {out}")
    return 0

