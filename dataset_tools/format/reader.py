"""Torch-free reader of a fused data set: the index, its splits, and one frame's images and labels.

    idx = DatasetIndex("data/small")
    for ref in idx.frames("train"):
        f = read_frame(ref)            # images {name: (H, W, 3) uint8 RGB}, semantic, instance,
                                       # visibility (float32 in [0, 1]), meta
    sem, vis = downsample_labels(f["semantic"], f["visibility"], 2)   # 0.125 m -> 0.25 m

Nothing here imports torch; `.rig` and `.grid` import `geometry` (which does) only when used.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .index import build_index, check_index, read_index
from .labels import read_labels
from .layout import INDEX, MANIFEST, DatasetError, FrameFiles, Manifest, frame_dir_name
from .meta import FrameMeta, read_meta
from .png import read_png

@dataclass(frozen=True)
class FrameRef:
    dir: Path
    scene: str
    frame: int
    split: str
    weather: str = ""
    own_rig: bool = False  # meta.json holds this frame's own (jittered) rig, not the index's

    @property
    def name(self) -> str:
        return frame_dir_name(self.scene, self.frame)


class DatasetIndex:
    """`<root>/index.json` (written by `python -m dataset_tools index`): splits -> frames, class
    names, label grid and rig. Without an index.json it is built in memory from the manifest."""

    def __init__(self, root, data: dict | None = None):
        self.root = Path(root)
        path = self.root / INDEX
        if data is not None:  # an index held elsewhere (an export's shards.json), checked as index.json is
            self.data = check_index(data, path)
        elif path.is_file():
            self.data = read_index(self.root)
        elif Manifest(self.root).exists():
            self.data = check_index(build_index(self.root), path)
        else:
            raise DatasetError(f"{path}: missing (and no {MANIFEST} to build it from)")
        self.class_names: list[str] = list(self.data["class_names"])
        self.splits: dict[str, list[FrameRef]] = {
            split: [FrameRef(self.root / e["dir"], str(e["scene"]), int(e["frame"]), split, str(e.get("weather", "")),
                             bool(e.get("own_rig", False))) for e in entries]
            for split, entries in self.data["splits"].items()
        }
        self._rig = None

    def frames(self, split: str) -> list[FrameRef]:
        if split not in self.splits:
            raise DatasetError(f"{self.root / INDEX}: no split '{split}' (have: {', '.join(self.splits)})")
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
        """The nominal rig the frames were rendered with (geometry Rig); a frame with `own_rig`
        was rendered through its meta.json `rig` (see rig_of_frame)."""
        if self._rig is None:
            from geometry.rig import rig_from_dict

            if "rig" not in self.data:
                raise DatasetError(f"{self.root / INDEX}: missing field 'rig'")
            self._rig = rig_from_dict(self.data["rig"], f"{self.root / INDEX}: rig")
        return self._rig

    def __repr__(self) -> str:
        sizes = ", ".join(f"{k}={len(v)}" for k, v in self.splits.items())
        return f"DatasetIndex({self.root}, {sizes})"


def read_frame(ref, cameras=None, num_classes: int | None = None, instance: bool = True) -> dict:
    """One frame: images {name: (H, W, 3) uint8 RGB}, semantic (uint8), instance (uint16),
    visibility (float32 in [0, 1]) and meta (FrameMeta). `ref` is a FrameRef or a frame directory;
    `cameras` picks camera names (default: every cam_<name>.png of the frame); `num_classes`
    refuses semantic ids beyond it; `instance=False` leaves the instance labels unread."""
    files = FrameFiles(ref.dir if isinstance(ref, FrameRef) else ref)
    names = files.camera_names() if cameras is None else list(cameras)
    if not names:
        raise DatasetError(f"{files.dir}: no cam_<name>.png images")
    images = {n: read_png(files.camera_png(n), np.uint8, 3) for n in names}
    out = {"images": images, **read_labels(files.dir, num_classes, instance=instance)}
    out["meta"] = read_meta(files.dir)
    return out


def rig_of_frame(ref, meta: FrameMeta, nominal):
    """The rig a frame was rendered with: its meta.json `rig` when the index marks it `own_rig`,
    else `nominal`."""
    return meta.camera_rig() if getattr(ref, "own_rig", False) else nominal


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
