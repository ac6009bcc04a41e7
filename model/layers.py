"""Small building blocks shared by the image and BEV encoders.

Downsampling uses 4x4 stride-2 convolutions (padding 1) and 2x2 average pooling: output pixel j
then sits at input position 2 j + 0.5, so after k halvings a feature pixel is centred exactly on
image pixel s j + (s - 1) / 2 with s = 2^k, the convention the lift assumes. (A 3x3 stride-2
convolution would centre it on s j, half a stride off.)
"""

from __future__ import annotations

import torch
from torch import nn


def norm_layer(kind: str, channels: int) -> nn.Module:
    # GroupNorm by default: batch-independent, so small CPU batches and DDP shards behave the same
    if kind == "group":
        groups = max(1, min(8, channels // 4))
        while channels % groups:
            groups -= 1
        return nn.GroupNorm(groups, channels)
    if kind == "batch":
        return nn.BatchNorm2d(channels)
    raise ValueError(f"norm must be 'group' or 'batch', got {kind!r}")


def conv_norm_act(cin: int, cout: int, norm: str, k: int = 3, stride: int = 1) -> nn.Sequential:
    pad = 1 if (k == 4 and stride == 2) else k // 2
    return nn.Sequential(nn.Conv2d(cin, cout, k, stride, pad, bias=False), norm_layer(norm, cout), nn.ReLU(inplace=True))


def separable_norm_act(cin: int, cout: int, norm: str) -> nn.Sequential:
    """A 3x3 convolution split into a depthwise 3x3 and a pointwise 1x1 (MobileNet's): about
    1/9 + 1/cout of the work of `conv_norm_act`'s."""
    return nn.Sequential(nn.Conv2d(cin, cin, 3, 1, 1, groups=cin, bias=False), nn.Conv2d(cin, cout, 1, bias=False),
                         norm_layer(norm, cout), nn.ReLU(inplace=True))


class BasicBlock(nn.Module):
    """ResNet basic block; with down=True it halves the resolution (4x4/2 conv; avg-pool shortcut)."""

    def __init__(self, cin: int, cout: int, norm: str, down: bool = False):
        super().__init__()
        self.conv1 = conv_norm_act(cin, cout, norm, 4 if down else 3, 2 if down else 1)
        self.conv2 = nn.Conv2d(cout, cout, 3, 1, 1, bias=False)
        self.norm2 = norm_layer(norm, cout)
        short = []
        if down:
            short.append(nn.AvgPool2d(2))
        if down or cin != cout:
            short += [nn.Conv2d(cin, cout, 1, bias=False), norm_layer(norm, cout)]
        self.short = nn.Sequential(*short)

    def forward(self, x):
        return torch.relu(self.norm2(self.conv2(self.conv1(x))) + self.short(x))


def stage(cin: int, cout: int, blocks: int, norm: str, down: bool) -> nn.Sequential:
    return nn.Sequential(BasicBlock(cin, cout, norm, down), *[BasicBlock(cout, cout, norm) for _ in range(blocks - 1)])


class Up(nn.Module):
    """LSS's Up: upsample the coarse map, concatenate the skip, two convolutions."""

    def __init__(self, cin: int, cout: int, norm: str, scale: int = 2, separable: bool = False):
        super().__init__()
        self.scale = scale
        conv = separable_norm_act if separable else conv_norm_act
        self.conv = nn.Sequential(conv(cin, cout, norm), conv(cout, cout, norm))

    def forward(self, x, skip):
        x = nn.functional.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
        return self.conv(torch.cat([skip, x], 1))
