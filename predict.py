"""Run a checkpoint on your own images: BEV class ids and p(o) per frame, and a picture of each.

    python predict.py --checkpoint runs/demo/best.pt --frames FRAMES --rig RIG --out OUT

FRAMES is one frame (a folder with one image per rig camera, `<camera>.png|jpg` or `cam_<camera>.png`)
or a folder of such frame folders. RIG is any rig file `geometry.load_rig` reads (inline cameras,
calibration files of OpenCV, Kalibr, OCamCalib or WoodScape); a rendered frame of ours needs none
(its meta.json has its rig). The rig must have as many cameras as the training rig; they are
matched to the model's cameras by name (ours: front, left, rear, right, the training rig's order),
or, where the rig names them otherwise, by `--cameras A,B,C,D`: the rig's cameras in the model's
order. The model lifts each image through its own camera and pose, and pools them in the model's
order (a pooling with per-camera parameters must get each camera in its own place). Each image is
brought to the model's input size with its camera (an image of another size than its calibration
is taken as a resize of it; one that cannot be, such as 1 x 1, is refused). What each camera of
the rig became (model, exact or fitted with its residual) is printed once.

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
from dataset_tools.stitch import IMAGE_SUFFIXES, image_paths, read_image, rig_for
from dataset_tools.stitch import rig_of_images as _rig_of_images
from geometry.rig import Rig, load_rig
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
    from dataset_tools.format.layout import META

    if (root / META).is_file():  # one rendered frame (its labels/ folder is no frame of its own)
        return [root]
    frames = sorted(p for p in root.iterdir() if p.is_dir() and has_images(p))
    if frames:
        return frames
    if not has_images(root):
        raise PredictError(f"{root}: no images, and no sub-folders with images")
    return [root]


def in_model_order(rig: Rig, model_names, source: str, cameras: list[str] | None = None) -> Rig:
    """The rig's cameras in the model's camera order: matched by name, or, where the rig names them
    otherwise, as `cameras` (--cameras: the rig's cameras in the model's order) says. Refused, naming
    `source` (the rig file or option), where the number of cameras or the names do not fit."""
    model_names = list(model_names)
    if len(rig) != len(model_names):
        raise PredictError(f"{source}: {len(rig)} cameras ({', '.join(rig.names)}), the model was trained with "
                           f"{len(model_names)} ({', '.join(model_names)})")
    if cameras is None:
        if set(rig.names) != set(model_names):
            raise PredictError(f"{source}: cameras {', '.join(rig.names)} are not the model's ({', '.join(model_names)}); "
                               f"give --cameras with the rig's cameras in the model's order")
        cameras = model_names
    elif sorted(cameras) != sorted(rig.names):
        raise PredictError(f"--cameras: {','.join(cameras)} must name each camera of {source} once ({', '.join(rig.names)})")
    return Rig([rig[n] for n in cameras], rig.name, rig.origins)


class RigModel:
    """A trained model and the lift geometry of one rig: the images of a frame -> Prediction."""

    def __init__(self, model, cfg: dict, train_rig_dict: dict, rig, source: str = "--rig", cameras: list[str] | None = None):
        self.model, self.cfg = model, cfg
        rig = in_model_order(rig, model.camera_names, source, cameras)
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


def rig_of_images(rig: Rig, images: dict, paths: dict | None = None) -> Rig:
    """The rig with each camera resized to its image (an image of another size than its calibration
    is a resize of it: its camera goes with it; one that cannot be is refused, naming the image)."""
    return _rig_of_images(rig, images, paths)


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
    p.add_argument("--cameras", help="the rig's cameras in the model's order, comma-separated (default: matched by name; "
                                     "needed where the rig names its cameras otherwise than the training rig)")
    a = p.parse_args(argv)
    cameras = [c.strip() for c in a.cameras.split(",")] if a.cameras else None
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
    given = load_rig(a.rig) if a.rig else None
    described = False
    for frame in frames:
        rig = given or rig_for(frame, None)
        source = f"--rig {a.rig}" if a.rig else str(frame / "meta.json")
        if not described:  # once: what each camera of the rig became
            for line in rig.describe():
                print(f"rig {a.rig or frame}: {line}")
            described = True
        rig = in_model_order(rig, model.camera_names, source, cameras)  # before its images are looked for
        paths = image_paths(frame, rig.names)
        images = {n: read_image(q) for n, q in paths.items()}
        rig = rig_of_images(rig, images, paths)
        key = str(rig.to_dict())
        if key not in rig_models:
            rig_models[key] = RigModel(model, cfg, ckpt["rig"], rig, source, cameras)
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
