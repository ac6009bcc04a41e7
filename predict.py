"""Run a checkpoint on your own images: BEV class ids and p(o) per frame, and a picture of each.

    python predict.py --checkpoint runs/demo/best.pt --frames FRAMES --rig RIG --out OUT

FRAMES is one frame (a folder with one image per rig camera, `<camera>.png|jpg` or `cam_<camera>.png`;
its sub-folders, such as another tool's depth/ or our labels/, are no frames of their own) or a
folder of such frame folders. RIG is any rig file `geometry.load_rig` reads (inline cameras,
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
`occlusion_logit` float32, on the model's BEV grid; model.inference.write_prediction, the writer
eval.py's predictions share) and OUT/<frame>.png, its classes named by the checkpoint. On a frame
of the training rig it computes what eval.py computes (tests/test_predict.py). The library behind
this command is model.inference (RigModel); this file is only its command line.
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch

from common.cli import ArgumentParser, run_cli
from common.files import output_dir
from dataset_tools.stitch import IMAGE_SUFFIXES, image_paths, read_image, rig_for, rig_of_images
from geometry.rig import load_rig
from model.checkpoint import in_precision, load_checkpoint
from model.eval_report import prediction_picture
from model.inference import PredictError, RigModel, in_model_order, write_prediction
from model.run_dir import checkpoint_path


def frame_folders(root: Path, names=None) -> list[Path]:
    """The frame folders of FRAMES: itself where it is one frame (a rendered frame, with its
    meta.json; or, given the rig's camera `names`, a folder with images of its own and no rendered
    frames below: a frame of another tool, whose sub-folders such as depth/ are no frames, and whose
    missing camera image is named), else its sub-folders that hold images, else itself."""
    def has_images(p: Path) -> bool:
        return any(f.suffix.lower() in IMAGE_SUFFIXES for f in p.iterdir() if f.is_file())

    if not root.is_dir():
        raise PredictError(f"{root}: no such folder")
    from dataset_tools.format.layout import META

    if (root / META).is_file():  # one rendered frame (its labels/ folder is no frame of its own)
        return [root]
    subs = sorted(p for p in root.iterdir() if p.is_dir())
    if names and has_images(root) and not any((p / META).is_file() for p in subs):
        image_paths(root, names)  # an image of each camera, or one line naming the first one missing
        return [root]
    frames = [p for p in subs if has_images(p)]
    if frames:
        return frames
    if not has_images(root):
        raise PredictError(f"{root}: no images, and no sub-folders with images")
    return [root]


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
    given = load_rig(a.rig) if a.rig else None
    frames = frame_folders(Path(a.frames), given.names if given else None)
    out = output_dir(Path(a.out))
    model, cfg, ckpt = load_checkpoint(checkpoint_path(a.checkpoint))
    if a.precision:
        cfg = in_precision(model, cfg, a.precision)
    class_names = ckpt["class_names"]
    described = False
    for frame in frames:
        rig = given or rig_for(frame, None)
        source = f"--rig {a.rig}" if a.rig else str(frame / "meta.json")
        if not described:  # once: what each camera of the rig became
            rig.print_description(a.rig or frame)
            described = True
        rig = in_model_order(rig, model.camera_names, source, cameras)  # before its images are looked for
        paths = image_paths(frame, rig.names)
        images = {n: read_image(q) for n, q in paths.items()}
        rig = rig_of_images(rig, images, paths)
        rm = RigModel(model, cfg, ckpt["rig"], rig, source, cameras)  # its geometry cached by calibration (model_view)
        pred = rm(images)
        name = frame.name
        write_prediction(out / f"{name}.npz", pred)
        if not a.no_pictures:
            prediction_picture(out / f"{name}.png", images, pred.classes[0].numpy(), pred.visibility[0].numpy(),
                               rm.frustum.grid, class_names, f"{name}: {Path(a.checkpoint).name} on rig '{rig.name}'")
        print(f"{frame}: written {out / name}.npz" + ("" if a.no_pictures else " and .png"), file=sys.stderr)
    return 0


def cli() -> None:
    run_cli(main)


if __name__ == "__main__":
    cli()
