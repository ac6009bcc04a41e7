"""Fuse every rendered frame of a data set into BEV labels, (re)write index.json, then derive each
frame's camera-view targets (`camera_targets.npy`, format.camera_targets) from its EXR passes.

    python -m dataset_tools fuse <dataset> [--workers N] [--config configs/dataset/small.yaml] [--force]
                                 [--backend ray [--address ADDR]]

Resumable: a frame whose three label PNGs look whole is skipped (each PNG is written atomically,
the visibility last); a label that is missing, empty, cut short or of the wrong size
(`format.labels.label_damage`: header, end and size, no decoding) is redone, with one notice line;
`--force` redoes every frame. Per-frame work is `labels.label_fusion.fuse_frame`, run through
common.backend: a local process pool (`--workers` processes), or Ray tasks in batches (`--backend
ray`; `--workers` then caps the batches running at once).
"""

from __future__ import annotations

import sys
from pathlib import Path

from common.backend import add_backend_args, make_backend
from common.cli import ArgumentParser, print_problems, require_positive, run_cli
from common.files import clean_stale_temps
from common.lock import hold_lock
from common.resources import dataset_config

from .format.camera_targets import derive_camera_targets, targets_path, write_camera_targets
from .format.index import build_index, write_index
from .format.labels import label_damage, write_labels
from .format.layout import DatasetError, FrameFiles, Manifest
from .format.meta import read_meta
from .generation.dataset_config import load_labels
from .labels.label_fusion import FusionConfig, fuse_frame


def fuse_one(frame_dir: str, cfg: FusionConfig):
    """(frame_dir, problem or None): fuse one frame and write its labels (idempotent)."""
    try:
        write_labels(frame_dir, fuse_frame(frame_dir, cfg))
        return frame_dir, None
    except (DatasetError, ValueError) as exc:
        return frame_dir, str(exc)


def frames_and_damage(root, force: bool = False) -> list[tuple[str, str | None]]:
    """(frame dir, why its existing labels are redone or None) for every frame to fuse: all with
    `force`, else those without three whole label PNGs."""
    root = Path(root)
    todo = [str(root / e["dir"]) for e in Manifest(root).entries()]
    if force:
        return [(d, None) for d in todo]
    out = []
    for d in todo:
        if not any(p.exists() for p in FrameFiles(d).label_paths()):
            out.append((d, None))  # never fused
            continue
        try:
            shape = read_meta(d).grid().shape
        except DatasetError:
            out.append((d, None))  # fusing it names the problem
            continue
        damage = label_damage(d, shape)
        if damage:
            out.append((d, damage))
    return out


def damage_notice(damaged: list[str]) -> str:
    """One line for the frames whose labels a resume redoes."""
    more = f" (and {len(damaged) - 1} more)" if len(damaged) > 1 else ""
    return f"fuse: redoing {len(damaged)} frame(s) whose labels are damaged: {damaged[0]}{more}"


def targets_one(frame_dir: str, _shared=None):
    """(frame_dir, problem or None): write the frame's camera-view targets (format.camera_targets)."""
    try:
        write_camera_targets(frame_dir, derive_camera_targets(frame_dir, FrameFiles(frame_dir).camera_names()))
        return frame_dir, None
    except (DatasetError, ValueError) as exc:
        return frame_dir, str(exc)


def fuse_dataset(root, cfg: FusionConfig, workers: int | None = None, force: bool = False, progress: bool = True,
                 backend: str = "local", address: str | None = None) -> list[str]:
    """The fuse stage: fuse every manifest frame that has no whole labels yet, write index.json,
    then the camera-view targets of every fused frame that has none (what training reads; derived
    here, never by the loader, so a data set is read-only once built); the problems, one line each."""
    from tqdm import tqdm

    root = Path(root)
    clean_stale_temps(root)
    planned = frames_and_damage(root, force)
    damaged = [why for _, why in planned if why]
    if damaged:
        print(damage_notice(damaged), file=sys.stderr)
    todo = [d for d, _ in planned]
    failed = {}
    pool = make_backend(backend, workers, address)
    with tqdm(total=len(todo), desc="fuse", unit="frame", disable=not progress) as bar:
        for d, err in pool.map(fuse_one, todo, shared=cfg):
            if err:
                failed[d] = err
            bar.update(1)
    write_index(root, build_index(root, cfg.class_names))
    frames = [str(root / e["dir"]) for e in Manifest(root).entries()]
    targets = [d for d in frames if d not in failed and (force or not targets_path(d).is_file())]
    with tqdm(total=len(targets), desc="camera targets", unit="frame", disable=not progress or not targets) as bar:
        for d, err in pool.map(targets_one, targets):
            if err:
                failed[d] = err
            bar.update(1)
    return [f"error: {err}" for err in failed.values()]


def main(argv=None) -> int:
    ap = ArgumentParser(prog="python -m dataset_tools fuse",
                        description="Fuse rendered frames into BEV labels (semantic, instance, visibility).")
    ap.add_argument("dataset")
    ap.add_argument("--workers", type=int, default=None,
                    help="processes (default 1); with --backend ray: at most this many batches at once (default: no cap)")
    ap.add_argument("--config", type=dataset_config, help="dataset config YAML whose 'labels:' section sets the fusion")
    ap.add_argument("--force", action="store_true", help="redo frames that already have labels")
    add_backend_args(ap)
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    require_positive("--workers", args.workers)
    cfg = load_labels(args.config) if args.config else FusionConfig()
    if not Manifest(args.dataset).exists():
        raise DatasetError(f"dataset: {Manifest(args.dataset).path}: missing (not a generated data set)")
    with hold_lock(args.dataset):  # a second fuse (or a generate) on this data set is refused
        problems = fuse_dataset(args.dataset, cfg, args.workers, args.force, progress=not args.no_progress,
                                backend=args.backend, address=args.address)
    return print_problems(problems)


if __name__ == "__main__":
    run_cli(main)
