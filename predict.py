"""Run a checkpoint on your own images: BEV class ids and p(o) per frame, and a picture of each.

    python predict.py --checkpoint runs/demo/best.pt --frames FRAMES --rig RIG --out OUT

FRAMES is one frame (a folder with one image per rig camera, `<camera>.png|jpg` or `cam_<camera>.png`)
or a folder of such frame folders. RIG is any rig file `geometry.load_rig` reads (inline cameras,
calibration files of OpenCV, Kalibr, OCamCalib or WoodScape); a rendered frame of ours needs none
(its meta.json has its rig). The rig must have as many cameras as the training rig, listed in the
same order (front, rear, left, right for ours): the model lifts each image through its own camera
and pose, and pools them in that order. Each image is brought to the model's input size with its
camera (an image of another size than its calibration is taken as a resize of it).

Writes OUT/<frame>.npz (`semantic` uint8 class ids 1..K-1, `visibility` float32 p(o),
`occlusion_logit` float32, on the model's BEV grid) and OUT/<frame>.png. On a frame of the training
rig it computes what eval.py computes (tests/test_predict.py).
"""

from __future__ import annotations

import io
import sys
from pathlib import Path

import numpy as np
import torch

from common.cli import ArgumentParser, run_cli
from common.errors import InputError
from common.files import output_dir, write_bytes_atomic
from dataset_tools.stitch import IMAGE_SUFFIXES, read_images, rig_for
from geometry.rig import Rig, RigCamera
from model.augment import warp_image
from model.checkpoint import in_precision, load_checkpoint
from model.frustum import Frustum
from model.predict import Prediction, predict
from model.rectified import model_rig, rectifier
from model.run_dir import checkpoint_path


class PredictError(InputError):
    pass


def frame_folders(root: Path) -> list[Path]:
    """The frame folders of FRAMES: its sub-folders that hold images, else itself."""
    def has_images(p: Path) -> bool:
        return any(f.suffix.lower() in IMAGE_SUFFIXES for f in p.iterdir() if f.is_file())

    if not root.is_dir():
        raise PredictError(f"{root}: no such folder")
    frames = sorted(p for p in root.iterdir() if p.is_dir() and has_images(p))
    if frames:
        return frames
    if not has_images(root):
        raise PredictError(f"{root}: no images, and no sub-folders with images")
    return [root]


class RigModel:
    """A trained model and the lift geometry of one rig: the images of a frame -> Prediction."""

    def __init__(self, model, cfg: dict, train_rig_dict: dict, rig):
        self.model, self.cfg = model, cfg
        if len(rig) != len(model.camera_names):
            raise PredictError(f"rig '{rig.name}': {len(rig)} cameras, the model was trained with {len(model.camera_names)} "
                               f"({', '.join(model.camera_names)})")
        self.rig = rig
        self.rectify = rectifier(rig, cfg)
        self.frustum = Frustum(model_rig(rig, cfg), cfg)
        # the training rig itself: the model's own cached geometry, as eval uses it
        self.geometry = None if rig.to_dict() == train_rig_dict else tuple(t[None] for t in self.frustum.nominal)

    def inputs(self, images: dict) -> torch.Tensor:
        out = []
        for rc, t, src in zip(self.frustum.rig, self.frustum.nominal_transforms(), self.rig):
            img = images[src.name]
            if self.rectify:
                img = self.rectify(src.name, img)
            out.append(warp_image(img, rc.camera, t))
        return (torch.from_numpy(np.stack(out)).permute(0, 3, 1, 2).float() / 255.0)[None]

    @torch.no_grad()
    def __call__(self, images: dict) -> Prediction:
        batch = {"images": self.inputs(images)}
        if self.geometry is not None:
            batch["point_cell"], batch["intrinsics"] = self.geometry
        self.model.eval()
        return predict(self.model, batch)


def rig_of_images(rig: Rig, images: dict) -> Rig:
    """The rig with each camera resized to its image (an image of another size than its calibration
    is a resize of it: its camera goes with it)."""
    def fit(rc):
        h, w = images[rc.name].shape[:2]
        return rc.camera if (h, w) == (rc.camera.height, rc.camera.width) else rc.camera.resized(w, h)

    return Rig([RigCamera(rc.name, fit(rc), rc.cam_to_ego) for rc in rig], rig.name)


def save_prediction(path: Path, pred: Prediction) -> None:
    buf = io.BytesIO()
    np.savez_compressed(buf, semantic=pred.classes[0].numpy().astype(np.uint8), visibility=pred.visibility[0].numpy().astype(np.float32),
                        occlusion_logit=pred.occlusion_logit[0].numpy().astype(np.float32))
    write_bytes_atomic(path, buf.getvalue())


def picture(path: Path, images: dict, pred: Prediction, grid, class_names, title: str) -> None:
    """The images, the prediction and p(o) over the metric grid (metres, forward up, left left)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    from common.files import write_figure_atomic
    from dataset_tools import TRAIN_PALETTE, colorize_train
    from model.eval_report import camera_row

    fig = plt.figure(figsize=(4 * max(4, len(images)), 8))
    gs = fig.add_gridspec(2, max(4, len(images)), height_ratios=[1, 1.8])
    camera_row(fig, gs, images)
    extent = (grid.y_max, grid.y_min, grid.x_min, grid.x_max)  # columns run from +y (left) to -y
    for j, (img, t) in enumerate([(colorize_train(pred.classes[0].numpy()), "predicted classes"),
                                  (pred.visibility[0].numpy(), "predicted visibility p(o)")]):
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
    plt.close(fig)


def main(argv=None) -> int:
    p = ArgumentParser(prog="predict.py", description="Run a checkpoint on your own images (one image per rig camera per frame).")
    p.add_argument("--checkpoint", required=True, help="a checkpoint of train.py, or a run folder (its latest.pt)")
    p.add_argument("--frames", required=True, help="a frame folder (one image per camera) or a folder of frame folders")
    p.add_argument("--rig", help="rig file (any format geometry.load_rig reads); default: a rendered frame's own rig")
    p.add_argument("--out", required=True, help="output folder: <frame>.npz and <frame>.png")
    p.add_argument("--no-pictures", action="store_true", help="write only the .npz predictions")
    p.add_argument("--threads", type=int, default=0, help="torch threads (default: torch's choice)")
    p.add_argument("--precision", choices=("fp32", "bf16"), help="run the model in fp32 or bf16 (default: as trained)")
    a = p.parse_args(argv)
    if a.threads < 0:
        raise PredictError(f"--threads: must be >= 0, got {a.threads}")
    if a.threads:
        torch.set_num_threads(a.threads)
    frames = frame_folders(Path(a.frames))
    out = output_dir(Path(a.out))
    model, cfg, ckpt = load_checkpoint(checkpoint_path(a.checkpoint))
    if a.precision:
        cfg = in_precision(model, cfg, a.precision)
    from dataset_tools import TRAIN_CLASSES

    class_names = list(TRAIN_CLASSES)[: ckpt["num_classes"]]
    rig_models: dict = {}
    for frame in frames:
        rig = rig_for(frame, a.rig)
        images = read_images(frame, rig.names)
        rig = rig_of_images(rig, images)
        key = str(rig.to_dict())
        if key not in rig_models:
            rig_models[key] = RigModel(model, cfg, ckpt["rig"], rig)
        rm = rig_models[key]
        pred = rm(images)
        name = frame.name
        save_prediction(out / f"{name}.npz", pred)
        if not a.no_pictures:
            picture(out / f"{name}.png", images, pred, rm.frustum.grid, class_names, f"{name}: {Path(a.checkpoint).name} on rig '{rig.name}'")
        print(f"{frame}: written {out / name}.npz" + ("" if a.no_pictures else " and .png"), file=sys.stderr)
    return 0


def cli() -> None:
    run_cli(main)


if __name__ == "__main__":
    cli()
