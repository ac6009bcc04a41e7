"""The `python -m dataset_tools.validate` command (library: `dataset_tools.qa.validate`)."""

from common.cli import run_cli

from .qa.validate import main

if __name__ == "__main__":
    run_cli(main)
