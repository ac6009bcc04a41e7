"""The BEV grid: ego-frame metres <-> cells, in the orientation of docs/geometry.md.

In a BEV image up is +x (forward) and left is +y (left):
row i has x = x_max - (i + 0.5) res, column j has y = y_max - (j + 0.5) res.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch


@dataclass(frozen=True)
class BevGrid:
    x_min: float = -25.0
    x_max: float = 25.0
    y_min: float = -25.0
    y_max: float = 25.0
    res: float = 0.125

    def __post_init__(self):
        if self.res <= 0 or self.x_max <= self.x_min or self.y_max <= self.y_min:
            raise ValueError(f"BEV grid: empty or negative extent {self}")
        for n, span in (("x", self.x_max - self.x_min), ("y", self.y_max - self.y_min)):
            cells = span / self.res
            if abs(cells - round(cells)) > 1e-6:
                raise ValueError(f"BEV grid: {n} extent {span} m is not a whole number of {self.res} m cells")

    @classmethod
    def from_dict(cls, d: dict) -> "BevGrid":
        """{'bound': 25, 'res': 0.25} or explicit x_min/x_max/y_min/y_max/res."""
        d = dict(d)
        if "bound" in d:
            b = float(d.pop("bound"))
            d.update(x_min=-b, x_max=b, y_min=-b, y_max=b)
        unknown = set(d) - {"x_min", "x_max", "y_min", "y_max", "res"}
        if unknown:
            raise ValueError(f"BEV grid: unknown key '{sorted(unknown)[0]}'")
        return cls(**{k: float(v) for k, v in d.items()})

    def to_dict(self) -> dict:
        return {"x_min": self.x_min, "x_max": self.x_max, "y_min": self.y_min, "y_max": self.y_max, "res": self.res}

    @property
    def rows(self) -> int:  # along x
        return int(round((self.x_max - self.x_min) / self.res))

    @property
    def cols(self) -> int:  # along y
        return int(round((self.y_max - self.y_min) / self.res))

    @property
    def shape(self) -> tuple[int, int]:
        return self.rows, self.cols

    def with_res(self, res: float) -> "BevGrid":
        return BevGrid(self.x_min, self.x_max, self.y_min, self.y_max, res)

    def cell_centres(self):
        """(rows, cols, 2) numpy: the ego (x, y) of each cell centre."""
        x = self.x_max - (np.arange(self.rows) + 0.5) * self.res
        y = self.y_max - (np.arange(self.cols) + 0.5) * self.res
        xx, yy = np.meshgrid(x, y, indexing="ij")
        return np.stack([xx, yy], -1)

    def turned(self, yaw: float, *grids: np.ndarray, fill=0) -> tuple[np.ndarray, ...]:
        """Grids (rows, cols, ...) of the world turned by `yaw` radians about the ego z axis (to the
        left; Rig.turned moves the cameras alike): the cell at p takes the value of the cell holding
        rot_z(-yaw) p (nearest), `fill` where that lies outside the grid."""
        c, s = math.cos(yaw), math.sin(yaw)
        p = self.cell_centres()
        row, col, inside = self.cell_of(np.stack([c * p[..., 0] + s * p[..., 1], -s * p[..., 0] + c * p[..., 1]], -1))
        row, col = np.clip(row, 0, self.rows - 1), np.clip(col, 0, self.cols - 1)
        out = []
        for g in grids:
            if g.shape[:2] != self.shape:
                raise ValueError(f"BEV grid: a grid of shape {g.shape[:2]} is not this grid's {self.shape}")
            keep = inside.reshape(inside.shape + (1,) * (g.ndim - 2))
            out.append(np.where(keep, g[row, col], np.asarray(fill, dtype=g.dtype)))
        return tuple(out)

    def cell_of(self, xy):
        """Ego (x, y) (..., >=2) -> (row, col, inside): integer cells, numpy or torch."""
        if isinstance(xy, torch.Tensor):
            row = torch.floor((self.x_max - xy[..., 0]) / self.res).long()
            col = torch.floor((self.y_max - xy[..., 1]) / self.res).long()
        else:
            xy = np.asarray(xy)
            row = np.floor((self.x_max - xy[..., 0]) / self.res).astype(np.int64)
            col = np.floor((self.y_max - xy[..., 1]) / self.res).astype(np.int64)
        inside = (row >= 0) & (row < self.rows) & (col >= 0) & (col < self.cols)
        return row, col, inside
