"""A static HTML QA report of a data set: one overview page and one page per scene, opened from
the file system (no server, no CDN; HTML, CSS and a little plain JavaScript).

    python -m dataset_tools report DATA [--out DATA/report] [--frames-per-scene N]

Every picture is drawn by dataset_tools.qa.inspect_frame (cameras and BEV), contact_sheet, stats and
consistency; this module only shrinks them into thumbnails and writes the pages. Per frame the
outputs lie in <out>/frames/<scene>/<frame>/ and are rebuilt only when an input of the frame is
newer than the frame's info.json (written last). The per-cell data behind the hover read-out is a
small script (cells.js, base64 bytes per coarse cell), not a .json file: browsers refuse fetch()
from file:// pages, a <script> tag they load.
"""

from __future__ import annotations

import base64
import html
import json
import time
from pathlib import Path

import cv2
import numpy as np

from common.backend import make_backend
from common.files import clean_stale_temps, write_bytes_atomic, write_figure_atomic, write_json_atomic, write_text_atomic

from ..format.audit_file import audit_metric, read_audit
from ..format.labels import read_labels
from ..format.layout import CARD, REPORT_DIR, DatasetError, FrameFiles, frame_dir_name
from ..format.meta import FrameMeta
from ..format.png import read_png
from ..format.reader import DatasetIndex, downsample_labels
from ..labels.classes import TRAIN_PALETTE
from ..labels.label_fusion import DEFAULT_EGO_BOX, FusionConfig
from . import consistency
from . import inspect_frame
from . import stats
from .contact_sheet import frame_sheet

CAMERA_W = 320  # camera thumbnails at most this wide
BEV_SIDE = 400  # BEV pictures at most this many pixels a side
SHEET_W = 1280
CELLS_MAX = 64  # the hover grid has at most this many cells a side
WEBP_QUALITY = 80
PASSES = ("rgb", "semantic", "instance", "distance", "ego")
CLASS_PASSES = ("semantic", "instance")  # nearest-neighbour, lossless
BEV_VIEWS = (("topdown_all", "top-down, first hit from above"), ("topdown_ground", "top-down, occluders hidden"),
             ("labels_over_topdown", "labels over the top-down view"), ("labels_semantic", "labels"),
             ("labels_visibility", "visibility p(o)"), ("camera_footprints", "camera footprints"))
ASSETS = Path(__file__).with_name("report_assets")
VERSION = 1  # bump when the per-frame outputs change: older ones are rebuilt


# ---------------------------------------------------------------- images


def encode(img: np.ndarray, lossless: bool) -> tuple[bytes, str]:
    """(bytes, extension): PNG for class maps (exact colours), WebP for photos and heat maps."""
    bgr = img[..., ::-1] if img.ndim == 3 else img
    if lossless:
        # level 6: level 9 took twice the time (a third of a frame's work here) for files 12 % smaller
        ok, buf = cv2.imencode(".png", bgr, [cv2.IMWRITE_PNG_COMPRESSION, 6])
        ext = "png"
    else:
        ok, buf = cv2.imencode(".webp", bgr, [cv2.IMWRITE_WEBP_QUALITY, WEBP_QUALITY])
        ext = "webp"
    if not ok:
        raise RuntimeError(f"cannot encode a {img.shape} picture as {ext}")
    return buf.tobytes(), ext


def shrink(img: np.ndarray, max_w: int, max_h: int | None = None, nearest: bool = False) -> np.ndarray:
    h, w = img.shape[:2]
    f = min(1.0, max_w / w, (max_h or h) / h)
    if f >= 1.0:
        return img
    size = (max(1, round(w * f)), max(1, round(h * f)))
    return cv2.resize(img, size, interpolation=cv2.INTER_NEAREST if nearest else cv2.INTER_AREA)


def write_picture(folder: Path, stem: str, img: np.ndarray, max_w: int, lossless: bool) -> str:
    data, ext = encode(shrink(img, max_w, max_w if max_w == BEV_SIDE else None, nearest=lossless), lossless)
    write_bytes_atomic(folder / f"{stem}.{ext}", data)
    return f"{stem}.{ext}"


def ego_overlay(rgb: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The camera image with the ego body (mask > 0) tinted red."""
    if mask.ndim == 3:
        mask = mask[..., 0]
    if mask.shape != rgb.shape[:2]:
        mask = cv2.resize(mask, rgb.shape[1::-1], interpolation=cv2.INTER_NEAREST)
    out = rgb.astype(np.float32)
    m = mask > 0
    out[m] = 0.45 * out[m] + 0.55 * np.array([255, 0, 0], np.float32)
    return out.astype(np.uint8)


# ---------------------------------------------------------------- one frame


def frame_inputs(frame_dir: Path) -> list[Path]:
    f = FrameFiles(frame_dir)
    return [p for p in (*frame_dir.iterdir(), *(f.labels.iterdir() if f.labels.is_dir() else ())) if p.is_file()]


def up_to_date(output: Path, inputs: list[Path]) -> bool:
    try:
        t = output.stat().st_mtime
    except FileNotFoundError:
        return False
    return all(p.stat().st_mtime <= t for p in inputs)


def coarse_factor(rows: int, cols: int) -> int:
    """The smallest factor dividing both sides that leaves at most CELLS_MAX cells a side (else the
    largest common divisor that stays under it, possibly 1)."""
    best = 1
    for f in range(1, min(rows, cols) + 1):
        if rows % f or cols % f:
            continue
        best = f
        if rows // f <= CELLS_MAX and cols // f <= CELLS_MAX:
            return f
    return best


def cell_table(labels: dict, topdown: dict, seen: dict, names: list[str], grid, n_classes: int) -> dict:
    """Per coarse cell: class (priority lane marking, vehicle, else majority), mean p(o) (0..250),
    highest first hit from above in decimetres (0..250) and a bit per camera that sees more than
    half of the cell; each a base64 string of bytes, row-major."""
    rows, cols = grid.shape
    f = coarse_factor(rows, cols)
    sem, vis = downsample_labels(labels["semantic"], labels["visibility"], f, num_classes=n_classes)

    def blocks(a):
        return a.reshape(rows // f, f, cols // f, f)

    h = topdown.get("height_all")
    height = np.zeros(sem.shape) if h is None else np.nan_to_num(blocks(h).max(axis=(1, 3)), nan=0.0)
    cams = np.zeros(sem.shape, np.uint8)
    for bit, name in enumerate(names[:8]):
        cams |= ((blocks(seen[name].astype(np.float32)).mean(axis=(1, 3)) > 0.5).astype(np.uint8) << bit)

    def b64(a):
        return base64.b64encode(np.ascontiguousarray(a, np.uint8).tobytes()).decode("ascii")

    return {"rows": rows // f, "cols": cols // f, "cell_m": grid.res * f, "x_max": grid.x_max, "y_max": grid.y_max,
            "cameras": names[:8], "cameras_seen": b64(cams), "class": b64(sem), "p": b64(np.rint(np.clip(vis, 0, 1) * 250)),
            "height_dm": b64(np.clip(np.rint(height * 10), 0, 250))}


def meta_summary(meta: FrameMeta) -> dict:
    """The metadata shown beside a frame: weather, sun, actors by kind, ego pose, timings."""
    kinds: dict[str, int] = {}
    for a in meta.actors or []:
        if isinstance(a, dict):
            k = f"{a.get('kind', a.get('class', '?'))}{' (parked)' if a.get('parked') else ''}"
            kinds[k] = kinds.get(k, 0) + 1
    pose = meta.ego_pose or {}
    return {
        "time_s": meta.time_s, "family": meta.family, "split": meta.split,
        "weather": meta.weather or {}, "sun": meta.sun or {},
        "ego_pose": {k: pose[k] for k in ("x", "y", "yaw") if k in pose},
        "actors": len(meta.actors or []), "actors_by_kind": dict(sorted(kinds.items())),
        "timings": meta.timings or {},
    }


def build_frame(ref, out: Path, cfg: FusionConfig, class_names: list[str]) -> dict:
    """Writes the frame's thumbnails, cells.js and (last) info.json; returns the info."""
    out.mkdir(parents=True, exist_ok=True)
    files = FrameFiles(ref.dir)
    pics, d = inspect_frame.frame_pictures(ref.dir, cfg, read_labels(ref.dir))
    images: dict[str, dict[str, str]] = {}
    for name in d["names"]:
        rgb = read_png(files.camera_png(name), np.uint8, 3)
        per = {"rgb": rgb, **inspect_frame.pass_pictures(d["cameras"][name])}
        ego = files.camera_ego_mask(name)
        if ego.is_file():
            per["ego"] = ego_overlay(rgb, read_png(ego))
        images[name] = {p: write_picture(out, f"cam_{name}_{p}", per[p], CAMERA_W, p in CLASS_PASSES)
                        for p in PASSES if p in per}
    bev = {k: write_picture(out, k, pics[k], BEV_SIDE, k in ("topdown_all", "topdown_ground", "labels_semantic", "camera_footprints"))
           for k, _ in BEV_VIEWS}
    cells = cell_table(d["labels"], d["topdown"], d["seen"], d["names"], d["grid"], len(class_names))
    write_text_atomic(out / "cells.js", f"REPORT.cells[{json.dumps(ref.name)}] = {json.dumps(cells, separators=(',', ':'))};\n")
    conf = consistency.camera_vs_labels(d["rig"], d["cameras"], d["labels"]["semantic"], d["labels"]["visibility"], d["grid"], cfg)
    vis = d["labels"]["visibility"]
    info = {
        "version": VERSION, "name": ref.name, "scene": ref.scene, "frame": ref.frame, "split": ref.split,
        "cameras": d["names"], "images": images, "bev": bev, "meta": meta_summary(d["meta"]),
        "consistency": consistency.scores(conf, cfg.class_names),
        "visibility_mean": float(vis.mean()), "visible_share": float(np.mean(vis >= 0.5)),
        "grid": {"rows": d["grid"].rows, "cols": d["grid"].cols, "res": d["grid"].res},
    }
    write_json_atomic(out / "info.json", info)
    return info


def frame_info(ref, out: Path, cfg: FusionConfig, class_names: list[str], force: bool = False) -> tuple[dict, bool]:
    """(info, rebuilt): the frame's outputs, rebuilt unless info.json is newer than every input."""
    marker = out / "info.json"
    if not force and up_to_date(marker, frame_inputs(ref.dir)):
        try:
            info = json.loads(marker.read_text())
            if info.get("version") == VERSION:
                return info, False
        except (OSError, ValueError):
            pass
    return build_frame(ref, out, cfg, class_names), True


# ---------------------------------------------------------------- figures


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def rig_figure(rig, path: Path, box=DEFAULT_EGO_BOX, reach_m: float = 3.0) -> None:
    """Top view of the car: each camera's position and its horizontal field of view, the fan of
    the rays of the image's middle row (camera model unproject, rotated into the ego frame)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5, 5))
    x0, x1, y0, y1 = box
    # ego frame x forward (drawn up), y left (drawn left)
    ax.add_patch(plt.Rectangle((-y1, x0), y1 - y0, x1 - x0, fc="#ddd", ec="#333"))
    ax.annotate("", xy=(0, x1 - 0.3), xytext=(0, x1 - 1.3), arrowprops={"arrowstyle": "->", "color": "#333"})
    for i, rc in enumerate(rig):
        cam = rc.camera
        u = np.linspace(0, cam.width - 1, 181)
        uv = np.stack([u, np.full_like(u, (cam.height - 1) / 2)], -1)
        origin, rays, valid = rc.rays_ego(uv)
        rays = np.asarray(rays)[np.asarray(valid)]
        xy = rays[:, :2] / np.maximum(np.linalg.norm(rays[:, :2], axis=1, keepdims=True), 1e-9)
        fan = np.concatenate([origin[None, :2], origin[None, :2] + reach_m * xy, origin[None, :2]])
        colour = inspect_frame.CAMERA_COLOURS[i % len(inspect_frame.CAMERA_COLOURS)] / 255
        ax.fill(-fan[:, 1], fan[:, 0], color=colour, alpha=0.25, lw=1, ec=colour)
        az = np.degrees(np.arctan2(rays[:, 1], rays[:, 0]))
        span = float(np.degrees(np.arccos(np.clip(xy[0] @ xy[-1], -1, 1)))) if len(xy) > 1 else 0.0
        span = 360 - span if np.ptp(np.unwrap(np.radians(az))) > np.pi else span
        ax.plot(-origin[1], origin[0], "o", color=colour)
        at = origin[:2] + 0.7 * reach_m * xy[len(xy) // 2]  # the label out along the optical axis
        ax.text(-at[1], at[0], f"{rc.name}\n{span:.0f}° h-FOV", fontsize=8, ha="center", va="center")
    ax.set_aspect("equal")
    ax.set_xlabel("y (m, left)")
    ax.set_ylabel("x (m, forward)")
    ax.set_xticks(ax.get_xticks(), [f"{-t:g}" for t in ax.get_xticks()])
    ax.set_title("rig: camera positions and horizontal fields of view")
    write_figure_atomic(fig, path)


def scene_scores_figure(frames: list[str], series: dict[str, list], threshold: float | None, title: str,
                        ylabel: str, path: Path) -> None:
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6, 2.6))
    x = np.arange(len(frames))
    for name, v in series.items():
        ax.plot(x, [np.nan if a is None else a for a in v], "o-", ms=3, label=name)
    if threshold is not None:
        ax.axhline(threshold, color="r", ls="--", lw=1, label=f"threshold {threshold:g}")
    ax.set_xticks(x, [f.split("/")[-1].lstrip("0") or "0" for f in frames], fontsize=7)
    ax.set_xlabel("frame")
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=7)
    write_figure_atomic(fig, path)


def timing_figure(infos: list[dict], path: Path) -> None:
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7, 2.8))
    keys = ("fisheye_s", "topdown_s", "write_s")
    bottom = np.zeros(len(infos))
    for k in keys:
        v = np.array([float(i["meta"]["timings"].get(k, 0.0) or 0.0) for i in infos])
        ax.bar(np.arange(len(infos)), v, bottom=bottom, label=k[:-2])
        bottom += v
    ax.set_xlabel("frame (in scene order)")
    ax.set_ylabel("seconds")
    ax.set_title("render time per frame")
    ax.legend(fontsize=7)
    write_figure_atomic(fig, path)


# ---------------------------------------------------------------- audit


AUDIT_FIGURES = ("visible_no_los", "los_invisible")  # drawn beside the metric the audit checked


def _number(v):
    return v if isinstance(v, (int, float)) and not isinstance(v, bool) else None


def audit_fails(fig: dict, threshold, metric: str = "visible_no_los") -> bool:
    """A frame fails the audit when its checked metric is above the audit's threshold."""
    v = _number(fig.get(metric))
    return threshold is not None and v is not None and v > threshold


# ---------------------------------------------------------------- pages


def esc(x) -> str:
    return html.escape(str(x))


def page(title: str, body: str, depth: int, script: str = "") -> str:
    up = "../" * depth
    return (f"<!doctype html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{esc(title)}</title>"
            f"<link rel=\"stylesheet\" href=\"{up}report.css\"></head>\n<body>\n{body}\n{script}"
            f"<script src=\"{up}report.js\"></script>\n</body></html>\n")


def table(head: list[str], rows: list[list]) -> str:
    h = "".join(f"<th>{esc(c)}</th>" for c in head)
    b = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><thead><tr>{h}</tr></thead><tbody>{b}</tbody></table>"


def pct(v) -> str:
    return "-" if v is None else f"{v:.1%}"


def frame_link(name: str, depth: int = 0) -> str:
    scene, frame = name.split("/")
    return f"<a href=\"{'../' * depth}scenes/{esc(scene)}.html#{esc(frame)}\">{esc(name)}</a>"


def overview_page(title: str, idx: DatasetIndex, scenes: dict, st: dict, audit: dict | None, threshold: float,
                  settings: dict) -> str:
    parts = [f"<h1>{esc(title)}</h1>", "<nav>" + " ".join(f"<a href=\"scenes/{esc(s)}.html\">{esc(s)}</a>" for s in scenes) + "</nav>"]
    parts.append(f"<p class=\"card\">The <a href=\"../{CARD}\">dataset card</a> ({CARD}: licence, classes, splits, cameras, how it was made).</p>")
    parts.append("<div class=\"row\"><section><h2>Data set</h2>" + table(["", ""], [[esc(k), esc(v)] for k, v in settings.items()]))
    rows = []
    for split, refs in idx.splits.items():
        sc = sorted({r.scene for r in refs})
        rows.append([esc(split), len(refs), " ".join(f"<a href=\"scenes/{esc(s)}.html\">{esc(s)}</a>" for s in sc)])
    parts.append("<h2>Splits</h2>" + table(["split", "frames", "scenes"], rows) + "</section>"
                 "<section><h2>Rig</h2><img class=\"fig\" src=\"overview/rig.png\" alt=\"rig\"></section></div>")
    names = idx.class_names
    srows = [[esc(s), v["frames"], *[pct(v["classes"][c]) for c in names]] for s, v in st["splits"].items()]
    parts.append("<section><h2>Classes and visibility</h2>" + table(["split", "frames", *names], srows)
                 + "<p>share of cells per class (all cells, fused labels)</p><div class=\"figs\">"
                 + "".join(f"<img class=\"fig\" src=\"overview/{f}\" alt=\"{f}\">" for f in st["_plots"]) + "</div></section>")
    # consistency
    crow, figs = [], []
    for scene, infos in scenes.items():
        low = [i["name"] for i in infos if below(i["consistency"].get("street"), threshold)]
        overall = [i["consistency"].get("overall") for i in infos if i["consistency"].get("overall") is not None]
        crow.append([f"<a href=\"scenes/{esc(scene)}.html\">{esc(scene)}</a>", len(infos),
                     pct(float(np.mean(overall)) if overall else None),
                     " ".join(frame_link(n) for n in low) or "none"])
        figs.append(f"<img class=\"fig\" src=\"overview/consistency_{esc(scene)}.png\" alt=\"consistency {esc(scene)}\">")
    parts.append("<section><h2>Consistency (camera pixels vs fused labels)</h2>"
                 + table(["scene", "frames", "overall", f"frames with street below {threshold:g}"], crow)
                 + f"<div class=\"figs\">{''.join(figs)}</div></section>")
    # audit
    if audit is None:
        parts.append("<section id=\"audit\"><h2>Line-of-sight audit</h2><p class=\"missing\">no audit yet "
                     "(python -m dataset_tools audit DATA)</p></section>")
    else:
        th = audit.get("threshold")
        arow, figs = [], []
        for scene in scenes:
            fr = {k: v for k, v in audit["frames"].items() if k.split("/")[0] == scene}
            bad = [k for k, v in sorted(fr.items()) if audit_fails(v, th, audit_metric(audit))]
            arow.append([f"<a href=\"scenes/{esc(scene)}.html\">{esc(scene)}</a>", len(fr),
                         " ".join(frame_link(n) for n in bad) or "none"])
            if fr:
                figs.append(f"<img class=\"fig\" src=\"overview/audit_{esc(scene)}.png\" alt=\"audit {esc(scene)}\">")
        overall = audit.get("overall") or {}
        parts.append("<section id=\"audit\"><h2>Line-of-sight audit</h2>"
                     + table(["figure", "overall"], [[esc(k), esc(f"{v:.4g}" if isinstance(v, float) else v)] for k, v in overall.items()])
                     + table(["scene", "frames audited", f"frames with {esc(audit_metric(audit))} above {th}"], arow)
                     + f"<div class=\"figs\">{''.join(figs)}</div></section>")
    parts.append("<section><h2>Render time</h2><img class=\"fig\" src=\"overview/render_time.png\" alt=\"render time\">"
                 + table(["", "mean s/frame"], [[esc(k), f"{np.mean(v):.2f}"] for k, v in _timings(scenes).items()]) + "</section>")
    return page(title, "\n".join(parts), 0)


def below(score, threshold) -> bool:
    return score is not None and score < threshold


def _timings(scenes: dict) -> dict:
    out: dict[str, list] = {}
    for infos in scenes.values():
        for i in infos:
            for k, v in i["meta"]["timings"].items():
                if isinstance(v, (int, float)):
                    out.setdefault(k, []).append(v)
    return out


def scene_page(scene: str, infos: list[dict], class_names: list[str], audit: dict | None, has_sheet: bool) -> str:
    data = {"scene": scene, "class_names": class_names, "class_colours": TRAIN_PALETTE[: len(class_names)].tolist(),
            "camera_colours": inspect_frame.CAMERA_COLOURS.astype(int).tolist(), "passes": list(PASSES), "bev": [list(v) for v in BEV_VIEWS],
            "audit": {k: {f: (round(x, 5) if isinstance(x, float) else x) for f, x in v.items() if not isinstance(x, (dict, list))}
                      for k, v in (audit or {}).get("frames", {}).items() if k.split("/")[0] == scene},
            "frames": infos}
    strip = "".join(
        f"<button class=\"thumb\" data-frame=\"{i}\" title=\"{esc(f['name'])}\"><img src=\"../frames/{esc(f['name'])}/"
        f"{esc(f['images'][f['cameras'][0]]['rgb'])}\" alt=\"{esc(f['name'])}\"><span>{f['frame']}</span></button>"
        for i, f in enumerate(infos))
    passes = "".join(f"<button class=\"pass\" data-pass=\"{p}\">{p}</button>" for p in PASSES)
    body = (f"<p><a href=\"../index.html\">overview</a></p><h1>{esc(scene)}</h1>"
            + f"<section><h2>Frames</h2><div id=\"strip\">{strip}</div></section>"
            + "<section id=\"frame\"><h2 id=\"frame-title\"></h2>"
            + f"<div id=\"passes\">{passes}</div><div id=\"cameras\"></div>"
            + "<div id=\"bev-row\"><div><div id=\"bev\"></div><div id=\"legend\"></div></div><div id=\"side\"><h3>cell</h3><pre id=\"cell\">hover or click a BEV cell</pre>"
            + "<h3>frame</h3><pre id=\"meta\"></pre></div></div></section>"
            + ("<section><h2>Contact sheet (first frame)</h2><img class=\"sheet\" src=\"" + esc(scene)
               + "_sheet.webp\" alt=\"contact sheet\"></section>" if has_sheet else ""))
    script = f"<script>window.REPORT = {{cells: {{}}, scene: {json.dumps(data, separators=(',', ':'))}}};</script>\n"
    return page(scene, body, 1, script)


# ---------------------------------------------------------------- the report


def _frame_job(ref, shared) -> tuple[dict, bool]:
    out, cfg, class_names, force = shared
    return frame_info(ref, out / "frames" / frame_dir_name(ref.scene, ref.frame), cfg, class_names, force)


def _scene_job(job, shared) -> None:
    """A scene's figures, contact sheet and page."""
    scene, infos, first_dir, frames_audit = job
    out, class_names, threshold, audit_head, force = shared
    audit = None if audit_head is None else {**audit_head, "frames": frames_audit}
    names = [i["name"] for i in infos]
    series = {k: [i["consistency"].get(k) for i in infos] for k in [*class_names[1:], "overall"]
              if any(i["consistency"].get(k) is not None for i in infos)}
    scene_scores_figure(names, series, threshold, f"{scene}: consistency per frame", "agreement",
                        out / "overview" / f"consistency_{scene}.png")
    if audit is not None and any(n in frames_audit for n in names):
        keys = dict.fromkeys([audit_metric(audit), *AUDIT_FIGURES])
        series = {k: [_number(frames_audit.get(n, {}).get(k)) for n in names] for k in keys}
        scene_scores_figure(names, series, audit.get("threshold"), f"{scene}: line-of-sight audit", "share",
                            out / "overview" / f"audit_{scene}.png")
    sheet = out / "scenes" / f"{scene}_sheet.webp"
    if force or not up_to_date(sheet, frame_inputs(Path(first_dir))):
        write_bytes_atomic(sheet, encode(shrink(frame_sheet(Path(first_dir)), SHEET_W), False)[0])
    write_text_atomic(out / "scenes" / f"{scene}.html", scene_page(scene, infos, class_names, audit, True))


def build_report(root, out=None, frames_per_scene: int | None = None, threshold: float = 0.97,
                 progress: bool = True, force: bool = False, workers: int | None = None) -> Path:
    """Writes the report (its frames' pictures in `workers` processes); returns the path of its index.html."""
    from tqdm import tqdm

    root = Path(root)
    out = Path(out) if out else root / REPORT_DIR
    idx = DatasetIndex(root)
    cfg = FusionConfig(class_names=list(idx.class_names))
    refs = sorted(idx.all_frames(), key=lambda r: (r.scene, r.frame))
    if not refs:
        raise DatasetError(f"{root}: no frames in the index")
    if frames_per_scene is not None:
        if frames_per_scene < 1:
            raise DatasetError("--frames-per-scene: must be at least 1")
        by: dict[str, list] = {}
        for r in refs:
            by.setdefault(r.scene, []).append(r)
        # evenly spread over the scene, first and last included
        refs = [rs[i] for rs in by.values() for i in sorted(set(np.linspace(0, len(rs) - 1, min(frames_per_scene, len(rs))).round().astype(int)))]
    clean_stale_temps(out)  # temp files of an interrupted run
    (out / "overview").mkdir(parents=True, exist_ok=True)
    (out / "scenes").mkdir(exist_ok=True)
    for asset in ("report.css", "report.js"):
        write_bytes_atomic(out / asset, (ASSETS / asset).read_bytes())
    scenes: dict[str, list[dict]] = {}
    rebuilt = 0
    jobs = make_backend("local", workers).map(_frame_job, refs, shared=(out, cfg, list(idx.class_names), force))
    for ref, (info, new) in zip(refs, tqdm(jobs, total=len(refs), desc="report", unit="frame", disable=not progress)):
        rebuilt += new
        scenes.setdefault(ref.scene, []).append(info)
    audit = read_audit(root, missing_ok=True)
    # the statistics read every label: cached, redone when a frame or the index changed
    stamp = out / "overview" / "stats.json"
    if rebuilt or force or not up_to_date(stamp, [root / "index.json"]):
        st = stats.dataset_stats(root, cameras=False, progress=progress)
        write_json_atomic(stamp, st)
    st = json.loads(stamp.read_text())
    st["_plots"] = [p.name for p in stats.plot(st, out / "overview")]
    rig_figure(idx.rig, out / "overview" / "rig.png")
    timing_figure([i for infos in scenes.values() for i in infos], out / "overview" / "render_time.png")
    first_dir = {r.name: str(r.dir) for r in refs}
    frames_audit = (audit or {}).get("frames", {})
    # the audit as the scene pages need it: its settings and only their scene's frames
    audit_head = None if audit is None else {k: v for k, v in audit.items() if k != "frames"}
    by_scene: dict[str, dict] = {}
    for name, v in frames_audit.items():
        by_scene.setdefault(name.split("/")[0], {})[name] = v
    jobs = [(scene, infos, first_dir[infos[0]["name"]], by_scene.get(scene, {})) for scene, infos in scenes.items()]
    for _ in tqdm(make_backend("local", workers).map(_scene_job, jobs, shared=(out, list(idx.class_names), threshold,
                                                                                 audit_head, force)),
                  total=len(jobs), desc="report scenes", unit="scene", disable=not progress):
        pass
    g = next(iter(scenes.values()))[0]["grid"]
    settings = {"data set": root.resolve().name, "frames": len(refs), "scenes": len(scenes),
                "label grid": f"{g['rows']} x {g['cols']} cells of {g['res']:g} m",
                "cameras": camera_line(idx.rig),
                "classes": ", ".join(idx.class_names), "report built": time.strftime("%Y-%m-%d %H:%M")}
    write_text_atomic(out / "index.html", overview_page(f"Label QA: {root.resolve().name}", idx, scenes, st, audit,
                                                        threshold, settings))
    return out / "index.html"


def camera_line(rig) -> str:
    """'front, left: 480x302 OpenCVFisheye; ...' grouped by size and model."""
    groups: dict[str, list[str]] = {}
    for rc in rig:
        groups.setdefault(f"{rc.camera.width}x{rc.camera.height} {type(rc.camera).__name__}", []).append(rc.name)
    return "; ".join(f"{', '.join(n)}: {k}" for k, n in groups.items())


def report_size(out: Path) -> int:
    return sum(p.stat().st_size for p in Path(out).rglob("*") if p.is_file())


def main(argv=None) -> int:
    from common.cli import ArgumentParser, print_problems, require_positive

    ap = ArgumentParser(prog="python -m dataset_tools report", description=__doc__.splitlines()[0])
    ap.add_argument("dataset", type=Path)
    ap.add_argument("--out", type=Path, help=f"report folder (default <dataset>/{REPORT_DIR})")
    ap.add_argument("--frames-per-scene", type=int, help="at most this many frames per scene, evenly spread (default all)")
    ap.add_argument("--threshold", type=float, default=0.97, help="street consistency below this is flagged")
    ap.add_argument("--force", action="store_true", help="rebuild every output")
    ap.add_argument("--workers", type=int, default=None, help="processes drawing the frames' pictures (default 1)")
    ap.add_argument("--no-progress", action="store_true")
    a = ap.parse_args(argv)
    require_positive("--workers", a.workers)
    return print_problems(run_report(a.dataset, a.out, a.frames_per_scene, a.threshold, not a.no_progress, a.force,
                                     a.workers))


def run_report(root, out=None, frames_per_scene: int | None = None, threshold: float = 0.97, progress: bool = True,
               force: bool = False, workers: int | None = None) -> list[str]:
    """The report stage: build_report and one line saying where it is; the problems (none: the
    report shows what it finds, it does not judge)."""
    t0 = time.perf_counter()
    index = build_report(root, out, frames_per_scene, threshold, progress, force, workers)
    print(f"report: {index} ({report_size(index.parent) / 1e6:.1f} MB, {time.perf_counter() - t0:.1f} s)")
    return []
