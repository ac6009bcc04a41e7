"""Scoring a model: one loop (`score`) under validation during training (`validation_scores`),
eval.py (`evaluate_checkpoint`) and the ablation (`open_checkpoint` + `evaluate_splits`).

The protocol (docs/evaluation.md): per split, one confusion matrix over the whole split on cells
whose true visibility p(o) >= 0.5 and whose true class is valid; occlusion IoU of the binarised
visibility over every cell; the same by distance band and by weather preset, and inference time
per frame. Each split also keeps one confusion matrix per scene, from which `model.bootstrap`
gives every score's 95 % interval over scenes; `compare_checkpoints` (eval.py --compare) scores
two checkpoints on the same frames and bootstraps their difference, pairing the scenes.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
from torch.utils.data import DataLoader, Subset

from common.errors import InputError
from common.files import output_dir, write_json_atomic, write_text_atomic
from dataset_tools import SPLITS, DatasetIndex, read_frame

from .bootstrap import paired_bootstrap, per_scene_arrays, scene_bootstrap
from .checkpoint import in_precision, load_checkpoint
from .data import BevDataset, DataWorker
from .eval_report import comparison_table, confusion_picture, frame_picture, markdown_table
from .inference import pick_device, predict, to_device, write_prediction
from .metrics import BevMetrics, confusion, occlusion_confusion
from .run_dir import EvalDir, RunDir, checkpoint_path, frame_name

BANDS = ((0.0, 10.0), (10.0, 20.0), (20.0, 25.0))


class EvalError(InputError):
    pass


@torch.no_grad()
def score(model, ds, on_batch, frames=None, batch_size: int = 1, num_workers: int = 0, device=None,
          rank: int = 0, world: int = 1, desc: str | None = None) -> float:
    """`model` (in eval mode; its mode is restored after) over the frames `frames` of `ds` (default
    all; this process's share rank::world), calling on_batch(prediction, batch) for each batch.
    -> seconds spent in the model. The loader has its own generator, so scoring never draws from
    the global RNG (a resumed run stays identical to an uninterrupted one)."""
    training = model.training
    model.eval()
    indices = list(range(len(ds)) if frames is None else frames)[rank::world]
    # every worker builds a part of a batch (a worker builds whole batches, and frames are scored alone)
    batch_size = -(-batch_size // max(1, num_workers))
    loader = DataLoader(Subset(ds, indices), batch_size=batch_size, num_workers=num_workers, generator=torch.Generator(),
                        worker_init_fn=DataWorker())
    if desc is not None:
        from tqdm import tqdm

        loader = tqdm(loader, desc=desc, dynamic_ncols=True)
    seconds = 0.0
    for batch in loader:
        if device is not None:
            batch = to_device(batch, device)
        t0 = time.perf_counter()
        pred = predict(model, batch)
        if device is not None and torch.device(device).type == "cuda":
            torch.cuda.synchronize(device)  # the kernels run asynchronously: time them to the end
        seconds += time.perf_counter() - t0
        on_batch(pred, batch)
    model.train(training)
    return seconds


def validation_scores(model, ds, cfg, device, rank: int = 0, world: int = 1) -> dict:
    """Validation metrics of `model` on `ds` (train.val_max_frames of it; each process scores its
    share, then all-reduce)."""
    metrics = BevMetrics(ds.class_names)
    t = cfg["train"]
    n = len(ds) if not t["val_max_frames"] else min(len(ds), t["val_max_frames"])
    score(model, ds, metrics.update, range(n), max(1, t["batch_size"] // world), cfg["data"]["num_workers"], device, rank, world)
    if world > 1:
        for m in (metrics.cm, metrics.occ, metrics.tol):
            dist.all_reduce(m)
    return metrics.compute()


def band_masks(grid) -> dict[str, torch.Tensor]:
    """Band name -> (X, Y) bool mask of the cells whose centre lies in that distance band."""
    dist_m = torch.from_numpy(np.linalg.norm(grid.cell_centres(), axis=-1))
    return {f"{lo:g}-{hi:g} m": (dist_m >= lo) & (dist_m < hi) for lo, hi in BANDS}


class SplitScores:
    """Confusion matrices of one split: overall, per distance band, per weather preset and per scene
    (the bootstrap's unit: `result()["interval"]`)."""

    def __init__(self, class_names, grid):
        self.class_names = class_names
        self.overall = BevMetrics(class_names)
        self.bands = {name: (mask, BevMetrics(class_names)) for name, mask in band_masks(grid).items()}
        self.weather: dict[str, BevMetrics] = {}
        self.scenes: dict[str, BevMetrics] = {}
        self.frames = 0
        self.seconds = 0.0

    def add_frame(self, pred: torch.Tensor, occ_logit: torch.Tensor, semantic, visibility, weather: str, scene: str = ""):
        """One frame of `scene`: pred (X, Y) class ids, occ_logit (X, Y) visibility logits, truth (X, Y)."""
        k = len(self.class_names)
        cm, occ = confusion(pred, semantic, visibility, k), occlusion_confusion(occ_logit, visibility)
        self.overall.merge_(cm, occ)
        self.overall.add_tolerance(pred, semantic, visibility)
        self.weather.setdefault(weather or "unknown", BevMetrics(self.class_names)).merge_(cm, occ)
        self.scenes.setdefault(scene or "unknown", BevMetrics(self.class_names)).merge_(cm, occ)
        for mask, m in self.bands.values():
            m.merge_(confusion(pred[mask], semantic[mask], visibility[mask], k),
                     occlusion_confusion(occ_logit[mask], visibility[mask]))
        self.frames += 1

    def result(self) -> dict:
        scenes = {n: {"confusion": m.cm.tolist(), "occlusion_confusion": m.occ.tolist()} for n, m in sorted(self.scenes.items())}
        interval = scene_bootstrap(*per_scene_arrays(scenes), self.class_names) if scenes else {}
        return {
            "frames": self.frames,
            "inference_ms_per_frame": 1000 * self.seconds / max(self.frames, 1),
            "overall": self.overall.compute(),
            "confusion": self.overall.cm.tolist(),
            "occlusion_confusion": self.overall.occ.tolist(),
            "bands": {n: m.compute() for n, (_, m) in self.bands.items()},
            "weather": {n: m.compute() for n, m in sorted(self.weather.items())},
            "scenes": scenes,
            "interval": {key: list(v) for key, v in interval.items()},
        }


def evaluate_split(model, cfg, index: DatasetIndex, split: str, out: EvalDir, pictures: int = 0, save_predictions: bool = False) -> dict:
    """The protocol on one split, frame by frame; writes the split's confusion picture, `pictures`
    frame pictures and (save_predictions) every frame's prediction into `out`."""
    ds = BevDataset(index, split, cfg, train=False)
    if len(ds) == 0:
        raise EvalError(f"{index.root}: split '{split}' has no frames")
    scores = SplitScores(ds.class_names, ds.grid)
    picture_at = set(np.linspace(0, len(ds) - 1, min(pictures, len(ds))).round().astype(int).tolist()) if pictures else set()
    if save_predictions:
        out.predictions.mkdir(parents=True, exist_ok=True)

    def on_batch(pred, batch):
        for j, i in enumerate(batch["index"].tolist()):
            ref = ds.refs[i]
            classes, occ = pred.classes[j].cpu(), pred.occlusion_logit[j].cpu()
            semantic, visibility = batch["semantic"][j].cpu(), batch["visibility"][j].cpu()
            scores.add_frame(classes, occ, semantic, visibility, ref.weather, ref.scene)
            name = frame_name(ref)
            if save_predictions:
                write_prediction(out.prediction(name), pred, j)
            if i in picture_at:
                images = read_frame(ref, cameras=ds.names)["images"]
                frame_picture(out.frame(split, name), images, semantic.numpy(), visibility.numpy(), classes.numpy(),
                              torch.sigmoid(occ).numpy(), ds.class_names, f"{split}: {ref.scene} frame {ref.frame} ({ref.weather})")

    device = next(model.parameters()).device  # open_checkpoint's; on a GPU the loader's workers feed it
    workers = cfg["data"]["num_workers"] if device.type == "cuda" else 0
    scores.seconds = score(model, ds, on_batch, num_workers=workers, device=device, desc=f"eval {split}")
    res = scores.result()
    confusion_picture(out.confusion(split), res["confusion"], ds.class_names, f"{split}: rows normalised, visible cells")
    return res


def open_checkpoint(checkpoint, data=None, expect_config: dict | None = None, precision: str | None = None, label: str = "",
                    describe: bool = False, device: str = "cpu"):
    """-> (model in eval mode, config, checkpoint dict, DatasetIndex) for scoring a checkpoint on
    its data set (or on `data`, a data set root with the same rig and classes: the same cameras,
    calibrations up to a resize, and poses, not only the same names); `precision` (fp32 | bf16) runs
    it in another precision than it was trained in (model.precision). `label` ("--compare A") starts
    every error line, so that it says which checkpoint it is about. `describe`: print once what each
    camera of the checkpoint's rig became (as every command that loads a rig does). `device`: where
    the model runs (auto | cpu | cuda, model.inference.pick_device)."""
    from common.errors import InputError
    from geometry.rig import rig_difference, rig_from_dict

    head = f"{label}: " if label else ""
    try:
        if not Path(checkpoint).is_file():
            raise EvalError(f"{checkpoint}: no such checkpoint")
        model, cfg, ckpt = load_checkpoint(checkpoint, expect_config=expect_config)
        model.eval().to(pick_device(device))
        if precision:
            cfg = in_precision(model, cfg, precision)
        if data:
            cfg = {**cfg, "data": {**cfg["data"], "root": data}}
        index = DatasetIndex(cfg["data"]["root"])
        rig = rig_from_dict(ckpt["rig"], f"{checkpoint}: rig")
        diff = rig_difference(rig, index.rig)
        if diff:
            raise EvalError(f"{index.root}: rendered with another rig than the checkpoint {checkpoint} was trained on ({diff})")
        if len(index.class_names) != ckpt["num_classes"]:
            raise EvalError(f"{index.root}: {len(index.class_names)} classes, the checkpoint predicts {ckpt['num_classes']}")
    except InputError as exc:
        if not head:
            raise
        raise EvalError(f"{head}{exc}") from None
    if describe:
        rig.print_description(checkpoint)
    return model, cfg, ckpt, index


def evaluate_splits(model, cfg, index: DatasetIndex, splits, out: EvalDir, pictures: int = 0, save_predictions: bool = False) -> dict:
    """Split -> `evaluate_split` result, each split scored alone."""
    out.root.mkdir(parents=True, exist_ok=True)
    return {s: evaluate_split(model, cfg, index, s, out, pictures, save_predictions) for s in splits}


def evaluate_checkpoint(checkpoint, split: str = "all", out=None, data=None, expect_config: dict | None = None,
                        pictures: int = 4, save_predictions: bool = False, precision: str | None = None,
                        device: str = "cpu") -> tuple[str, EvalDir]:
    """eval.py: score a checkpoint (or a run folder's latest.pt) on `split` (one of SPLITS, or all:
    every split that has frames); writes metrics.json and table.md (and the pictures) into `out`
    (default: the run folder's eval/). -> (the Markdown table, the output folder)."""
    checkpoint = checkpoint_path(checkpoint)
    model, cfg, ckpt, index = open_checkpoint(checkpoint, data, expect_config, precision, describe=True, device=device)
    splits = [s for s in SPLITS if index.splits.get(s)] if split == "all" else [split]
    if not splits:
        raise EvalError(f"{index.root}: no split has frames")
    out = EvalDir(out) if out else RunDir.of_checkpoint(checkpoint).eval
    output_dir(out.root)
    results = evaluate_splits(model, cfg, index, splits, out, pictures, save_predictions)
    method = f"LSS-fisheye ({Path(checkpoint).parent.name}, {cfg['model']['pooling']} pooling)"
    report = {"checkpoint": str(checkpoint), "data": str(cfg["data"]["root"]), "step": ckpt.get("step"),
              "precision": cfg["model"]["precision"], "class_names": index.class_names, "splits": results}
    write_json_atomic(out.metrics, report, indent=2)
    table = markdown_table(results, method)
    write_text_atomic(out.table, table)
    return table, out


def _labelled(fn, arg, label: str):
    from common.errors import InputError

    try:
        return fn(arg)
    except InputError as exc:
        raise EvalError(f"{label}: {exc}") from None


def compare_checkpoints(checkpoint_a, checkpoint_b, split: str = "all", out=None, data=None, n: int = 1000,
                        precision: tuple[str | None, str | None] = (None, None), device: str = "cpu") -> tuple[str, EvalDir]:
    """eval.py --compare: score two checkpoints (or run folders) on the same frames (`data`, default
    A's data set) and bootstrap the difference A - B over scenes, paired (each resample draws the
    same scenes for both); `precision` (A's, B's) as open_checkpoint's. Writes comparison.json and comparison.md into `out` (default
    `<A's run folder>/compare_<B's run folder name>`), each side's confusion pictures in a/ and b/.
    -> (the Markdown table, the output folder)."""
    a = _labelled(checkpoint_path, checkpoint_a, "--compare A")
    b = _labelled(checkpoint_path, checkpoint_b, "--compare B")
    model_a, cfg_a, ckpt_a, index = open_checkpoint(a, data, precision=precision[0], label="--compare A", describe=True,
                                                    device=device)
    model_b, cfg_b, ckpt_b, _ = open_checkpoint(b, str(index.root), precision=precision[1], label="--compare B", describe=True,
                                              device=device)
    if cfg_a["data"]["grid"] != cfg_b["data"]["grid"]:
        raise EvalError(f"--compare B: {b}: scores on the grid {cfg_b['data']['grid']}, A ({a}) on {cfg_a['data']['grid']}: "
                        "not the same cells to compare")
    if ckpt_a["rig"] != ckpt_b["rig"]:
        from geometry.rig import rig_difference, rig_from_dict

        diff = rig_difference(rig_from_dict(ckpt_a["rig"], f"{a}: rig"), rig_from_dict(ckpt_b["rig"], f"{b}: rig"))
        if diff:
            raise EvalError(f"--compare B: {b}: trained on another rig than A ({a}): {diff}")
    splits = [s for s in SPLITS if index.splits.get(s)] if split == "all" else [split]
    if not splits:
        raise EvalError(f"{index.root}: no split has frames")
    out = EvalDir(out) if out else RunDir.of_checkpoint(a).comparison(RunDir.of_checkpoint(b).root.name)
    output_dir(out.root)
    for side in ("a", "b"):
        out.side(side).root.mkdir(parents=True, exist_ok=True)
    report = {"a": {"checkpoint": str(a), "step": ckpt_a.get("step"), "precision": cfg_a["model"]["precision"]},
              "b": {"checkpoint": str(b), "step": ckpt_b.get("step"), "precision": cfg_b["model"]["precision"]},
              "data": str(index.root), "class_names": index.class_names, "resamples": n, "splits": {}}
    for s in splits:
        ra = evaluate_split(model_a, cfg_a, index, s, out.side("a"))
        rb = evaluate_split(model_b, cfg_b, index, s, out.side("b"))
        if sorted(ra["scenes"]) != sorted(rb["scenes"]):
            raise EvalError(f"{index.root}: split '{s}' was not scored on the same scenes for both checkpoints")
        report["splits"][s] = {"frames": ra["frames"], "scenes": len(ra["scenes"]),
                               "difference": paired_bootstrap(per_scene_arrays(ra["scenes"]), per_scene_arrays(rb["scenes"]),
                                                              index.class_names, n),
                               "a": {k: ra[k] for k in ("overall", "interval", "scenes")},
                               "b": {k: rb[k] for k in ("overall", "interval", "scenes")}}
    write_json_atomic(out.comparison, report, indent=2)
    table = comparison_table(report)
    write_text_atomic(out.comparison_table, table)
    return table, out
