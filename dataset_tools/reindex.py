"""Build `<dataset>/index.json` from the manifest: `python -m dataset_tools index <dataset>`
(the library is `format.index`)."""

from __future__ import annotations


from common.cli import ArgumentParser, run_cli

from .format.index import build_index, write_index


def main(argv=None) -> int:
    ap = ArgumentParser(prog="python -m dataset_tools index", description="Build <dataset>/index.json from the manifest.")
    ap.add_argument("dataset")
    args = ap.parse_args(argv)
    index = build_index(args.dataset)
    path = write_index(args.dataset, index)
    sizes = ", ".join(f"{k} {len(v)}" for k, v in index["splits"].items())
    print(f"wrote {path}: {sizes}")
    return 0


if __name__ == "__main__":
    run_cli(main)
