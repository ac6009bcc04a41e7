"""eval.py's outputs drawn from its scores: the Markdown table laid out as the paper's Table I
(each figure with its 95 % interval over scenes), the comparison table of eval.py --compare, the
confusion-matrix picture and the per-frame pictures as the paper's Figs. 6-8."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from common.files import write_figure_atomic
from dataset_tools import TRAIN_PALETTE, colorize_train

TABLE_COLUMNS = [("miou", "mIoU"), ("iou/occlusion", "Occlusions"), ("iou/vehicle", "Vehicles"),
                 ("iou/lane_marking", "Markings"), ("iou/street", "Street"), ("iou/background", "Background")]


def fmt(v) -> str:
    return "-" if v is None or v != v else f"{v:.3f}"  # NaN (class absent from truth and prediction) -> "-"


def fmt_interval(v, iv) -> str:
    """`0.462 [0.431, 0.490]`: a figure and its interval (the figure alone where there is none)."""
    if not iv or v is None or v != v or iv[0] != iv[0]:
        return fmt(v)
    return f"{v:.3f} [{iv[0]:.3f}, {iv[1]:.3f}]"


def markdown_table(results: dict, method: str) -> str:
    head = "| Method | Image type | Dataset | Scenes | " + " | ".join(t for _, t in TABLE_COLUMNS) + " |"
    lines = [head, "|" + "---|" * (4 + len(TABLE_COLUMNS))]
    for split, r in results.items():
        o, iv = r["overall"], r.get("interval", {})
        lines.append(f"| {method} | Raw distorted | {split} | {len(r.get('scenes', {})) or '-'} | "
                     + " | ".join(fmt_interval(o.get(k), iv.get(k)) for k, _ in TABLE_COLUMNS) + " |")
    lines += ["", "[low, high]: the 95 % interval of a bootstrap over the split's scenes (docs/evaluation.md)."]
    for split, r in results.items():
        for group in ("bands", "weather"):
            if len(r[group]) < 2:
                continue
            lines += ["", f"{split}, by {'distance band' if group == 'bands' else 'weather'}:", "",
                      f"| {group[:-1] if group == 'bands' else 'weather'} | " + " | ".join(t for _, t in TABLE_COLUMNS) + " |",
                      "|" + "---|" * (1 + len(TABLE_COLUMNS))]
            for name, o in r[group].items():
                lines.append(f"| {name} | " + " | ".join(fmt(o.get(k)) for k, _ in TABLE_COLUMNS) + " |")
    if any("iou_tol/lane_marking" in r["overall"] for r in results.values()):
        lines += ["", "Markings, tolerance IoU (a marking predicted within one cell of a true one counts): "
                  + ", ".join(f"{s} {fmt(r['overall'].get('iou_tol/lane_marking'))}" for s, r in results.items())]
    lines += ["", "Inference: " + ", ".join(f"{s} {r['inference_ms_per_frame']:.1f} ms/frame" for s, r in results.items())]
    return "\n".join(lines) + "\n"


def comparison_table(report: dict) -> str:
    """eval.py --compare's table: per split, each score of A and of B and A - B with its paired 95 %
    interval over scenes, and which is better where the interval excludes 0."""
    lines = [f"A: {report['a']['checkpoint']} (step {report['a']['step']})",
             f"B: {report['b']['checkpoint']} (step {report['b']['step']})", "",
             "| Dataset | Scenes | Score | A | B | A - B | 95 % interval | |", "|---|---|---|---|---|---|---|---|"]
    for split, r in report["splits"].items():
        for key, title in TABLE_COLUMNS:
            d = r["difference"].get(key)
            if d is None:
                continue
            better = "A better" if d["low"] > 0 else "B better" if d["high"] < 0 else "undecided"
            if d["low"] != d["low"]:
                better = "-"
            lines.append(f"| {split} | {r['scenes']} | {title} | {fmt(d['a'])} | {fmt(d['b'])} | {signed(d['diff'])} | "
                         f"[{signed(d['low'])}, {signed(d['high'])}] | {better} |")
    lines += ["", f"Paired bootstrap over scenes ({report['resamples']} resamples; docs/evaluation.md)."]
    return "\n".join(lines) + "\n"


def signed(v) -> str:
    return "-" if v is None or v != v else f"{v:+.3f}"


def camera_row(fig, gs, images: dict) -> None:
    """The camera images, titled by name, along the first row of the grid spec `gs`."""
    for i, (n, img) in enumerate(images.items()):
        ax = fig.add_subplot(gs[0, i])
        ax.imshow(img)
        ax.set_title(n, fontsize=9)
        ax.axis("off")


def frame_picture(path: Path, images: dict, truth, vis, pred, pred_vis, class_names, title: str):
    """The four fisheye images, the truth (dimmed where invisible), the prediction, the visibility."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    fig = plt.figure(figsize=(16, 7.4))
    gs = fig.add_gridspec(2, max(4, len(images)), height_ratios=[1, 1.6])
    camera_row(fig, gs, images)
    panels = [(colorize_train(truth, vis), "truth (dimmed: p(o) < 0.5)"), (colorize_train(pred), "prediction"),
              (vis, "true visibility p(o)"), (pred_vis, "predicted visibility")]
    for i, (img, t) in enumerate(panels):
        ax = fig.add_subplot(gs[1, i])
        ax.imshow(img, cmap="magma", vmin=0, vmax=1) if img.ndim == 2 else ax.imshow(img)
        ax.plot([img.shape[1] / 2 - 0.5], [img.shape[0] / 2 - 0.5], marker="^", color="cyan", ms=5)  # ego origin, facing up
        ax.set_title(t, fontsize=9)
        ax.axis("off")
    fig.legend(handles=[Patch(facecolor=TRAIN_PALETTE[i] / 255, edgecolor="black", label=n) for i, n in enumerate(class_names) if i > 0],
               loc="lower center", ncol=len(class_names) - 1, fontsize=9)
    fig.suptitle(title, fontsize=10)
    _save_fig(fig, path)


def prediction_picture(path: Path, images: dict, classes, visibility, grid, class_names, title: str) -> None:
    """predict.py's picture: the images, the predicted classes and p(o) over the metric grid
    (metres, forward up, left left)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    fig = plt.figure(figsize=(4 * max(4, len(images)), 8))
    gs = fig.add_gridspec(2, max(4, len(images)), height_ratios=[1, 1.8])
    camera_row(fig, gs, images)
    extent = (grid.y_max, grid.y_min, grid.x_min, grid.x_max)  # columns run from +y (left) to -y
    for j, (img, t) in enumerate([(colorize_train(classes), "predicted classes"), (visibility, "predicted visibility p(o)")]):
        ax = fig.add_subplot(gs[1, 2 * j: 2 * j + 2])
        ax.imshow(img, extent=extent, cmap="magma", vmin=0, vmax=1) if img.ndim == 2 else ax.imshow(img, extent=extent)
        ax.plot([0], [0], marker="^", color="cyan", ms=6)
        ax.set_xlabel("y (m, left is +)")
        ax.set_ylabel("x (m, forward)")
        ax.set_title(t, fontsize=9)
    fig.legend(handles=[Patch(facecolor=TRAIN_PALETTE[i] / 255, edgecolor="black", label=n) for i, n in enumerate(class_names) if i > 0],
               loc="lower center", ncol=len(class_names) - 1, fontsize=9)
    fig.suptitle(title, fontsize=10)
    write_figure_atomic(fig, path)


def confusion_picture(path: Path, cm: np.ndarray, class_names, title: str):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cm = np.asarray(cm, dtype=np.float64)[1:, 1:]  # invalid is never scored
    names = class_names[1:]
    rows = cm / np.maximum(cm.sum(1, keepdims=True), 1)
    fig, ax = plt.subplots(figsize=(5.5, 4.8))
    ax.imshow(rows, cmap="Blues", vmin=0, vmax=1)
    for i in range(len(names)):
        for j in range(len(names)):
            ax.text(j, i, f"{rows[i, j]:.2f}\n{int(cm[i, j])}", ha="center", va="center", fontsize=7,
                    color="white" if rows[i, j] > 0.5 else "black")
    ax.set_xticks(range(len(names)), names, rotation=30, fontsize=8)
    ax.set_yticks(range(len(names)), names, fontsize=8)
    ax.set_xlabel("predicted")
    ax.set_ylabel("true (visible cells)")
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    _save_fig(fig, path)


def _save_fig(fig, path: Path):
    write_figure_atomic(fig, path, dpi=80)
