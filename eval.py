"""Evaluate a checkpoint with the paper's protocol.

    python eval.py --checkpoint runs/cpu_default/latest.pt --split {train,easy,medium,hard,heldout,all}
    python eval.py --compare RUN_A RUN_B [--split S] [--data DIR]      # A - B, paired over scenes
    python eval.py --compare RUN RUN --precision bf16 fp32              # the same checkpoint in bf16 against fp32

Per split: one confusion matrix over the whole split, on cells whose true visibility p(o) >= 0.5
and whose true class is valid; per-class IoU from it; occlusion IoU of the binarised visibility
(occluded = p(o) < 0.5, predicted vs true, every cell); mIoU = mean of the IoUs of occlusion,
vehicle, lane marking, street and background (the paper's definition). The same by distance band
(Euclidean distance of the cell centre from the ego origin) and by weather preset, and inference
time per frame. Every split, class and mIoU gets its 95 % interval from a bootstrap over scenes.
Writes metrics.json, table.md (laid out as the paper's Table I), a confusion-matrix picture and,
for a sample of frames, pictures as the paper's Figs. 6-8. `--compare A B` scores two checkpoints
on the same frames and reports A - B per split and class with its paired bootstrap interval
(comparison.json, comparison.md). The scoring itself is `model.evaluation`; this is its command line.
"""

from __future__ import annotations

import torch

from common.cli import ArgumentParser, run_cli
from common.resources import preset
from dataset_tools import SPLITS
from model.config import load_config
from model.evaluation import EvalError, compare_checkpoints, evaluate_checkpoint
from model.run_dir import EvalDir


def main(argv=None) -> int:
    p = ArgumentParser(prog="eval.py", description="Evaluate a checkpoint with the paper's protocol (per-class IoU on visible cells).")
    which = p.add_mutually_exclusive_group(required=True)
    which.add_argument("--checkpoint", help="a checkpoint of train.py (latest.pt or best.pt), or a run folder (its latest.pt)")
    which.add_argument("--compare", nargs=2, metavar=("RUN_A", "RUN_B"),
                       help="score two checkpoints (or run folders) on the same frames: A - B per split and class with its 95%% interval, paired over scenes")
    p.add_argument("--split", default="all", choices=[*SPLITS, "all"], help="all: every split that has frames, each scored alone")
    p.add_argument("--data", help="data set root (default: the one the checkpoint was trained on)")
    p.add_argument("--config", help="refuse the checkpoint unless it was trained with this config's model, input size and grid")
    p.add_argument("--out", help="output folder (default: <checkpoint folder>/eval; --compare: <A's folder>/compare_<B's folder name>)")
    p.add_argument("--pictures", type=int, default=4, help="frames per split drawn as pictures (default 4)")
    p.add_argument("--save-predictions", action="store_true", help="write every frame's prediction as predictions/<scene>_<frame>.npz")
    p.add_argument("--threads", type=int, default=0, help="torch threads (default: torch's choice)")
    p.add_argument("--device", default="auto", choices=("auto", "cpu", "cuda"),
                   help="where the model runs (auto: the GPU when there is one)")
    p.add_argument("--precision", nargs="+", choices=("fp32", "bf16"), metavar="P",
                   help="run the model in fp32 or bf16 (default: as trained); with --compare, A's then B's (one value: both)")
    a = p.parse_args(argv)
    if a.pictures < 0:
        raise EvalError(f"--pictures: must be >= 0, got {a.pictures}")
    if a.threads < 0:
        raise EvalError(f"--threads: must be >= 0, got {a.threads}")
    if a.threads:
        torch.set_num_threads(a.threads)
    precision = a.precision or [None]
    if len(precision) > (2 if a.compare else 1):
        raise EvalError(f"--precision: {'two values at most (A, B)' if a.compare else 'one value'}, got {len(precision)}")
    if a.compare:
        if a.config or a.save_predictions:
            raise EvalError("--compare: takes neither --config nor --save-predictions")
        table, out = compare_checkpoints(*a.compare, a.split, a.out, a.data, precision=(precision[0], precision[-1]),
                                         device=a.device)
        print(table)
        print(f"written {out}/{out.comparison.name} and {out.comparison_table.name}")
        return 0
    expect = load_config(preset(a.config, "train")) if a.config else None
    table, out = evaluate_checkpoint(a.checkpoint, a.split, a.out, a.data, expect, a.pictures, a.save_predictions, precision[0],
                                     a.device)
    print(table)
    print(f"written {out}/{out.metrics.name}, {out.table.name}, {EvalDir.CONFUSION_GLOB} and {EvalDir.FRAME_GLOB}")
    return 0


def cli() -> None:
    """The console entry point (fisheye-bev-eval, pyproject.toml)."""
    run_cli(main)


if __name__ == "__main__":
    cli()
