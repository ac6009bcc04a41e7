"""Image encoder: a compact ResNet-style trunk trained from scratch, and LSS's depth/context head.

The trunk halves the resolution `len(widths)` times (stem + stages); the stride-`stride` map and
the deepest map are fused LSS-style (upsample, concatenate, convolve), then one 1x1 convolution
gives D depth logits and C context channels per feature pixel.
"""

from __future__ import annotations

import math

from torch import nn

from .layers import Up, conv_norm_act, stage

IMAGE_MEAN, IMAGE_STD = 0.45, 0.225


class ImageEncoder(nn.Module):
    def __init__(self, widths=(16, 32, 64, 128), blocks=(1, 1, 1), stride: int = 8, depth_bins: int = 32,
                 context_channels: int = 32, norm: str = "group", dropout: float = 0.0):
        super().__init__()
        if len(blocks) != len(widths) - 1:
            raise ValueError(f"encoder: blocks needs {len(widths) - 1} entries (one per stage after the stem), got {len(blocks)}")
        levels = int(round(math.log2(stride)))
        if 2**levels != stride or not 1 <= levels <= len(widths):
            raise ValueError(f"encoder: stride {stride} must be a power of 2 reached by the trunk (at most {2 ** len(widths)})")
        self.stride, self.total_stride = stride, 2 ** len(widths)
        self.depth_bins, self.context_channels = depth_bins, context_channels
        self.stem = conv_norm_act(3, widths[0], norm, 4, 2)
        self.stages = nn.ModuleList(stage(widths[i], widths[i + 1], blocks[i], norm, True) for i in range(len(blocks)))
        self.skip_level = levels - 1  # index into [stem, *stages] outputs of the stride map
        up_in = widths[self.skip_level] + widths[-1]
        self.fuse = Up(up_in, widths[-1], norm) if self.skip_level != len(widths) - 1 else None
        self.dropout = nn.Dropout2d(dropout) if dropout > 0 else nn.Identity()
        self.head = nn.Conv2d(widths[-1], depth_bins + context_channels, 1)

    def normalise(self, images):
        """(B, 3, H, W) in [0, 1] -> the trunk's input scale."""
        return (images - IMAGE_MEAN) / IMAGE_STD

    def forward(self, images):
        """images (B, 3, H, W), H and W multiples of total_stride -> depth logits (B, D, H/s, W/s),
        context (B, C, H/s, W/s)."""
        if images.shape[-1] % self.total_stride or images.shape[-2] % self.total_stride:
            raise ValueError(f"encoder: image size {tuple(images.shape[-2:])} must be a multiple of {self.total_stride}")
        feats = [self.stem(images)]
        for s in self.stages:
            feats.append(s(feats[-1]))
        x = feats[-1] if self.fuse is None else self.fuse(feats[-1], feats[self.skip_level])
        x = self.head(self.dropout(x))
        return x[:, : self.depth_bins], x[:, self.depth_bins :]
