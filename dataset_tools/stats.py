"""The `python -m dataset_tools.stats` command (library: `dataset_tools.qa.stats`)."""

from common.cli import run_cli

from .qa.stats import main

if __name__ == "__main__":
    run_cli(main)
