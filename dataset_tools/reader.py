"""Torch-free reader of a fused data set: the index, its splits, and one frame's images and labels.

    idx = DatasetIndex("data/small")
    for ref in idx.frames("train"):
        f = read_frame(ref)            # images {name: (H, W, 3) uint8 RGB}, semantic, instance,
                                       # visibility (float32 in [0, 1]), meta
    sem, vis = downsample_labels(f["semantic"], f["visibility"], 2)   # 0.125 m -> 0.25 m

Nothing here imports torch; `.rig` and `.grid` import `geometry` (which does) only when used.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

INDEX_FILE = "index.json"
MANIFEST_FILE = "manifest.jsonl"
SPLITS = ("train", "easy", "medium", "hard")
LABEL_DIR = "labels"
SEMANTIC_PNG = "semantic.png"
INSTANCE_PNG = "instance.png"
VISIBILITY_PNG = "visibility.png"
VISIBILITY_SCALE = 65535.0
DEFAULT_CLASS_NAMES = ["invalid", "vehicle", "lane_marking", "street", "background"]


class DatasetError(ValueError):
    """A data set file that cannot be read as expected (the message names the file and field)."""


@dataclass(frozen=True)
class FrameRef:
    dir: Path
    scene: str
    frame: int
    split: str
    weather: str = ""

    @property
    def name(self) -> str:
        return f"{self.scene}/{self.frame:06d}"


class DatasetIndex:
    """`<root>/index.json` (written by `python -m dataset_tools.index`): splits -> frames, class
    names, label grid and rig. Without an index.json it is built in memory from the manifest."""

    def __init__(self, root):
        self.root = Path(root)
        path = self.root / INDEX_FILE
        if path.is_file():
            self.data = _read_json(path)
        elif (self.root / MANIFEST_FILE).is_file():
            from .index import build_index

            self.data = build_index(self.root)
        else:
            raise DatasetError(f"{path}: missing (and no {MANIFEST_FILE} to build it from)")
        for key in ("splits", "class_names", "grid"):
            if key not in self.data:
                raise DatasetError(f"{path}: missing field '{key}'")
        self.class_names: list[str] = list(self.data["class_names"])
        self.splits: dict[str, list[FrameRef]] = {}
        for split, entries in self.data["splits"].items():
            refs = []
            for n, e in enumerate(entries):
                try:
                    refs.append(
                        FrameRef(self.root / e["dir"], str(e["scene"]), int(e["frame"]), split, str(e.get("weather", "")))
                    )
                except (KeyError, TypeError, ValueError):
                    raise DatasetError(f"{path}: splits.{split}[{n}]: needs 'dir', 'scene' and 'frame'") from None
            self.splits[split] = refs
        self._rig = None

    def frames(self, split: str) -> list[FrameRef]:
        if split not in self.splits:
            raise DatasetError(f"{self.root / INDEX_FILE}: no split '{split}' (have: {', '.join(self.splits)})")
        return list(self.splits[split])

    def all_frames(self) -> list[FrameRef]:
        return [r for s in self.splits.values() for r in s]

    @property
    def grid(self):
        """The label grid (geometry BevGrid, 0.125 m by default)."""
        from geometry.bev import BevGrid

        return BevGrid.from_dict(self.data["grid"])

    @property
    def rig(self):
        """The rig the frames were rendered with (geometry Rig)."""
        if self._rig is None:
            from geometry.rig import rig_from_dict

            if "rig" not in self.data:
                raise DatasetError(f"{self.root / INDEX_FILE}: missing field 'rig'")
            self._rig = rig_from_dict(self.data["rig"], f"{self.root / INDEX_FILE}: rig")
        return self._rig

    def __repr__(self) -> str:
        sizes = ", ".join(f"{k}={len(v)}" for k, v in self.splits.items())
        return f"DatasetIndex({self.root}, {sizes})"


def _read_json(path: Path):
    try:
        return json.loads(Path(path).read_text())
    except OSError as exc:
        raise DatasetError(f"{path}: cannot read ({exc.strerror})") from None
    except json.JSONDecodeError as exc:
        raise DatasetError(f"{path}: not valid JSON ({exc.msg}, line {exc.lineno})") from None


MANIFEST_FIELDS = ("scene", "frame", "split", "dir")


def manifest_lines(path: Path):
    """Yield (line number, entry, problem) for every non-blank line of a manifest: the parsed entry
    with every MANIFEST_FIELDS field and problem None, or entry None and a one-line problem."""
    for n, line in enumerate(Path(path).read_text().splitlines(), 1):
        if not line.strip():
            continue
        try:
            e = json.loads(line)
        except json.JSONDecodeError as exc:
            yield n, None, f"not valid JSON ({exc.msg})"
            continue
        if not isinstance(e, dict):
            yield n, None, "not a JSON object"
            continue
        missing = [k for k in MANIFEST_FIELDS if k not in e]
        if missing:
            yield n, None, f"missing field '{missing[0]}'"
        else:
            yield n, e, None


def read_png(path, dtype=None, channels: int | None = None) -> np.ndarray:
    """A PNG as stored (uint8 or uint16; RGB order for colour); checks dtype and channel count."""
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: missing")
    a = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if a is None:
        raise DatasetError(f"{path}: not a readable PNG")
    if a.ndim == 3:
        a = a[..., 2::-1] if a.shape[2] >= 3 else a
    if dtype is not None and a.dtype != np.dtype(dtype):
        raise DatasetError(f"{path}: pixel type {a.dtype}, expected {np.dtype(dtype)}")
    if channels is not None and (1 if a.ndim == 2 else a.shape[2]) != channels:
        raise DatasetError(f"{path}: {1 if a.ndim == 2 else a.shape[2]} channels, expected {channels}")
    return np.ascontiguousarray(a)


def camera_names(frame_dir) -> list[str]:
    """Camera names of a frame directory, from its cam_<name>.png files (sorted)."""
    return sorted(p.stem[4:] for p in Path(frame_dir).glob("cam_*.png"))


def read_labels(frame_dir) -> dict:
    """semantic (H, W) uint8, instance (H, W) uint16, visibility (H, W) float32 in [0, 1]."""
    d = Path(frame_dir) / LABEL_DIR
    sem = read_png(d / SEMANTIC_PNG, np.uint8, 1)
    ins = read_png(d / INSTANCE_PNG, np.uint16, 1)
    vis = read_png(d / VISIBILITY_PNG, np.uint16, 1)
    if not sem.shape == ins.shape == vis.shape:
        raise DatasetError(f"{d}: label shapes differ (semantic {sem.shape}, instance {ins.shape}, visibility {vis.shape})")
    return {"semantic": sem, "instance": ins, "visibility": vis.astype(np.float32) / VISIBILITY_SCALE}


def read_frame(ref, cameras=None) -> dict:
    """One frame: images {name: (H, W, 3) uint8 RGB}, semantic (uint8), instance (uint16),
    visibility (float32 in [0, 1]) and meta (dict). `ref` is a FrameRef or a frame directory;
    `cameras` picks camera names (default: every cam_<name>.png of the frame)."""
    frame_dir = Path(ref.dir if isinstance(ref, FrameRef) else ref)
    names = camera_names(frame_dir) if cameras is None else list(cameras)
    if not names:
        raise DatasetError(f"{frame_dir}: no cam_<name>.png images")
    images = {n: read_png(frame_dir / f"cam_{n}.png", np.uint8, 3) for n in names}
    out = {"images": images, **read_labels(frame_dir)}
    meta_path = frame_dir / "meta.json"
    out["meta"] = _read_json(meta_path) if meta_path.is_file() else {}
    return out


def downsample_labels(semantic: np.ndarray, visibility: np.ndarray, factor: int, priority=(2, 1), num_classes: int = 5):
    """Labels at `factor` times coarser cells (0.125 m -> 0.25 m is factor 2).

    A block of factor x factor cells takes the first class of `priority` present in it (default:
    lane_marking 2, then vehicle 1, so 10-15 cm lane lines survive), else the majority class
    (ties go to the lower class id); visibility is the block mean.
    """
    semantic = np.asarray(semantic)
    visibility = np.asarray(visibility, dtype=np.float32)
    factor = int(factor)
    if semantic.ndim != 2 or semantic.shape != visibility.shape:
        raise ValueError(f"downsample_labels: semantic {semantic.shape} and visibility {visibility.shape} must be one (H, W)")
    h, w = semantic.shape
    if factor < 1 or h % factor or w % factor:
        raise ValueError(f"downsample_labels: factor {factor} must divide the label size {h}x{w}")
    if factor == 1:
        return semantic.copy(), visibility.copy()
    hb, wb = h // factor, w // factor
    blocks = semantic.reshape(hb, factor, wb, factor).transpose(0, 2, 1, 3).reshape(hb, wb, factor * factor)
    counts = np.stack([(blocks == c).sum(-1) for c in range(num_classes)], -1)
    out = counts.argmax(-1).astype(semantic.dtype)  # argmax picks the lowest id on ties
    for c in reversed(priority):  # the first of `priority` wins, so apply it last
        out[counts[..., c] > 0] = c
    vis = visibility.reshape(hb, factor, wb, factor).mean(axis=(1, 3)).astype(np.float32)
    return out, vis
