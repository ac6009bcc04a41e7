"""The `python -m dataset_tools.contact_sheet` command (library: `dataset_tools.qa.contact_sheet`)."""

from common.cli import run_cli

from .qa.contact_sheet import main

if __name__ == "__main__":
    run_cli(main)
