"""The one place that knows the order of the data set stages: render (or merge parts rendered
apart), contact sheets, fuse, audit, report; then the dataset card (README.md).

    python -m dataset_tools dataset --config configs/dataset/small.yaml --out data/small [--workers N]
                                    [--backend ray [--address A] [--threads T]]

    build_dataset(load_config("configs/dataset/small.yaml"), "data/small")   # what `make dataset` runs
    build_dataset(cfg, "data/paper", parts=["parts/0", "parts/1"])           # what `merge` runs

The dataset config is loaded once (generation.dataset_config.load_config: its `labels:` section included,
so a mistake anywhere in it stops before anything renders) and handed to each stage, a library
function that returns its problems (one line each): generation.driver.render,
qa.contact_sheet.make_sheets, fuse.fuse_dataset (labels, then the camera-view targets),
qa.audit.run_audit, qa.html_report.run_report. The commands `generate`, `contact_sheet`, `fuse`,
`audit` and `report` are thin parsers over the same functions, so running the stages by hand
gives the same files. Every stage resumes: run it again after an interruption. A render or merge
that fails, or frames that cannot be fused, stop the pipeline; an audit above its threshold does
not (the report shows it), but the exit code is then EXIT_PROBLEMS. The stages after rendering run
in `--workers` processes, by default one per core (locally; they are per-frame numpy work).
"""

from __future__ import annotations

import os
from contextlib import ExitStack
from pathlib import Path

from common.backend import add_backend_args
from common.cli import EXIT_PROBLEMS, ArgumentParser, print_problems, require_positive, run_cli
from common.files import output_dir
from common.lock import hold_lock
from common.resources import dataset_config

from .card import write_dataset_card
from .format.merge_parts import merge
from .fuse import fuse_dataset
from .generation.dataset_config import load_config
from .generation.driver import plan, render
from .labels.label_fusion import FusionConfig
from .qa.audit import run_audit
from .qa.contact_sheet import make_sheets
from .qa.html_report import run_report

STAGES = ("render", "contact_sheets", "fuse", "audit", "report")
FATAL = {"render", "fuse"}  # their problems stop the pipeline; the audit's are reported, not fatal


def merge_parts(cfg: dict | None, out: Path, parts, progress: bool = True) -> list[str]:
    """The render stage for parts rendered apart (`generate --out` per node, `--shard i/N`): every
    frame of `cfg` (when given) must be in exactly one part."""
    expected = {(s["name"], f) for s, f in plan(cfg, (0, 1))} if cfg else None
    return [f"merge: {p}" for p in merge(out, [Path(p) for p in parts], expected, progress=progress)]


def contact_sheets(out: Path) -> list[str]:
    """One picture per scene (qa.contact_sheet); none to draw is not a problem of the pipeline."""
    make_sheets(out)
    return []


def build_dataset(cfg: dict | None, out, backend: str = "local", workers: int | None = None,
                  address: str | None = None, threads: int | None = None, parts=None, progress: bool = True,
                  config_path=None, rerender_changed: bool = False) -> int:
    """Render `cfg` (load_config) into `out` (or merge `parts` into it), then draw the contact sheets,
    fuse, audit and report, and write the dataset card (naming `config_path`, the config's file);
    the exit code. `cfg` may be None with `parts` (no check that every frame is there; default
    fusion). Holds `out`'s lock for the whole run (with `parts`, from after the merge, which checks
    the parts first and writes nothing when they do not fit)."""
    out = Path(out) if parts else output_dir(out)
    labels = cfg["labels"] if cfg else FusionConfig()
    # the stages after rendering are per-frame numpy work: every core unless told otherwise
    cores = (workers if backend == "local" else None) or os.cpu_count() or 1
    stages = {
        "render": ((lambda: merge_parts(cfg, out, parts, progress)) if parts
                   else (lambda: render(cfg, out, (0, 1), workers, progress, backend, address, threads or 1, rerender_changed))),
        "contact_sheets": lambda: contact_sheets(out),
        "fuse": lambda: fuse_dataset(out, labels, workers if backend != "local" else cores, progress=progress,
                                     backend=backend, address=address),
        "audit": lambda: run_audit(out, labels, progress=progress, workers=cores),
        "report": lambda: run_report(out, progress=progress, workers=cores),
    }
    result, locked = 0, False
    with ExitStack() as held:
        for stage in STAGES:
            if not locked and not (parts and stage == "render"):  # a second writer on this data set is refused
                held.enter_context(hold_lock(out))
                locked = True
            print(f"dataset: {'merge' if parts and stage == 'render' else stage}", flush=True)
            if print_problems(stages[stage]()):
                if stage in FATAL:  # the stage said why; run again to resume
                    return EXIT_PROBLEMS
                result = EXIT_PROBLEMS
        print(f"dataset: card {write_dataset_card(out, config_path)}", flush=True)  # README.md, the dataset card
    return result


def main(argv=None) -> int:
    ap = ArgumentParser(prog="python -m dataset_tools dataset",
                        description="Build a data set: render, contact sheets, fuse, audit, report, card (each resumable).")
    ap.add_argument("--config", required=True, type=dataset_config, help="configs/dataset/<preset>.yaml, or a preset's name (tiny, demo, ...)")
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--workers", type=int, default=None,
                    help="Blender processes and fusion processes (default: one Blender per core, one fusion process)")
    ap.add_argument("--threads", type=int, default=None, help="with --backend ray: CPU threads per Blender worker")
    add_backend_args(ap)
    ap.add_argument("--rerender-changed", action="store_true",
                    help="render again the scenes of --out whose recipe in the config changed since they were rendered")
    ap.add_argument("--no-progress", action="store_true")
    a = ap.parse_args(argv)
    require_positive("--workers", a.workers)
    require_positive("--threads", a.threads)
    return build_dataset(load_config(a.config), a.out, a.backend, a.workers, a.address, a.threads,
                         progress=not a.no_progress, config_path=a.config, rerender_changed=a.rerender_changed)



if __name__ == "__main__":
    run_cli(main)
