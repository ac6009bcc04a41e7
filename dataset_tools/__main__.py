"""Every data set command, from one table: `python -m dataset_tools <command> [options]`
(installed: `fisheye-bev-dataset <command>`). `python -m dataset_tools` alone lists them;
`python -m dataset_tools <command> --help` shows a command's options.
"""

from __future__ import annotations

import importlib
import sys

from common.cli import ArgumentParser, run_cli
from common.errors import InputError

PROG = "python -m dataset_tools"

# name: (module with main(argv) -> exit code, what it does)
COMMANDS = {
    "dataset": ("dataset_tools.pipeline", "the whole pipeline: render, fuse, audit, report (what `make dataset` runs)"),
    "generate": ("dataset_tools.generate", "render a data set in Blender (resumable; --shard, --backend ray)"),
    "fuse": ("dataset_tools.fuse", "fuse rendered frames into BEV labels and write index.json (resumable)"),
    "merge": ("dataset_tools.merge", "merge parts rendered apart, then fuse, audit and report the result"),
    "audit": ("dataset_tools.qa.audit", "line-of-sight audit of the visibility labels -> audit.json"),
    "report": ("dataset_tools.qa.html_report", "the static HTML label QA report -> DATA/report/index.html"),
    "index": ("dataset_tools.reindex", "rebuild index.json from the manifest"),
    "contact_sheet": ("dataset_tools.qa.contact_sheet", "one picture per scene (fisheye images, top-down views)"),
    "inspect": ("dataset_tools.qa.inspect_frame", "every pass and label of a frame (or one EXR) as pictures"),
    "validate": ("dataset_tools.qa.validate", "check every file of a data set (and its audit)"),
    "consistency": ("dataset_tools.qa.consistency", "fisheye semantic pixels vs fused labels, per class"),
    "stats": ("dataset_tools.qa.stats", "class frequencies, visibility, coverage"),
    "export-woodscape": ("dataset_tools.export_woodscape", "export a data set in the WoodScape layout (images, calibration, semantic maps, polygons, 2D boxes)"),
    "export-webdataset": ("dataset_tools.export_webdataset", "export a data set as WebDataset tar shards per split, with shards.json and a dataset card"),
    "stitch": ("dataset_tools.stitch", "bird's-eye stitch of a rig's images (real or rendered) on the ground plane"),
}
ALIASES = {"contact-sheet": "contact_sheet"}


def usage() -> str:
    width = max(map(len, COMMANDS))
    rows = "\n".join(f"  {name:<{width}}  {what}" for name, (_, what) in COMMANDS.items())
    return f"usage: {PROG} <command> [options]   ({PROG} <command> --help)\n\ncommands:\n{rows}\n"


def command_main(name: str):
    """The main(argv) of a command of the table (InputError for an unknown name)."""
    name = ALIASES.get(name, name)
    if name not in COMMANDS:
        raise InputError(f"{PROG}: unknown command {name!r} (one of: {', '.join(COMMANDS)})")
    return importlib.import_module(COMMANDS[name][0]).main


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(usage(), end="")
        return 0
    if argv[0].startswith("-"):
        ArgumentParser(prog=PROG).error(f"the command comes first, got {argv[0]!r}")
    return command_main(argv[0])(argv[1:])


def cli() -> None:
    """The console entry point (`fisheye-bev-dataset`, pyproject.toml)."""
    run_cli(main, prog=PROG)


if __name__ == "__main__":
    cli()
