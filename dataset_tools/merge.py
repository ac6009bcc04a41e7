"""Merge parts of a data set rendered apart into one: `python -m dataset_tools.merge OUT PART...`.

For clusters without a shared file system (`generate --out` per node) and Slurm job arrays
(`generate --shard i/N` per array task). `--config` also checks that no frame of the config is
missing. Library: dataset_tools.format.merge. Problems: one line each, exit 2, nothing written.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from common.cli import run_cli

from .format.merge import merge
from .generation.config import load_config
from .generation.driver import plan


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m dataset_tools.merge", description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="the merged data set (may be one of the parts)")
    ap.add_argument("parts", nargs="+", type=Path, help="generate --out folders")
    ap.add_argument("--config", type=Path, help="the dataset config the parts were rendered from: every frame must be there")
    ap.add_argument("--no-progress", action="store_true")
    a = ap.parse_args(argv)
    expected = None
    if a.config:
        expected = {(s["name"], f) for s, f in plan(load_config(a.config), (0, 1))}
    problems = merge(a.out, a.parts, expected, progress=not a.no_progress)
    for p in problems:
        print(f"merge: {p}", file=sys.stderr)
    return 2 if problems else 0


if __name__ == "__main__":
    run_cli(main)
