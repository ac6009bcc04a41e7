"""BEV encoder (LSS's BevEncode, CPU-sized): downsample twice, fuse back, upsample to the grid."""

from __future__ import annotations

from torch import nn

from .layers import Up, conv_norm_act, separable_norm_act, stage


class BevEncoder(nn.Module):
    """`separable`: the two decoder stages at 1/2 and full resolution, 80 % of the encoder's work
    with 3x3 convolutions, use depthwise-separable ones instead (model.bev_encoder.separable)."""

    def __init__(self, cin: int, widths=(32, 64, 128), blocks=(1, 1), norm: str = "group", dropout: float = 0.0,
                 separable: bool = False):
        super().__init__()
        if len(widths) != 3 or len(blocks) != 2:
            raise ValueError("bev encoder: widths needs 3 entries and blocks 2")
        w1, w2, w3 = widths
        self.stem = conv_norm_act(cin, w1, norm, 4, 2)  # /2
        self.layer1 = stage(w1, w2, blocks[0], norm, True)  # /4
        self.layer2 = stage(w2, w3, blocks[1], norm, True)  # /8
        self.up1 = Up(w3 + w1, w2, norm, separable=separable)  # back to /2
        self.dropout = nn.Dropout2d(dropout) if dropout > 0 else nn.Identity()
        last = separable_norm_act if separable else conv_norm_act
        self.up2 = nn.Sequential(nn.Upsample(scale_factor=2, mode="bilinear", align_corners=False), last(w2, w1, norm))
        self.out_channels = w1

    def forward(self, x):
        h, w = x.shape[-2:]
        s = self.stem(x)
        y = self.up1(self.layer2(self.layer1(s)), s)
        y = self.up2(self.dropout(y))
        return y[..., :h, :w]
