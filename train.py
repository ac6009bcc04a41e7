"""Train the LSS-fisheye BEV model.

    python train.py [--config configs/train/cpu_medium.yaml] [--out runs/cpu_medium] [--set train.lr=1e-4 ...]
    torchrun --nproc_per_node 2 train.py --config ...          # DDP (gloo on CPU, nccl on GPU)

A run directory holds latest.pt, best.pt (best validation mIoU) and TensorBoard logs. Running the
same command again resumes from latest.pt and continues exactly as an uninterrupted run would.
The training itself is `model.training`; this is its command line.
"""

from __future__ import annotations

import contextlib
import os
import sys
from pathlib import Path

from common.cli import ArgumentParser, EXIT_INTERRUPTED, run_cli
from common.files import output_dir
from common.lock import hold_lock
from common.resources import preset
from model.config import load_config, parse_overrides
from model.run_dir import RunDir
from model.training import train


DEFAULT_CONFIG = "configs/train/cpu_medium.yaml"  # the Makefile's CONFIG (tests/test_model.py holds them equal)


def main(argv=None) -> int:
    p = ArgumentParser(prog="train.py", description="Train the LSS-fisheye BEV model.")
    p.add_argument("--config", default=DEFAULT_CONFIG,
                   help=f"a training config, or a preset's name (demo, cpu_default, ...); default {DEFAULT_CONFIG}")
    p.add_argument("--out", help="run directory (default runs/<config name>)")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.FIELD=VALUE", help="override a config field")
    p.add_argument("--quiet", action="store_true")
    a = p.parse_args(argv)
    cfg = load_config(preset(a.config, "train"), parse_overrides(a.set))
    out = Path(a.out or Path("runs") / Path(a.config).stem)
    output_dir(out)
    # one training run per run folder (rank 0 holds the lock for its DDP peers)
    lock = hold_lock(out) if int(os.environ.get("RANK", "0")) == 0 else contextlib.nullcontext()
    try:
        with lock:
            res = train(cfg, out, a.quiet)
    except KeyboardInterrupt:
        print(f"\ninterrupted; {RunDir(out).latest} holds the last whole step: run the same command to resume", file=sys.stderr)
        return EXIT_INTERRUPTED
    if int(os.environ.get("RANK", "0")) == 0 and not a.quiet:
        v = res["val"]
        print(f"done: step {res['step']}, last loss {res['losses'][-1] if res['losses'] else float('nan'):.4f}"
              + (f", val mIoU {v['miou']:.3f}" if v else ""), file=sys.stderr)
    return 0


def cli() -> None:
    """The console entry point (fisheye-bev-train, pyproject.toml)."""
    run_cli(main)


if __name__ == "__main__":
    cli()
