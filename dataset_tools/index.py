"""Build `<dataset>/index.json` from the manifest: splits -> frame dirs, class names, grid, rig.

    python -m dataset_tools.index <dataset>

The split of each frame comes from its manifest line (the scene recipe decides it: train, easy,
medium, hard). The rig is the calibration stored in the first frame's meta.json.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .reader import DEFAULT_CLASS_NAMES, INDEX_FILE, MANIFEST_FILE, SPLITS, DatasetError, _read_json, manifest_lines

DEFAULT_GRID = {"x_min": -25.0, "x_max": 25.0, "y_min": -25.0, "y_max": 25.0, "res": 0.125}


def read_manifest(root) -> list[dict]:
    """The manifest's lines (one per finished frame); the last line per (scene, frame) wins."""
    path = Path(root) / MANIFEST_FILE
    if not path.is_file():
        raise DatasetError(f"{path}: missing")
    entries: dict[tuple, dict] = {}
    for n, e, problem in manifest_lines(path):
        if problem:
            raise DatasetError(f"{path}: line {n}: {problem}")
        try:
            e["frame"] = int(e["frame"])
        except (TypeError, ValueError):
            raise DatasetError(f"{path}: line {n}: field 'frame' must be an integer") from None
        entries[(str(e["scene"]), e["frame"])] = e
    return [entries[k] for k in sorted(entries)]


def meta_rig(meta: dict):
    """The rig calibration dict stored in a frame's meta.json (None if absent)."""
    for key in ("rig", "rig_calibration", "calibration"):
        r = meta.get(key)
        if isinstance(r, dict) and isinstance(r.get("cameras"), dict):
            return r
    return None


def meta_weather(meta: dict) -> str:
    w = meta.get("weather", "")
    if isinstance(w, dict):
        w = w.get("preset", w.get("name", ""))
    return str(w)


def meta_grid(meta: dict):
    g = meta.get("grid") or (meta.get("topdown") or {}).get("grid")
    return g if isinstance(g, dict) and "res" in g else None


def build_index(root, class_names=None) -> dict:
    root = Path(root)
    entries = read_manifest(root)
    if not entries:
        raise DatasetError(f"{root / MANIFEST_FILE}: no frames")
    splits: dict[str, list] = {s: [] for s in SPLITS}
    rig = grid = None
    for e in entries:
        meta_path = root / e["dir"] / "meta.json"
        meta = _read_json(meta_path) if meta_path.is_file() else {}
        rig = rig or meta_rig(meta)
        grid = grid or meta_grid(meta)
        weather = e.get("weather") or meta_weather(meta)
        if isinstance(weather, dict):
            weather = weather.get("preset", weather.get("name", ""))
        splits.setdefault(str(e["split"]), []).append(
            {"dir": str(e["dir"]), "scene": str(e["scene"]), "frame": e["frame"], "weather": str(weather)}
        )
    index = {
        "version": 1,
        "class_names": list(class_names or DEFAULT_CLASS_NAMES),
        "grid": grid or dict(DEFAULT_GRID),
        "splits": splits,
    }
    if rig is not None:
        index["rig"] = rig
    return index


def write_index(root, index: dict) -> Path:
    from .exr import write_text_atomic

    path = Path(root) / INDEX_FILE
    write_text_atomic(path, json.dumps(index, indent=1))
    return path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="Build <dataset>/index.json from the manifest.")
    ap.add_argument("dataset")
    args = ap.parse_args(argv)
    try:
        index = build_index(args.dataset)
        path = write_index(args.dataset, index)
    except DatasetError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    sizes = ", ".join(f"{k} {len(v)}" for k, v in index["splits"].items())
    print(f"wrote {path}: {sizes}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
