"""LSS-fisheye: image encoder -> lift (ray-distance bins x context) -> splat per camera ->
camera pooling -> BEV encoder -> semantic and occlusion heads."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from dataset_tools.labels.classes import TRAIN_CLASSES

from .bev_encoder import BevEncoder
from .cpu import resolve_precision
from .encoder import ImageEncoder
from .frustum import Frustum
from .ground import GroundImage, sample_ground
from .pooling import make_pooling
from .splat import splat, splat_count, splat_index

NUM_CLASSES = len(TRAIN_CLASSES)  # the default class list: invalid (never predicted) and the K-1 the semantic head scores


def make_encoder(mcfg: dict) -> nn.Module:
    """The image encoder of `model.trunk`: the from-scratch trunk or the pretrained EfficientNet-Lite0."""
    d, c = mcfg["depth"], mcfg["context_channels"]
    if mcfg["trunk"] == "efficientnet_lite0":
        from .efficientnet import EfficientNetLite0Encoder

        return EfficientNetLite0Encoder(mcfg["stride"], d["bins"], c, mcfg["encoder"]["widths"][-1], mcfg["norm"], mcfg["dropout"],
                                        frozen=mcfg["trunk_frozen"],
                                        depthwise_frozen=mcfg["trunk_depthwise_frozen"])
    return ImageEncoder(mcfg["encoder"]["widths"], mcfg["encoder"]["blocks"], mcfg["stride"], d["bins"], c, mcfg["norm"], mcfg["dropout"])


class LSSFisheye(nn.Module):
    def __init__(self, mcfg: dict, frustum: Frustum, num_classes: int = NUM_CLASSES, camera_head: bool = False):
        """mcfg: the config's `model` section; frustum: the lift geometry of the config and rig;
        camera_head: add the camera-view semantic head (loss.camera_seg_weight > 0), run in training only."""
        super().__init__()
        self.frustum = frustum
        self.grid, self.input_size, self.camera_names = frustum.grid, frustum.input_size, frustum.rig.names
        self.stride = mcfg["stride"]
        c = mcfg["context_channels"]
        self.encoder = make_encoder(mcfg)
        pc, intr = frustum.nominal  # the cameras without augmentation
        self.register_buffer("nominal_point_cell", pc, persistent=False)
        self.register_buffer("nominal_intrinsics", intr, persistent=False)
        self.pooling_kind = mcfg["pooling"]
        grid = self.grid
        cover = splat_count(splat_index(pc[None], grid.rows * grid.cols)).view(len(pc), *grid.shape)
        self.pool = make_pooling(self.pooling_kind, len(pc), c, grid.shape, cover)
        b = mcfg["bev_encoder"]
        self.bev = BevEncoder(c, b["widths"], b["blocks"], mcfg["norm"], mcfg["dropout"], b["separable"])
        self.semantic_head = nn.Conv2d(self.bev.out_channels, num_classes - 1, 1)  # classes 1..K-1; 0 is invalid
        self.occlusion_head = nn.Conv2d(self.bev.out_channels, 1, 1)  # logit of visibility p(o)
        self._index_cache = None
        self.bf16 = resolve_precision(mcfg["precision"], torch.device("cpu")) == "bf16"  # train.py resolves auto per device
        # built last, so the other layers draw the same initial weights with or without it
        self.camera_head = nn.Conv2d(c, num_classes - 1, 1) if camera_head else None
        self.ground = None  # the ground image (model.ground_channels): after every other layer, likewise
        if mcfg["ground_channels"] > 0:
            self.ground = GroundImage(len(pc), mcfg["ground_channels"], c, self.bev.out_channels, mcfg["norm"])
            self.register_buffer("nominal_ground", frustum.nominal_ground, persistent=False)

    def _index(self, point_cell, batch: int):
        """The splat index of this batch's cameras; for the nominal cameras it is built once per
        batch size and device, and reused (training without augmentation, validation, eval)."""
        cells = self.grid.rows * self.grid.cols
        summed = self.pooling_kind == "sum"
        if point_cell is not None:
            return splat_index(point_cell, cells, summed)
        key = (batch, self.nominal_point_cell.device)
        if self._index_cache is None or self._index_cache[0] != key:
            pc = self.nominal_point_cell[None].expand(batch, *self.nominal_point_cell.shape)
            self._index_cache = (key, splat_index(pc.contiguous(), cells, summed))
        return self._index_cache[1]

    def _autocast(self, x):
        """bfloat16 autocast on x's device where model.precision is bf16, else nothing."""
        return torch.autocast(x.device.type, dtype=torch.bfloat16, enabled=self.bf16)

    def bev_outputs(self, feats, index, b: int, n: int, intrinsics=None, ground=None) -> dict:
        """The splat's output (features per cell, or per camera and cell) -> {'semantic',
        'occlusion'}: camera pooling, the BEV encoder and the heads; `ground`: the ground image's
        samples (`ground_samples`) where the model has one."""
        x_, y_ = self.grid.shape
        if self.pooling_kind == "sum":
            pooled = self.pool(feats.view(b, x_, y_, -1))
        else:
            cover = splat_count(index).view(b, n, x_, y_) if self.pooling_kind == "intrinsics_embedding" else None
            if intrinsics is None:
                intrinsics = self.nominal_intrinsics[None].expand(b, -1, -1)
            pooled = self.pool(feats.view(b, n, x_, y_, -1), cover, intrinsics)
        with self._autocast(pooled):
            if self.ground is None:
                y = self.bev(pooled)
            else:
                to_bev, to_head = self.ground(ground)
                y = self.bev(pooled + to_bev) + to_head
            return {"semantic": self.semantic_head(y).float(), "occlusion": self.occlusion_head(y)[:, 0].float()}

    def ground_samples(self, images, ground_grid=None):
        """images (B, N, 3, H, W) in [0, 1] -> the ground image's samples (B, 4 N, X, Y), at the
        nominal cameras' ground points unless `ground_grid` (B, N, X, Y, 2) gives the batch's; None
        without a ground image."""
        if self.ground is None:
            return None
        if ground_grid is None:
            ground_grid = self.nominal_ground[None].expand(images.shape[0], *self.nominal_ground.shape)
        x = self.encoder.normalise(images.flatten(0, 1)).reshape(images.shape)
        return sample_ground(x, ground_grid)

    def lift(self, images):
        """images (B, N, 3, H, W) in [0, 1] -> depth probabilities (B, N, D, h, w), context (B, N, C, h, w)."""
        depth_logits, ctx = self.lift_logits(images)
        return depth_logits.softmax(2), ctx

    def lift_logits(self, images):
        """images (B, N, 3, H, W) in [0, 1] -> depth logits (B, N, D, h, w), context (B, N, C, h, w)."""
        b, n, _, h, w = images.shape
        x = self.encoder.normalise(images.flatten(0, 1))
        ts = self.encoder.total_stride
        x = F.pad(x, (0, -w % ts, 0, -h % ts))  # right/bottom padding keeps the principal point
        with self._autocast(x):
            depth_logits, ctx = self.encoder(x)
        depth_logits, ctx = depth_logits.float(), ctx.float()  # the lift and the splat sum in float32
        hs, ws = -(-h // self.stride), -(-w // self.stride)
        depth_logits = depth_logits[..., :hs, :ws]
        ctx = ctx[..., :hs, :ws]
        return depth_logits.reshape(b, n, *depth_logits.shape[1:]), ctx.reshape(b, n, *ctx.shape[1:])

    def forward(self, images, point_cell=None, intrinsics=None, ground_grid=None):
        """images (B, N, 3, H, W) in [0, 1] at the input size; point_cell (B, N, D, h, w),
        intrinsics (B, N, 12) and ground_grid (B, N, X, Y, 2) for augmented cameras (default: the
        rig's nominal ones, index cached).
        -> {'semantic': (B, K-1, X, Y) logits, 'occlusion': (B, X, Y) visibility logits}; in training
        also 'depth_logits' (B, N, D, h, w) and, with the camera head, 'camera_semantic' (B, N, K-1, h, w)."""
        if images.ndim != 5 or images.shape[1] != len(self.camera_names) or tuple(images.shape[-1:-3:-1]) != self.input_size:
            raise ValueError(f"model: images must be (B, {len(self.camera_names)}, 3, {self.input_size[1]}, {self.input_size[0]}), got {tuple(images.shape)}")
        b, n = images.shape[:2]
        depth_logits, ctx = self.lift_logits(images)
        depth = depth_logits.softmax(2)
        if point_cell is not None and point_cell.shape[2:] != depth.shape[2:]:
            raise ValueError(f"model: point_cell {tuple(point_cell.shape)} does not match the features {tuple(depth.shape)}")
        index = self._index(point_cell, b)
        out = self.bev_outputs(splat(depth, ctx, index), index, b, n, intrinsics, self.ground_samples(images, ground_grid))
        return self.training_outputs(out, depth_logits, ctx) if self.training else out

    def training_outputs(self, out: dict, depth_logits, ctx) -> dict:
        """out with what the training losses add: 'depth_logits' and, with the camera head, 'camera_semantic'."""
        out["depth_logits"] = depth_logits
        if self.camera_head is not None:
            out["camera_semantic"] = self.camera_head(ctx.flatten(0, 1)).view(*ctx.shape[:2], -1, *ctx.shape[-2:])
        return out
