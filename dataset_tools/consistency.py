"""The `python -m dataset_tools.consistency` command (library: `dataset_tools.qa.consistency`)."""

from common.cli import run_cli

from .qa.consistency import main

if __name__ == "__main__":
    run_cli(main)
