"""The `python -m dataset_tools.inspect` command (library: `dataset_tools.qa.inspect`)."""

from common.cli import run_cli

from .qa.inspect import main

if __name__ == "__main__":
    run_cli(main)
