"""A torch Dataset over the data set index: 8-bit camera images and label PNGs (no EXR).

Each camera image is brought to the config's input size by a view transform that moves the camera
with it (`model.augment`), and the sample carries the lift geometry of those cameras (`point_cell`,
which BEV cell every lifted point lands in) and their intrinsics descriptors. Augmentation is drawn
from a generator seeded by (seed, epoch, sample index), so a sample is the same whichever worker or
DDP process loads it, and a resumed run sees the same data as an uninterrupted one.
"""

from __future__ import annotations

import numpy as np
import torch
from torch.utils.data import Dataset

from dataset_tools.reader import DatasetIndex, downsample_labels, read_frame
from geometry.bev import BevGrid

from .augment import ColorJitter, base_transform, random_transform, transform_camera, warp_image
from .lift import camera_point_cells, depth_bins, intrinsics_descriptor


class DataError(ValueError):
    pass


def label_factor(label_grid: BevGrid, model_grid: BevGrid, source: str = "data set") -> int:
    same = all(abs(getattr(label_grid, k) - getattr(model_grid, k)) < 1e-9 for k in ("x_min", "x_max", "y_min", "y_max"))
    f = model_grid.res / label_grid.res
    if not same or abs(f - round(f)) > 1e-9 or round(f) < 1:
        raise DataError(f"{source}: grid: labels {label_grid} cannot be pooled to the model grid {model_grid}")
    return int(round(f))


class BevDataset(Dataset):
    def __init__(self, index: DatasetIndex | str, split: str, cfg: dict, train: bool = False):
        self.index = index if isinstance(index, DatasetIndex) else DatasetIndex(index)
        self.refs = self.index.frames(split)
        self.rig = self.index.rig
        self.names = self.rig.names
        self.class_names = self.index.class_names
        # thin classes win a block when labels are pooled to the model grid (by name: the class map is configurable)
        self.priority = tuple(self.class_names.index(n) for n in ("lane_marking", "vehicle") if n in self.class_names)
        self.input_size = tuple(cfg["data"]["input_size"])
        self.grid = BevGrid.from_dict(cfg["data"]["grid"])
        self.factor = label_factor(self.index.grid, self.grid, str(self.index.root / "index.json"))
        m = cfg["model"]
        self.stride, self.z_range = m["stride"], tuple(m["z_range"])
        d = m["depth"]
        self.bins = depth_bins(d["min"], d["max"], d["bins"], d["spacing"]).astype(np.float32).astype(np.float64)
        self.seed = cfg["train"]["seed"]
        a = cfg["augment"]
        self.augment = a if (train and a["enabled"]) else None
        self.jitter = ColorJitter(**a["color_jitter"]) if self.augment else None
        self.epoch = 0
        self._nominal = None

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def __len__(self):
        return len(self.refs)

    def _geometry(self, transforms):
        pcs, intr = [], []
        for rc, t in zip(self.rig, transforms):
            rc2 = transform_camera(rc, t)
            pcs.append(camera_point_cells(rc2, self.stride, self.input_size, self.bins, self.grid, self.z_range))
            intr.append(intrinsics_descriptor(rc2.camera))
        return torch.from_numpy(np.stack(pcs)), torch.from_numpy(np.stack(intr))

    def __getitem__(self, i: int) -> dict:
        ref = self.refs[i]
        f = read_frame(ref, cameras=self.names)
        rng = np.random.default_rng([self.seed, self.epoch, i])  # independent streams: no collisions
        seed = int(rng.integers(2**63))  # the colour jitter's torch seed
        if self.augment:
            a = self.augment
            transforms = [random_transform(rc.camera, self.input_size, rng, a["scale"], a["rotation_deg"], a["crop"]) for rc in self.rig]
            point_cell, intrinsics = self._geometry(transforms)
        else:
            transforms = [base_transform(rc.camera, self.input_size) for rc in self.rig]
            if self._nominal is None:
                self._nominal = self._geometry(transforms)
            point_cell, intrinsics = self._nominal
        imgs = []
        for rc, t in zip(self.rig, transforms):
            img = f["images"][rc.name]
            if img.shape[:2] != (rc.camera.height, rc.camera.width):
                raise DataError(f"{ref.dir}/cam_{rc.name}.png: size {img.shape[1]}x{img.shape[0]}, rig says {rc.camera.width}x{rc.camera.height}")
            imgs.append(warp_image(img, rc.camera, t))
        images = torch.from_numpy(np.stack(imgs)).permute(0, 3, 1, 2).float() / 255.0
        if self.jitter is not None:
            with torch.random.fork_rng(devices=[]):
                torch.manual_seed(seed)
                images = self.jitter(images)
        sem, vis = f["semantic"], f["visibility"]
        if self.factor > 1:
            sem, vis = downsample_labels(sem, vis, self.factor, priority=self.priority, num_classes=len(self.class_names))
        if sem.shape != self.grid.shape:
            raise DataError(f"{ref.dir}/labels/semantic.png: {sem.shape} after pooling, model grid is {self.grid.shape}")
        return {
            "images": images,
            "point_cell": point_cell,
            "intrinsics": intrinsics,
            "semantic": torch.from_numpy(sem.astype(np.int64)),
            "visibility": torch.from_numpy(np.ascontiguousarray(vis, dtype=np.float32)),
            "index": i,
        }
