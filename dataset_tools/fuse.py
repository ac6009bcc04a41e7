"""Fuse every rendered frame of a data set into BEV labels, then (re)write index.json.

    python -m dataset_tools fuse <dataset> [--workers N] [--config configs/dataset/small.yaml] [--force]
                                 [--backend ray [--address ADDR]]

Resumable: a frame whose three label PNGs exist is skipped (each PNG is written atomically, the
visibility last); `--force` redoes every frame. Per-frame work is `labels.fusion.fuse_frame`, run
through common.backend: a local process pool, or Ray tasks in batches (`--backend ray`).
"""

from __future__ import annotations

import sys
from pathlib import Path

from common.backend import add_backend_args, make_backend
from common.cli import EXIT_PROBLEMS, ArgumentParser, run_cli
from common.files import clean_stale_temps
from common.lock import hold_lock

from .format.index import build_index, write_index
from .format.labels import write_labels
from .format.layout import DatasetError, FrameFiles, Manifest
from .labels.fusion import FusionConfig, fuse_frame


def fuse_one(frame_dir: str, cfg: FusionConfig):
    """(frame_dir, problem or None): fuse one frame and write its labels (idempotent)."""
    try:
        write_labels(frame_dir, fuse_frame(frame_dir, cfg))
        return frame_dir, None
    except (DatasetError, ValueError) as exc:
        return frame_dir, str(exc)


def frames_to_fuse(root, force: bool = False) -> list[str]:
    root = Path(root)
    todo = [str(root / e["dir"]) for e in Manifest(root).entries()]
    return todo if force else [d for d in todo if not FrameFiles(d).labels_done()]


def fuse_dataset(root, cfg: FusionConfig, workers: int = 1, force: bool = False, progress: bool = True,
                 backend: str = "local", address: str | None = None) -> list[str]:
    """Fuse every manifest frame that has no labels yet; returns the problems (one line each)."""
    from tqdm import tqdm

    root = Path(root)
    clean_stale_temps(root)
    todo = frames_to_fuse(root, force)
    problems = []
    with tqdm(total=len(todo), desc="fuse", unit="frame", disable=not progress) as bar:
        for _, err in make_backend(backend, workers, address).map(fuse_one, todo, shared=cfg):
            if err:
                problems.append(err)
            bar.update(1)
    write_index(root, build_index(root, cfg.class_names))
    return problems


def main(argv=None) -> int:
    ap = ArgumentParser(prog="python -m dataset_tools fuse",
                        description="Fuse rendered frames into BEV labels (semantic, instance, visibility).")
    ap.add_argument("dataset")
    ap.add_argument("--workers", type=int, default=1, help="processes (default 1)")
    ap.add_argument("--config", help="dataset config YAML whose 'labels:' section sets the fusion")
    ap.add_argument("--force", action="store_true", help="redo frames that already have labels")
    add_backend_args(ap)
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    if args.workers < 1:
        raise DatasetError(f"--workers: must be >= 1, got {args.workers}")
    cfg = FusionConfig.load(args.config) if args.config else FusionConfig()
    if not Manifest(args.dataset).exists():
        raise DatasetError(f"{Manifest(args.dataset).path}: missing")
    with hold_lock(args.dataset):  # a second fuse (or a generate) on this data set is refused
        problems = fuse_dataset(args.dataset, cfg, args.workers, args.force, progress=not args.no_progress,
                                backend=args.backend, address=args.address)
    for p in problems:
        print(f"error: {p}", file=sys.stderr)
    return EXIT_PROBLEMS if problems else 0


if __name__ == "__main__":
    run_cli(main)
