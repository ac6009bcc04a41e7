"""Build `<dataset>/index.json` from the manifest: splits -> frame dirs, class names, grid, rig.

The split of each frame comes from its manifest line (the scene recipe decides it: train, easy,
medium, hard). The rig is the calibration stored in the first frame's meta.json. The command is
`python -m dataset_tools.index <dataset>`.
"""

from __future__ import annotations

from pathlib import Path

from common.files import write_json_atomic

from ..labels.classes import TRAIN_CLASSES
from .layout import INDEX, MANIFEST, SPLITS, DatasetError, Manifest, read_meta

DEFAULT_GRID = {"x_min": -25.0, "x_max": 25.0, "y_min": -25.0, "y_max": 25.0, "res": 0.125}


def meta_rig(meta: dict, key: str = "rig"):
    """The rig calibration dict stored in a frame's meta.json (None if absent): `rig` the frame's
    own, `rig_nominal` the rig before the scene's jitter (older frames: their `rig`)."""
    r = meta.get(key) if key in meta else meta.get("rig")
    return r if isinstance(r, dict) and isinstance(r.get("cameras"), dict) else None


def meta_weather(meta: dict) -> str:
    w = meta.get("weather", "")
    if isinstance(w, dict):
        w = w.get("preset", "")
    return str(w)


def meta_grid(meta: dict):
    g = (meta.get("topdown") or {}).get("grid") if isinstance(meta.get("topdown"), dict) else None
    return g if isinstance(g, dict) and "res" in g else None


def build_index(root, class_names=None) -> dict:
    root = Path(root)
    entries = Manifest(root).entries()
    if not entries:
        raise DatasetError(f"{root / MANIFEST}: no frames")
    splits: dict[str, list] = {s: [] for s in SPLITS}
    rig = grid = None
    for e in entries:
        meta = read_meta(root / e["dir"])
        rig = rig or meta_rig(meta, "rig_nominal")
        grid = grid or meta_grid(meta)
        weather = e.get("weather") or meta_weather(meta)
        entry = {"dir": str(e["dir"]), "scene": str(e["scene"]), "frame": e["frame"], "weather": str(weather)}
        if meta_rig(meta) is not None and meta_rig(meta) != rig:
            entry["own_rig"] = True  # a per-frame rig (jittered): the reader lifts with meta.json's
        splits.setdefault(str(e["split"]), []).append(entry)
    index = {
        "version": 1,
        "class_names": list(class_names or TRAIN_CLASSES),
        "grid": grid or dict(DEFAULT_GRID),
        "splits": splits,
    }
    if rig is not None:
        index["rig"] = rig
    return index


def write_index(root, index: dict) -> Path:
    path = Path(root) / INDEX
    write_json_atomic(path, index)
    return path
