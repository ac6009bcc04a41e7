"""A torch Dataset over the data set index: 8-bit camera images and label PNGs (no EXR).

Each camera image is brought to the config's input size by a view transform that moves the camera
with it (`model.augment`). An augmented sample carries the lift geometry of its cameras
(`point_cell`, which BEV cell every lifted point lands in, and, for the intrinsics-embedding
pooling, their intrinsics descriptors, and, for the ground image, `ground_grid`, where each cell's
ground point lies in each input image, from `model.frustum.Frustum`); a sample without
augmentation carries none, and the model uses its cached nominal geometry. A frame rendered
through its own (jittered) rig (`FrameRef.own_rig`) is lifted with that rig: in a split holding
such frames every sample carries its geometry, so a batch never mixes samples with and without it.
Augmentation is drawn from a generator seeded by (seed, epoch, sample index), so a sample is the
same whichever worker or DDP process loads it, and a resumed run sees the same data as an
uninterrupted one. A mirrored sample (`augment.mirror`) has its images, camera-view targets and
labels flipped along y and its lift geometry mirrored (`model.frustum.mirrored_cells`). A turned sample
(`augment.bev_rotation_deg`) keeps its images and has its world turned about the ego z axis: its rig's poses
and labels turned (`Frustum.geometry(yaw=)`, `BevGrid.turned`), and `bev_known` marks the cells whose
label came from inside the grid (the losses leave the others out).
On a GPU (`device_images`) the images leave the loader as 8 bits with their colour jitter's draws, and
`finish` converts and jitters the batch on the device (the same draws, the same kornia steps).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch.utils.data import Dataset

from common.errors import InputError
from common.lifetime import LoaderWorker
from dataset_tools.format.camera_targets import camera_targets as read_camera_passes
from dataset_tools.format.layout import INDEX, FrameFiles
from dataset_tools.format.reader import DatasetIndex, downsample_labels, read_frame, rig_of_frame
from geometry.bev import BevGrid

from .augment import ColorJitter, random_transform, warp_image
from .feature_targets import camera_targets, train_lut
from .rectified import model_view


class DataError(InputError):
    pass


def label_factor(label_grid: BevGrid, model_grid: BevGrid, source: str = "data set") -> int:
    same = all(abs(getattr(label_grid, k) - getattr(model_grid, k)) < 1e-9 for k in ("x_min", "x_max", "y_min", "y_max"))
    f = model_grid.res / label_grid.res
    if not same or abs(f - round(f)) > 1e-9 or round(f) < 1:
        raise DataError(f"{source}: grid: labels {label_grid} cannot be pooled to the model grid {model_grid}")
    return int(round(f))


class BevDataset(Dataset):
    """The samples of a split. `frames`: {position in the split: a frame as read_frame gives it (plus
    `camera_targets`)} held in memory (a split read from shards, model.shards), else each frame is
    read from the data set folder. `make_sample` turns a read frame into a sample, for a stream too.
    `device_images`: samples carry their images as uint8 and their colour jitter as draws, for
    `finish` on the training step's device (a quarter of the bytes through the loader, and the
    jitter off its workers)."""

    def __init__(self, index: DatasetIndex | str, split: str, cfg: dict, train: bool = False, frames: dict | None = None,
                 device_images: bool = False):
        self.device_images = device_images
        self.index = index if isinstance(index, DatasetIndex) else DatasetIndex(index)
        self.refs = self.index.frames(split)
        self.frames = frames
        view = model_view(self.index.rig, cfg)
        self.rectifier = view.rectifier  # None: the model sees the fisheye images
        self.rig = view.rig
        self.names = self.rig.names
        self.class_names = self.index.class_names
        # thin classes win a block when labels are pooled to the model grid (by name: the class map is configurable)
        self.priority = tuple(self.class_names.index(n) for n in ("lane_marking", "vehicle") if n in self.class_names)
        self.cfg = cfg
        self.frustum = view.frustum
        self.input_size, self.grid = self.frustum.input_size, self.frustum.grid
        self.factor = label_factor(self.index.grid, self.grid, str(self.index.root / INDEX))
        self.seed = cfg["train"]["seed"]
        a = cfg["augment"]
        self.augment = a if (train and a["enabled"]) else None
        self.jitter = ColorJitter(**a["color_jitter"]) if self.augment else None
        self.epoch = 0
        self.carry_geometry = any(r.own_rig for r in self.refs)
        # camera-view targets (depth bins, classes) only when a loss uses them, and only for training
        loss = cfg["loss"]
        self.camera_targets = train and (loss["depth_weight"] > 0 or loss["camera_seg_weight"] > 0)
        self.lut = train_lut(self.class_names)
        self.cache: dict[int, dict] = {}  # decoded frames, up to data.cache_mb (each loader process its own)
        self.cache_budget = int(cfg["data"].get("cache_mb", 0)) * 2**20

    def geometry_of(self, ref, meta: dict):
        """(lift geometry, rectifier or None) of the frame's rig: the nominal ones unless the
        frame has its own (jittered) rig, whose fisheye images are then rectified with their own maps."""
        if not ref.own_rig:
            return self.frustum, self.rectifier
        fisheye = rig_of_frame(ref, meta, self.index.rig)
        if fisheye.names != self.names:
            raise DataError(f"{FrameFiles(ref.dir).meta}: rig cameras {fisheye.names}, the index has {self.names}")
        view = model_view(fisheye, self.cfg)  # cached by calibration
        return view.frustum, view.rectifier

    def targets_of(self, ref, frustum, transforms, rectify, passes=None) -> tuple[torch.Tensor, torch.Tensor]:
        """(depth bin (N, h, w), training class (N, h, w)) of what each feature pixel's ray hits
        (`passes`: the frame's camera targets when already read, from a shard)."""
        passes = read_camera_passes(ref.dir, self.names) if passes is None else passes
        for n, (dist, _) in passes.items():
            src = self.index.rig[n].camera
            if dist.shape != (src.height, src.width):
                raise DataError(f"{FrameFiles(ref.dir).camera_exr(n)}: size {dist.shape[1]}x{dist.shape[0]}, rig says {src.width}x{src.height}")
        depth, semantic = camera_targets(frustum, transforms, passes, self.lut, rectify)
        return torch.from_numpy(depth), torch.from_numpy(semantic)

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def __len__(self):
        return len(self.refs)

    def __getitem__(self, key) -> dict:
        """Sample `key`: its place in the split, augmented as in epoch `set_epoch`, or (epoch, place)
        (a loader that spans epochs: model.training.RunBatches)."""
        epoch, i = key if isinstance(key, tuple) else (self.epoch, key)
        ref = self.refs[i]
        return self.make_sample(ref, self.frames[i] if self.frames is not None else self.read(i), i, epoch)

    def read(self, i: int) -> dict:
        """Frame i of the split from the data set folder, decoded and its labels pooled to the model
        grid; kept while the cache's budget lasts (the same sample either way)."""
        if i in self.cache:
            return self.cache[i]
        f = read_frame(self.refs[i], cameras=self.names, num_classes=len(self.class_names), instance=False)
        f["semantic"], f["visibility"] = self.pooled_labels(self.refs[i], f)
        f["pooled"] = True
        size = sum(a.nbytes for a in (*f["images"].values(), f["semantic"], f["visibility"]))
        if size <= self.cache_budget:
            self.cache[i] = f
            self.cache_budget -= size
        return f

    def pooled_labels(self, ref, f: dict) -> tuple[np.ndarray, np.ndarray]:
        """The frame's (semantic, visibility) labels on the model grid."""
        if f.get("pooled"):
            return f["semantic"], f["visibility"]
        sem, vis = f["semantic"], f["visibility"]
        if self.factor > 1:
            sem, vis = downsample_labels(sem, vis, self.factor, priority=self.priority, num_classes=len(self.class_names))
        if sem.shape != self.grid.shape:
            raise DataError(f"{FrameFiles(ref.dir).semantic}: {sem.shape} after pooling, model grid is {self.grid.shape}")
        return sem, vis

    def make_sample(self, ref, f: dict, i: int, epoch: int | None = None) -> dict:
        """The sample of frame `f` (read_frame's dict), the `i`-th of the split, in `epoch` (default
        set_epoch's): (seed, epoch, i) seeds its augmentation."""
        epoch = self.epoch if epoch is None else int(epoch)
        rng = np.random.default_rng([self.seed, epoch, i])  # independent streams: no collisions
        seed = int(rng.integers(2**63))  # the colour jitter's torch seed
        sample = {}
        frustum, rectify = self.geometry_of(ref, f["meta"])
        mirrored, yaw = False, None  # yaw: the turn of the world, radians (augment.bev_rotation_deg > 0)
        if self.augment:
            a = self.augment
            transforms = [random_transform(rc.camera, self.input_size, rng, a["scale"], a["rotation_deg"], a["crop"]) for rc in frustum.rig]
            mirrored = a["mirror"] > 0 and bool(rng.random() < a["mirror"])  # drawn after the others: they stay as without it
            turn = a["bev_rotation_deg"]
            yaw = math.radians(rng.uniform(-turn, turn)) if turn > 0 else None  # drawn last, likewise
            sample["point_cell"], intrinsics = frustum.geometry(transforms, mirrored, intrinsics=frustum.reads_intrinsics, yaw=yaw or 0.0)
            if intrinsics is not None:  # else the model's pooling never reads them
                sample["intrinsics"] = intrinsics
            if frustum.ground:
                sample["ground_grid"] = frustum.ground_grid(transforms, yaw or 0.0)
        else:
            transforms = frustum.nominal_transforms()
            if self.carry_geometry:
                sample["point_cell"], sample["intrinsics"] = frustum.nominal
                if frustum.ground:
                    sample["ground_grid"] = frustum.nominal_ground
        imgs = []
        for rc, t in zip(frustum.rig, transforms):
            img, src = f["images"][rc.name], self.index.rig[rc.name].camera
            if img.shape[:2] != (src.height, src.width):
                raise DataError(f"{FrameFiles(ref.dir).camera_png(rc.name)}: size {img.shape[1]}x{img.shape[0]}, rig says {src.width}x{src.height}")
            if rectify:
                img = rectify(rc.name, img)
            img = warp_image(img, rc.camera, t)
            imgs.append(img[:, ::-1] if mirrored else img)
        images = torch.from_numpy(np.stack(imgs)).permute(0, 3, 1, 2)
        if self.device_images:
            if self.jitter is not None:
                sample["jitter_factors"], sample["jitter_order"] = self.jitter.draw(len(imgs), seed)
        else:
            images = images.float() / 255.0
            if self.jitter is not None:
                with torch.random.fork_rng(devices=[]):
                    torch.manual_seed(seed)
                    images = self.jitter(images)
        if self.camera_targets:
            depth, semantic = self.targets_of(ref, frustum, transforms, rectify, f.get("camera_targets"))
            sample["depth_target"], sample["camera_semantic"] = (depth.flip(-1), semantic.flip(-1)) if mirrored else (depth, semantic)
        sem, vis = self.pooled_labels(ref, f)
        known = None
        if yaw is not None:  # every such sample carries the mask, a zero turn too: batches stack
            sem, vis, known = self.grid.turned(yaw, sem, vis, np.ones(sem.shape, dtype=np.float32))
        if mirrored:  # the grid's columns run along y: y -> -y
            sem, vis = sem[:, ::-1], vis[:, ::-1]
            known = None if known is None else known[:, ::-1].copy()
        if known is not None:
            sample["bev_known"] = torch.from_numpy(known)
        return {
            **sample,
            "images": images.contiguous(),  # NCHW (the jitter returns NHWC): a loader in this process (data.num_workers 0) hands the trunk what a worker does
            "semantic": torch.from_numpy(sem.astype(np.int64)),
            "visibility": torch.from_numpy(np.array(vis, dtype=np.float32)),  # a copy: `vis` may be the cache's
            "index": i,
        }

    def finish(self, batch: dict) -> dict:
        """A batch of `device_images` samples (on its device) as `make_sample` makes them without:
        images as float in [0, 1], jittered with their draws."""
        if batch["images"].dtype != torch.uint8:
            return batch
        batch = dict(batch)
        images = batch["images"].float() / 255.0
        if "jitter_factors" in batch:
            images = self.jitter.apply(images, batch.pop("jitter_factors"), batch.pop("jitter_order"))
        batch["images"] = images
        return batch


class DataWorker(LoaderWorker):
    """A DataLoader worker (common.lifetime.LoaderWorker) whose OpenCV keeps to one thread, as torch
    does in a worker: the workers are the parallelism. OpenCV's own pool in each of 12 workers on 16
    cores held the paper configuration's loader at 55 samples/s instead of 67 (H200, 2026-11-27)."""

    def __call__(self, *args) -> None:
        super().__call__(*args)
        import cv2

        cv2.setNumThreads(1)
