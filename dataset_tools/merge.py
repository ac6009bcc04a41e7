"""Merge parts of a data set rendered apart into one, then fuse, audit and report it:
`python -m dataset_tools merge OUT PART... [--config CFG]`.

For clusters without a shared file system (`generate --out` per node) and Slurm job arrays
(`generate --shard i/N` per array task). `--config` also checks that no frame of the config is
missing and sets the fusion. Library: dataset_tools.format.merge_parts; the stages after it:
dataset_tools.pipeline. Problems: one line each, exit 1 (EXIT_PROBLEMS), nothing written.
"""

from __future__ import annotations

from pathlib import Path

from common.backend import add_backend_args
from common.cli import ArgumentParser, require_positive, run_cli
from common.resources import dataset_config

from .generation.dataset_config import load_config
from .pipeline import build_dataset


def main(argv=None) -> int:
    ap = ArgumentParser(prog="python -m dataset_tools merge", description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="the merged data set (may be one of the parts)")
    ap.add_argument("parts", nargs="+", type=Path, help="generate --out folders")
    ap.add_argument("--config", type=dataset_config, help="the dataset config the parts were rendered from: every frame must be there")
    ap.add_argument("--workers", type=int, default=None, help="fusion processes (default 1)")
    add_backend_args(ap)
    ap.add_argument("--no-progress", action="store_true")
    a = ap.parse_args(argv)
    require_positive("--workers", a.workers)
    cfg = load_config(a.config) if a.config else None
    return build_dataset(cfg, a.out, a.backend, a.workers, a.address, parts=a.parts, progress=not a.no_progress,
                         config_path=a.config)


if __name__ == "__main__":
    run_cli(main)
