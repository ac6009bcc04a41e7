"""The `python -m dataset_tools.report` command (library: `dataset_tools.qa.report`)."""

from common.cli import run_cli

from .qa.report import main

if __name__ == "__main__":
    run_cli(main)
