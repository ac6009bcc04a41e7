"""`<dataset>/index.json`: splits -> frame dirs, class names, grid, rig. One builder (from the
manifest), one writer and one reader (which checks the version and the fields).

The split of each frame comes from its manifest line (the scene recipe decides it: train, easy,
medium, hard). The rig is the nominal calibration stored in the first frame's meta.json. The
command is `python -m dataset_tools index <dataset>`.
"""

from __future__ import annotations

from pathlib import Path

from common.files import read_json, write_json_atomic

from .layout import INDEX, MANIFEST, SPLITS, DatasetError, Manifest
from .meta import read_meta

INDEX_VERSION = 1  # bump when the layout of index.json changes
# The paper's training classes: the class names of an index built without a fusion config.
DEFAULT_CLASS_NAMES = ("invalid", "vehicle", "lane_marking", "street", "background")


def build_index(root, class_names=None) -> dict:
    root = Path(root)
    entries = Manifest(root).entries()
    if not entries:
        raise DatasetError(f"{root / MANIFEST}: no frames")
    splits: dict[str, list] = {s: [] for s in SPLITS}
    rig = grid = None
    for e in entries:
        meta = read_meta(root / e["dir"])
        rig = rig or meta.nominal_rig
        grid = grid or meta.topdown["grid"]
        weather = e.get("weather") or meta.weather_preset
        entry = {"dir": str(e["dir"]), "scene": str(e["scene"]), "frame": e["frame"], "weather": str(weather)}
        if meta.rig != rig:
            entry["own_rig"] = True  # a per-frame rig (jittered): the reader lifts with meta.json's
        splits.setdefault(str(e["split"]), []).append(entry)
    return {
        "version": INDEX_VERSION,
        "class_names": list(class_names or DEFAULT_CLASS_NAMES),
        "grid": grid,
        "splits": splits,
        "rig": rig,
    }


def write_index(root, index: dict) -> Path:
    path = Path(root) / INDEX
    write_json_atomic(path, index)
    return path


def check_index(index, path) -> dict:
    """`index` (the parsed index.json at `path`) if its version and fields are right, else one
    DatasetError line naming the field."""
    if not isinstance(index, dict):
        raise DatasetError(f"{path}: must be a JSON object")
    if index.get("version") != INDEX_VERSION:
        raise DatasetError(f"{path}: field 'version' is {index.get('version')!r}, this code reads version {INDEX_VERSION} "
                           f"(rebuild it: python -m dataset_tools index {Path(path).parent})")
    for key, kind in (("splits", dict), ("class_names", list), ("grid", dict)):
        if not isinstance(index.get(key), kind):
            raise DatasetError(f"{path}: field '{key}' missing or not a {'mapping' if kind is dict else 'list'}")
    if not index["class_names"] or not all(isinstance(n, str) for n in index["class_names"]):
        raise DatasetError(f"{path}: field 'class_names' must be a list of names")
    if "rig" in index and not isinstance(index["rig"], dict):
        raise DatasetError(f"{path}: field 'rig' must be a mapping (the rig calibration)")
    for split, entries in index["splits"].items():
        if not isinstance(entries, list):
            raise DatasetError(f"{path}: splits.{split}: must be a list of frames")
        for n, e in enumerate(entries):
            try:
                d = Path(e["dir"])
                str(e["scene"]), int(e["frame"])
            except (KeyError, TypeError, ValueError):
                d = None
            if d is None or d.is_absolute() or ".." in d.parts:
                raise DatasetError(f"{path}: splits.{split}[{n}]: needs 'dir', 'scene' and 'frame'")
    return index


def read_index(root) -> dict:
    """`<root>/index.json`, checked (check_index); DatasetError when missing or bad."""
    path = Path(root) / INDEX
    if not path.is_file():
        raise DatasetError(f"{path}: missing (python -m dataset_tools index {root})")
    return check_index(read_json(path, DatasetError), path)
