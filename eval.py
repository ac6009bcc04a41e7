"""Evaluate a checkpoint with the paper's protocol.

    python eval.py --checkpoint runs/cpu_default/latest.pt --split {train,easy,medium,hard,all}

Per split: one confusion matrix over the whole split, on cells whose true visibility p(o) >= 0.5
and whose true class is valid; per-class IoU from it; occlusion IoU of the binarised visibility
(occluded = p(o) < 0.5, predicted vs true, every cell); mIoU = mean of the IoUs of occlusion,
vehicle, lane marking, street and background (the paper's definition). The same by distance band
(Euclidean distance of the cell centre from the ego origin) and by weather preset, and inference
time per frame. Writes metrics.json, table.md (laid out as the paper's Table I), a confusion-matrix
picture and, for a sample of frames, pictures as the paper's Figs. 6-8.
"""

from __future__ import annotations

import io
import time
from pathlib import Path

import numpy as np
import torch

from common.cli import ArgumentParser, run_cli
from common.errors import InputError
from common.files import output_dir, write_bytes_atomic, write_figure_atomic, write_json_atomic, write_text_atomic
from dataset_tools import SPLITS, TRAIN_PALETTE, DatasetIndex, colorize_train, read_frame
from model import load_checkpoint
from model.config import load_config
from model.data import BevDataset
from model.metrics import BevMetrics, confusion, occlusion_confusion
BANDS = ((0.0, 10.0), (10.0, 20.0), (20.0, 25.0))
TABLE_COLUMNS = [("miou", "mIoU"), ("iou/occlusion", "Occlusions"), ("iou/vehicle", "Vehicles"),
                 ("iou/lane_marking", "Markings"), ("iou/street", "Street"), ("iou/background", "Background")]


class EvalError(InputError):
    pass


def band_masks(grid) -> dict[str, torch.Tensor]:
    """Band name -> (X, Y) bool mask of the cells whose centre lies in that distance band."""
    dist = torch.from_numpy(np.linalg.norm(grid.cell_centres(), axis=-1))
    return {f"{lo:g}-{hi:g} m": (dist >= lo) & (dist < hi) for lo, hi in BANDS}


class SplitScores:
    """Confusion matrices of one split: overall, per distance band and per weather preset."""

    def __init__(self, class_names, grid):
        self.class_names = class_names
        self.overall = BevMetrics(class_names)
        self.bands = {name: (mask, BevMetrics(class_names)) for name, mask in band_masks(grid).items()}
        self.weather: dict[str, BevMetrics] = {}
        self.frames = 0
        self.seconds = 0.0

    def update(self, pred: torch.Tensor, occ_logit: torch.Tensor, semantic, visibility, weather: str):
        """One frame: pred (X, Y) class ids, occ_logit (X, Y) visibility logits, truth (X, Y)."""
        k = len(self.class_names)
        cm, occ = confusion(pred, semantic, visibility, k), occlusion_confusion(occ_logit, visibility)
        self.overall.merge_(cm, occ)
        self.overall.add_tolerance(pred, semantic, visibility)
        self.weather.setdefault(weather or "unknown", BevMetrics(self.class_names)).merge_(cm, occ)
        for mask, m in self.bands.values():
            m.merge_(confusion(pred[mask], semantic[mask], visibility[mask], k),
                     occlusion_confusion(occ_logit[mask], visibility[mask]))
        self.frames += 1

    def result(self) -> dict:
        return {
            "frames": self.frames,
            "inference_ms_per_frame": 1000 * self.seconds / max(self.frames, 1),
            "overall": self.overall.compute(),
            "confusion": self.overall.cm.tolist(),
            "occlusion_confusion": self.overall.occ.tolist(),
            "bands": {n: m.compute() for n, (_, m) in self.bands.items()},
            "weather": {n: m.compute() for n, m in sorted(self.weather.items())},
        }


def _fmt(v) -> str:
    return "-" if v is None or v != v else f"{v:.3f}"  # NaN (class absent from truth and prediction) -> "-"


def markdown_table(results: dict, method: str) -> str:
    head = "| Method | Image type | Dataset | " + " | ".join(t for _, t in TABLE_COLUMNS) + " |"
    lines = [head, "|" + "---|" * (3 + len(TABLE_COLUMNS))]
    for split, r in results.items():
        o = r["overall"]
        lines.append(f"| {method} | Raw distorted | {split} | " + " | ".join(_fmt(o.get(k)) for k, _ in TABLE_COLUMNS) + " |")
    for split, r in results.items():
        for group in ("bands", "weather"):
            if len(r[group]) < 2:
                continue
            lines += ["", f"{split}, by {'distance band' if group == 'bands' else 'weather'}:", "",
                      f"| {group[:-1] if group == 'bands' else 'weather'} | " + " | ".join(t for _, t in TABLE_COLUMNS) + " |",
                      "|" + "---|" * (1 + len(TABLE_COLUMNS))]
            for name, o in r[group].items():
                lines.append(f"| {name} | " + " | ".join(_fmt(o.get(k)) for k, _ in TABLE_COLUMNS) + " |")
    if any("iou_tol/lane_marking" in r["overall"] for r in results.values()):
        lines += ["", "Markings, tolerance IoU (a marking predicted within one cell of a true one counts): "
                  + ", ".join(f"{s} {_fmt(r['overall'].get('iou_tol/lane_marking'))}" for s, r in results.items())]
    lines += ["", "Inference: " + ", ".join(f"{s} {r['inference_ms_per_frame']:.1f} ms/frame" for s, r in results.items())]
    return "\n".join(lines) + "\n"


def frame_picture(path: Path, images: dict, truth, vis, pred, pred_vis, class_names, title: str):
    """The four fisheye images, the truth (dimmed where invisible), the prediction, the visibility."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    names = list(images)
    fig = plt.figure(figsize=(16, 7.4))
    gs = fig.add_gridspec(2, max(4, len(names)), height_ratios=[1, 1.6])
    for i, n in enumerate(names):
        ax = fig.add_subplot(gs[0, i])
        ax.imshow(images[n])
        ax.set_title(n, fontsize=9)
        ax.axis("off")
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


@torch.no_grad()
def evaluate_split(model, cfg, index: DatasetIndex, split: str, out: Path, pictures: int, save_predictions: bool) -> dict:
    from tqdm import tqdm

    ds = BevDataset(index, split, cfg, train=False)
    if len(ds) == 0:
        raise EvalError(f"{index.root}: split '{split}' has no frames")
    scores = SplitScores(ds.class_names, ds.grid)
    picture_at = set(np.linspace(0, len(ds) - 1, min(pictures, len(ds))).round().astype(int).tolist()) if pictures else set()
    if save_predictions:
        (out / "predictions").mkdir(parents=True, exist_ok=True)
    for i in tqdm(range(len(ds)), desc=f"eval {split}", dynamic_ncols=True):
        sample = ds[i]
        ref = ds.refs[i]
        t0 = time.perf_counter()
        geometry = [sample[k][None] if k in sample else None for k in ("point_cell", "intrinsics")]
        o = model(sample["images"][None], *geometry)  # none: the nominal cameras, the model's cached geometry
        scores.seconds += time.perf_counter() - t0
        pred = o["semantic"][0].argmax(0) + 1  # the head scores classes 1..K-1; invalid is never predicted
        occ = o["occlusion"][0]
        scores.update(pred, occ, sample["semantic"], sample["visibility"], ref.weather)
        name = f"{ref.scene}_{ref.frame:06d}"
        if save_predictions:
            buf = io.BytesIO()
            np.savez_compressed(buf, semantic=pred.numpy().astype(np.uint8), occlusion_logit=occ.numpy())
            write_bytes_atomic(out / "predictions" / f"{name}.npz", buf.getvalue())
        if i in picture_at:
            images = read_frame(ref, cameras=ds.names)["images"]
            frame_picture(out / f"frame_{split}_{name}.png", images, sample["semantic"].numpy(), sample["visibility"].numpy(),
                          pred.numpy(), torch.sigmoid(occ).numpy(), ds.class_names, f"{split}: {ref.scene} frame {ref.frame} ({ref.weather})")
    res = scores.result()
    confusion_picture(out / f"confusion_{split}.png", res["confusion"], ds.class_names, f"{split}: rows normalised, visible cells")
    return res


def main(argv=None) -> int:
    p = ArgumentParser(prog="eval.py", description="Evaluate a checkpoint with the paper's protocol (per-class IoU on visible cells).")
    p.add_argument("--checkpoint", required=True, help="a checkpoint of train.py (latest.pt or best.pt)")
    p.add_argument("--split", default="all", choices=[*SPLITS, "all"], help="all: every split that has frames, each scored alone")
    p.add_argument("--data", help="data set root (default: the one the checkpoint was trained on)")
    p.add_argument("--config", help="refuse the checkpoint unless it was trained with this config's model, input size and grid")
    p.add_argument("--out", help="output folder (default: <checkpoint folder>/eval)")
    p.add_argument("--pictures", type=int, default=4, help="frames per split drawn as pictures (default 4)")
    p.add_argument("--save-predictions", action="store_true", help="write every frame's prediction as predictions/<scene>_<frame>.npz")
    p.add_argument("--threads", type=int, default=0, help="torch threads (default: torch's choice)")
    a = p.parse_args(argv)
    if a.pictures < 0:
        raise EvalError(f"--pictures: must be >= 0, got {a.pictures}")
    if a.threads < 0:
        raise EvalError(f"--threads: must be >= 0, got {a.threads}")
    if a.threads:
        torch.set_num_threads(a.threads)
    expect = load_config(a.config) if a.config else None
    if not Path(a.checkpoint).is_file():
        raise EvalError(f"{a.checkpoint}: no such checkpoint")
    model, cfg, ckpt = load_checkpoint(a.checkpoint, expect_config=expect)
    model.eval()
    if a.data:
        cfg = {**cfg, "data": {**cfg["data"], "root": a.data}}
    index = DatasetIndex(cfg["data"]["root"])
    if index.rig.names != list(ckpt["rig"]["cameras"]):
        raise EvalError(f"{index.root}: rig cameras {index.rig.names} differ from the checkpoint's {list(ckpt['rig']['cameras'])}")
    if len(index.class_names) != ckpt.get("num_classes", 5):
        raise EvalError(f"{index.root}: {len(index.class_names)} classes, the checkpoint predicts {ckpt.get('num_classes', 5)}")
    splits = [s for s in SPLITS if index.splits.get(s)] if a.split == "all" else [a.split]
    if not splits:
        raise EvalError(f"{index.root}: no split has frames")
    out = Path(a.out) if a.out else Path(a.checkpoint).parent / "eval"
    output_dir(out)
    results = {s: evaluate_split(model, cfg, index, s, out, a.pictures, a.save_predictions) for s in splits}
    method = f"LSS-fisheye ({Path(a.checkpoint).parent.name}, {cfg['model']['pooling']} pooling)"
    report = {"checkpoint": str(a.checkpoint), "data": str(cfg["data"]["root"]), "step": ckpt.get("step"),
              "class_names": index.class_names, "splits": results}
    write_json_atomic(out / "metrics.json", report, indent=2)
    table = markdown_table(results, method)
    write_text_atomic(out / "table.md", table)
    print(table)
    print(f"written {out}/metrics.json, table.md, confusion_*.png and frame_*.png")
    return 0


if __name__ == "__main__":
    run_cli(main)
