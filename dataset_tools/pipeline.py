"""The one place that knows the order of the data set stages: render (or merge parts rendered
apart), fuse, audit, report; then the dataset card (README.md).

    python -m dataset_tools dataset --config configs/dataset/small.yaml --out data/small [--workers N]
                                    [--backend ray [--address A] [--threads T]]

    build_dataset("configs/dataset/small.yaml", "data/small")            # what `make dataset` runs
    build_dataset(cfg, "data/paper", parts=["parts/0", "parts/1"])       # what `merge` runs

Each stage is its command (`python -m dataset_tools <stage>`) with the same options, so running
the stages by hand gives the same files. Every stage resumes: run it again after an interruption.
A render or merge that fails, or frames that cannot be fused, stop the pipeline; an audit above
its threshold does not (the report shows it), but the exit code is then EXIT_PROBLEMS.
"""

from __future__ import annotations

import sys
from pathlib import Path

from common.backend import add_backend_args
from common.cli import EXIT_PROBLEMS, ArgumentParser, run_cli
from common.resources import dataset_config

STAGES = ("render", "fuse", "audit", "report")


def _render(config, out, backend, workers, address, threads, progress) -> int:
    from . import generate

    argv = ["--config", str(config), "--out", str(out), "--backend", backend]
    argv += ["--address", address] if address else []
    argv += ["--workers", str(workers)] if workers else []
    argv += ["--threads", str(threads)] if threads else []
    return generate.main(argv + ([] if progress else ["--no-progress"]))


def _merge(config, out, parts, progress) -> int:
    """The render stage for parts rendered apart (`generate --out` per node, `--shard i/N`)."""
    from .format.merge import merge
    from .generation.config import load_config
    from .generation.driver import plan

    expected = None
    if config:
        expected = {(s["name"], f) for s, f in plan(load_config(config), (0, 1))}
    problems = merge(Path(out), [Path(p) for p in parts], expected, progress=progress)
    for p in problems:
        print(f"merge: {p}", file=sys.stderr)
    if problems:
        return EXIT_PROBLEMS
    from .qa.contact_sheet import make_sheets

    make_sheets(Path(out))  # as generate does after rendering
    return 0


def _fuse(config, out, backend, workers, address, progress) -> int:
    from . import fuse

    argv = [str(out), "--backend", backend]
    argv += ["--config", str(config)] if config else []
    argv += ["--address", address] if address else []
    argv += ["--workers", str(workers)] if workers else []
    return fuse.main(argv + ([] if progress else ["--no-progress"]))


def _audit(config, out, progress) -> int:
    from .qa import audit

    argv = [str(out)] + (["--config", str(config)] if config else [])
    return audit.main(argv + ([] if progress else ["--no-progress"]))


def _report(out, progress) -> int:
    from .qa import report

    return report.main([str(out)] + ([] if progress else ["--no-progress"]))


def build_dataset(config, out, backend: str = "local", workers: int | None = None, address: str | None = None,
                  threads: int | None = None, parts=None, progress: bool = True) -> int:
    """Render `config` into `out` (or merge `parts` into it), then fuse, audit and report; the exit code.
    `config` may be None with `parts` (no check that every frame is there; default fusion)."""
    stages = {
        "render": ((lambda: _merge(config, out, parts, progress)) if parts
                   else (lambda: _render(config, out, backend, workers, address, threads, progress))),
        "fuse": lambda: _fuse(config, out, backend, workers, address, progress),
        "audit": lambda: _audit(config, out, progress),
        "report": lambda: _report(out, progress),
    }
    result = 0
    for stage in STAGES:
        print(f"dataset: {'merge' if parts and stage == 'render' else stage}", flush=True)
        code = stages[stage]()
        if stage == "audit" and code == EXIT_PROBLEMS:  # labels above the audit's threshold: reported, not fatal
            result = code
        elif code:  # the stage said why; run again to resume
            return code
    from .card import write_dataset_card

    print(f"dataset: card {write_dataset_card(out, config)}", flush=True)  # README.md, the dataset card (issue 35)
    return result


def main(argv=None) -> int:
    ap = ArgumentParser(prog="python -m dataset_tools dataset",
                        description="Build a data set: render, fuse, audit, report (each resumable).")
    ap.add_argument("--config", required=True, type=dataset_config, help="configs/dataset/<preset>.yaml, or a preset's name (tiny, demo, ...)")
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--workers", type=int, default=None,
                    help="Blender processes and fusion processes (default: one Blender per core, one fusion process)")
    ap.add_argument("--threads", type=int, default=None, help="with --backend ray: CPU threads per Blender worker")
    add_backend_args(ap)
    ap.add_argument("--no-progress", action="store_true")
    a = ap.parse_args(argv)
    return build_dataset(a.config, a.out, a.backend, a.workers, a.address, a.threads, progress=not a.no_progress)


if __name__ == "__main__":
    run_cli(main)
