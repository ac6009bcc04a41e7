"""The `python -m dataset_tools.audit` command (library: `dataset_tools.qa.audit`)."""

from common.cli import run_cli

from .qa.audit import main

if __name__ == "__main__":
    run_cli(main)
