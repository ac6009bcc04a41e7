"""Pooling the per-camera BEV features into one grid (the paper's section III-B).

All take per-camera features `feats` (B, N, X, Y, C) channels last (what the splat gives) plus
the per-camera coverage `cover` (B, N, X, Y): 1 where a camera's lifted points reach the cell,
and return (B, C, X, Y).

- sum, max: symmetric.
- weighted_sum (eq. 2): sum_i W_i * F_i with a learnable W_i in R^{C x X x Y} per camera (init 1).
- sensors_per_cell (eq. 3): a learnable w_{i,xy} per camera and cell, initialised to 1/N_xy, with
  N_xy the number of rig cameras that see the cell (from the rig's nominal geometry).
- intrinsics_embedding (eq. 4): F = sum_k I_k (F_k - mu_k) + E_k. How we read it: I_k (3x3) cannot
  multiply a C x X x Y map as written, so I_k enters through a learned linear map of the camera's
  intrinsics descriptor (`lift.intrinsics_descriptor`: normalised fx, fy, cx, cy and the angle of
  eight image radii, which covers any camera model) to one scale per channel, initialised to 1;
  mu_k is the per-channel mean of F_k over the cells camera k covers, subtracted there only (cells a
  camera does not see stay 0); E_k in R^{C x X x Y} is a learnable per-camera embedding (init 0)
  added where camera k covers the cell.
"""

from __future__ import annotations

import torch
from torch import nn

from .frustum import INTRINSICS_DIM

POOLINGS = ("sum", "max", "weighted_sum", "sensors_per_cell", "intrinsics_embedding")


class SumPool(nn.Module):
    def forward(self, feats, cover=None, intrinsics=None):
        return (feats if feats.ndim == 4 else feats.sum(1)).permute(0, 3, 1, 2)


class MaxPool(nn.Module):
    def forward(self, feats, cover=None, intrinsics=None):
        return feats.amax(1).permute(0, 3, 1, 2)


class WeightedSumPool(nn.Module):
    def __init__(self, cameras: int, channels: int, shape):
        super().__init__()
        self.weight = nn.Parameter(torch.ones(cameras, channels, *shape))  # W_i in R^{C x X x Y}

    def forward(self, feats, cover=None, intrinsics=None):
        return torch.einsum("bnxyc,ncxy->bcxy", feats, self.weight)


class SensorsPerCellPool(nn.Module):
    def __init__(self, nominal_cover: torch.Tensor):
        super().__init__()
        cover = (nominal_cover > 0).float()  # (N, X, Y)
        n = cover.sum(0, keepdim=True).clamp(min=1)
        self.weight = nn.Parameter(cover / n)  # w_ij = 1 / N_ij

    def forward(self, feats, cover=None, intrinsics=None):
        return torch.einsum("bnxyc,nxy->bcxy", feats, self.weight)


class IntrinsicsEmbeddingPool(nn.Module):
    def __init__(self, cameras: int, channels: int, shape):
        super().__init__()
        self.scale = nn.Linear(INTRINSICS_DIM, channels)
        nn.init.zeros_(self.scale.weight)
        nn.init.ones_(self.scale.bias)
        self.embedding = nn.Parameter(torch.zeros(cameras, channels, *shape))  # E_k

    def forward(self, feats, cover, intrinsics):
        if intrinsics is None or cover is None:
            raise ValueError("intrinsics_embedding pooling needs the cameras' coverage and intrinsics")
        m = (cover > 0).to(feats.dtype)[..., None]  # (B, N, X, Y, 1)
        mu = (feats * m).sum((2, 3), keepdim=True) / m.sum((2, 3), keepdim=True).clamp(min=1)
        scale = self.scale(intrinsics)[:, :, None, None, :]  # (B, N, 1, 1, C)
        emb = self.embedding.permute(0, 2, 3, 1)[None]  # (1, N, X, Y, C)
        return ((scale * (feats - mu) + emb) * m).sum(1).permute(0, 3, 1, 2)


def make_pooling(kind: str, cameras: int, channels: int, shape, nominal_cover: torch.Tensor) -> nn.Module:
    if kind == "sum":
        return SumPool()
    if kind == "max":
        return MaxPool()
    if kind == "weighted_sum":
        return WeightedSumPool(cameras, channels, shape)
    if kind == "sensors_per_cell":
        return SensorsPerCellPool(nominal_cover)
    if kind == "intrinsics_embedding":
        return IntrinsicsEmbeddingPool(cameras, channels, shape)
    raise ValueError(f"pooling must be one of {', '.join(POOLINGS)}, got {kind!r}")
