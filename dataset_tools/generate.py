"""Render a data set: `python -m dataset_tools generate --config configs/dataset/<preset>.yaml --out DIR`.

The render stage of dataset_tools.pipeline alone: `generation.driver.render` (planning, Blender
workers, manifest) on the config checked by `generation.dataset_config`. The contact sheets are the
pipeline's next stage (`python -m dataset_tools contact_sheet DIR`, or the whole `dataset`).
Bad input: one line, exit 2; scenes that fail: one line each, exit 1. Run again after an
interruption to resume. `--backend ray` renders on a Ray cluster (common.backend, docs/scaling.md).
"""

from __future__ import annotations

from pathlib import Path

from common.backend import add_backend_args
from common.cli import ArgumentParser, print_problems, require_positive, run_cli
from common.errors import ConfigError
from common.files import output_dir
from common.lock import hold_lock
from common.resources import dataset_config

from .generation.dataset_config import load_config
from .generation.driver import parse_shard, render


def main(argv=None) -> int:
    ap = ArgumentParser(prog="python -m dataset_tools generate", description="Render procedural road scenes through the fisheye rig.")
    ap.add_argument("--config", required=True, type=dataset_config, help="configs/dataset/<preset>.yaml, or a preset's name")
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--shard", default="0/1", help="i/N: render every N-th job starting at i")
    ap.add_argument("--workers", type=int, default=None,
                    help="Blender processes (default: one per core; with Ray: as many as the cluster's CPUs hold)")
    ap.add_argument("--threads", type=int, default=1, help="with --backend ray: CPU threads per Blender worker (default 1)")
    add_backend_args(ap)
    ap.add_argument("--scenes", nargs="+", default=None, metavar="NAME",
                    help="render only these scenes of the config (e.g. one sampled scene again)")
    ap.add_argument("--rerender-changed", action="store_true",
                    help="render again the scenes of --out whose recipe in the config changed since they were rendered")
    ap.add_argument("--no-progress", action="store_true")
    a = ap.parse_args(argv)
    shard = parse_shard(a.shard)
    require_positive("--workers", a.workers)
    require_positive("--threads", a.threads)
    cfg = load_config(a.config)
    if a.scenes:
        unknown = sorted(set(a.scenes) - {s["name"] for s in cfg["scenes"]})
        if unknown:
            raise ConfigError(f"--scenes: {a.config} has no scene '{unknown[0]}'")
        cfg["scenes"] = [s for s in cfg["scenes"] if s["name"] in a.scenes]
    out = output_dir(a.out)
    with hold_lock(out):  # a second generate on this --out is refused, naming the holder
        return print_problems(render(cfg, out, shard, a.workers, progress=not a.no_progress, backend=a.backend,
                                     address=a.address, threads=a.threads,
                                     rerender_changed=a.rerender_changed))


if __name__ == "__main__":
    run_cli(main)
