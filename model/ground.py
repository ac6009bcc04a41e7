"""The ground image: each camera's input image sampled where every BEV cell's ground point projects.

Lane paint, kerbs and the road's edge lie on the ground, so for them the lift's depth guess is not
needed: a cell's ground point (ego z = 0) has one position in each camera that sees it
(`model.frustum.Frustum.ground_grid`, from geometry's camera models), and the input image read there
is the road seen from above at the grid's full resolution (Inverse Perspective Mapping, the
surround-view parking systems' picture). The lift's features come from stride-8 feature pixels, a
metre or more of road apart beyond 10 m; the ground image keeps the input image's own detail.

`GroundImage` turns the sampled colours (each camera's RGB, normalised as the trunk's input, and
whether it sees the cell) into `channels` features with one 3x3 convolution, and adds a 1x1 map of
them to the pooled BEV features (what the BEV encoder reads) and to the BEV encoder's output (what
the heads read, at full resolution). Both maps start at zero, so an untrained ground image changes
nothing; it is built after every other layer, so they draw the same initial weights with or without it.
What stands above the ground (vehicles) lands smeared along the camera's rays, as in any inverse
perspective map; the BEV encoder sees the lift's features beside it.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from .layers import conv_norm_act


def sample_ground(images: torch.Tensor, grid: torch.Tensor) -> torch.Tensor:
    """images (B, N, C, H, W), grid (B, N, X, Y, 2) (Frustum.ground_grid) -> (B, N (C + 1), X, Y):
    each camera's C channels at each cell's ground point, then 1 where the camera sees it, 0 elsewhere
    (and its channels 0)."""
    b, n, c = images.shape[:3]
    x, y = grid.shape[2:4]
    seen = (grid.abs() <= 1).all(-1).to(images.dtype)  # (B, N, X, Y)
    v = F.grid_sample(images.flatten(0, 1), grid.flatten(0, 1).to(images.dtype), mode="bilinear",
                      padding_mode="zeros", align_corners=False).view(b, n, c, x, y)
    return torch.cat([v * seen[:, :, None], seen[:, :, None]], 2).flatten(1, 2)


def ground_colours(images: torch.Tensor, grid: torch.Tensor) -> torch.Tensor:
    """images (N, 3, H, W), grid (N, X, Y, 2) of one sample -> (3, X, Y): each cell's colour averaged
    over the cameras that see its ground point, 0 where none does (the ground image as a picture)."""
    got = sample_ground(images[None], grid[None])[0].view(images.shape[0], images.shape[1] + 1, *grid.shape[1:3])
    seen = got[:, -1:]
    return (got[:, :-1] * seen).sum(0) / seen.sum(0).clamp(min=1)


class GroundImage(nn.Module):
    def __init__(self, cameras: int, channels: int, bev_channels: int, head_channels: int, norm: str, colours: int = 3):
        super().__init__()
        self.local = conv_norm_act(cameras * (colours + 1), channels, norm)
        self.to_bev = nn.Conv2d(channels, bev_channels, 1)
        self.to_head = nn.Conv2d(channels, head_channels, 1)
        for m in (self.to_bev, self.to_head):
            nn.init.zeros_(m.weight)
            nn.init.zeros_(m.bias)

    def forward(self, sampled: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """sampled (B, N (C + 1), X, Y) (`sample_ground`) -> (what to add to the pooled features, to the heads' input)."""
        g = self.local(sampled)
        return self.to_bev(g), self.to_head(g)
