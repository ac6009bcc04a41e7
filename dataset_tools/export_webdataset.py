"""Export a fused data set as WebDataset shards with a dataset card, for streaming and publishing.

    python -m dataset_tools export-webdataset DATA OUT [--shard-size N] [--license ID]

    OUT/<split>-<000000>.tar    one sample per frame (camera images, camera_targets.npy, BEV labels,
                                visibility, meta.json, frame.json; format.shards)
    OUT/shards.json             shards per split with their frame counts, and the data set's index
    OUT/README.md               the dataset card (Hugging Face front matter; dataset_tools.card)

The export is atomic: it is built in a hidden folder beside OUT which then replaces OUT (OUT must
be missing, empty or an earlier export). Training streams it with `data.shards:
"OUT/train-{000000..000012}.tar"` (docs/publishing.md).
"""

from __future__ import annotations

from pathlib import Path

from common.cli import ArgumentParser, run_cli
from common.errors import InputError
from common.files import build_folder

from .card import write_export_card
from .format.layout import DatasetError
from .format.reader import DatasetIndex
from .format.shards import DEFAULT_SHARD_SIZE, SHARDS_INDEX, write_shards


def export(data, out, shard_size: int = DEFAULT_SHARD_SIZE, license: str | None = None, progress: bool = True) -> dict:
    """Shards, shards.json and README.md of the data set `data` in `out`; returns shards.json's content."""
    from tqdm import tqdm

    data = Path(data)
    if not data.exists():
        raise InputError(f"DATA: {data}: missing")
    if not data.is_dir():
        raise InputError(f"DATA: {data}: is a file, not a data set folder")
    index = DatasetIndex(data)
    if not any(index.splits.values()):
        raise DatasetError(f"{data}: the index lists no frames")
    out = Path(out)
    if out.resolve() == data.resolve() or data.resolve() in out.resolve().parents:
        raise InputError(f"OUT: {out} is inside DATA; give a folder outside the data set")

    def fill(tmp: Path) -> dict:
        with tqdm(total=len(index.all_frames()), desc="export-webdataset", unit="frame", disable=not progress) as bar:
            summary = write_shards(index, tmp, shard_size, progress=lambda: bar.update(1))
        write_export_card(index, tmp, summary, license)
        return summary

    return build_folder(out, fill, SHARDS_INDEX)


def main(argv=None) -> int:
    p = ArgumentParser(prog="python -m dataset_tools export-webdataset",
                       description="Export a data set as WebDataset tar shards per split, with shards.json and a dataset card.")
    p.add_argument("data", help="a fused data set (index.json)")
    p.add_argument("out", help="output folder (missing, empty or an earlier export)")
    p.add_argument("--shard-size", type=int, default=DEFAULT_SHARD_SIZE, help=f"frames per shard (default {DEFAULT_SHARD_SIZE})")
    p.add_argument("--license", default=None, help="licence id of the renders for the card (default: the data set card's, else cc-by-4.0)")
    p.add_argument("--no-progress", action="store_true")
    a = p.parse_args(argv)
    if not 1 <= a.shard_size <= 100_000:
        p.error(f"--shard-size: must be 1..100000 frames, got {a.shard_size}")
    s = export(a.data, a.out, a.shard_size, a.license, progress=not a.no_progress)
    shards = sum(len(v["shards"]) for v in s["splits"].values())
    print(f"written {shards} shards to {a.out}: " + ", ".join(f"{k} {v['frames']} frames ({v['pattern']})" for k, v in s["splits"].items()))
    return 0


if __name__ == "__main__":
    run_cli(main)
