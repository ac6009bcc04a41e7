"""Splat: lifted frustum features -> per-camera BEV features, with precomputed indices.

Each feature pixel (camera n, row h, column w) times each ray-distance bin d is a 3D point; the lift
(`model.frustum`) says which BEV cell it falls in (`point_cell`, -1 when outside the grid). The feature
of a point is depth[d, h, w] * context[:, h, w] (LSS's outer product). The splat sums them per cell:

    bev[b, n, cell, :] = sum over points p in cell of depth[b, n, p] * context[b, n, :, pixel(p)]

It never builds the (B, N, D, H, W, C) outer product: `SplatIndex` keeps, for the points that land
in the grid only, the flat position of their depth value, of their context pixel and of their target
cell; the forward gathers context rows, weights them by depth and `index_add_`s them into the grid,
in chunks. A custom autograd function recomputes the gathers in the backward instead of storing the
(P, C) weighted features.
"""

from __future__ import annotations

from dataclasses import dataclass

from contextlib import contextmanager

import torch

CHUNK = 8192  # points per gather/index_add_ chunk: the (chunk, C) buffer stays in cache


@dataclass
class SplatIndex:
    """Flat indices of the points that land in the grid.

    point:  into depth.reshape(-1)            (B*N*D*H*W)
    pixel:  into context rows (B*N*H*W, C)
    target: into the output rows (B*N*cells, C), or (B*cells, C) when cameras are summed
    """

    point: torch.Tensor
    pixel: torch.Tensor
    target: torch.Tensor
    batch: int
    cameras: int
    cells: int
    summed: bool

    @property
    def out_rows(self) -> int:
        return self.batch * (1 if self.summed else self.cameras) * self.cells


def splat_index(point_cell: torch.Tensor, cells: int, sum_cameras: bool = False) -> SplatIndex:
    """Indices for `splat` from point_cell (B, N, D, H, W) int (cell index or -1).

    With sum_cameras the cameras of a sample share one grid (sum pooling, the cheapest).
    """
    if point_cell.ndim != 5:
        raise ValueError(f"point_cell must be (B, N, D, H, W), got {tuple(point_cell.shape)}")
    b, n, d, h, w = point_cell.shape
    flat = point_cell.reshape(-1)
    point = torch.nonzero(flat >= 0).squeeze(1)
    cell = flat[point]
    hw = point % (h * w)
    bn = point // (d * h * w)  # b * n + camera
    pixel = bn * (h * w) + hw
    target = (bn // n if sum_cameras else bn) * cells + cell
    order = torch.argsort(target, stable=True)  # cell-ordered: index_add_ then writes rows in order
    return SplatIndex(point[order], pixel[order], target[order], b, n, cells, sum_cameras)


@contextmanager
def _one_cpu_thread(t: torch.Tensor):
    """Run the scatter on one thread on CPU: index_add_ is memory-bound, and its multi-threaded
    CPU kernel was measured 400x slower (63 ms vs 0.16 ms per 8192-row chunk) on a loaded 2-core
    machine, where every parallel region waits for a descheduled thread."""
    if t.device.type != "cpu" or torch.get_num_threads() == 1:
        yield
        return
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(n)


class _Splat(torch.autograd.Function):
    @staticmethod
    def forward(ctx, depth_flat, context_rows, point, pixel, target, out_rows, chunk):
        out = context_rows.new_zeros(out_rows, context_rows.shape[1])
        with _one_cpu_thread(out):
            _forward_chunks(out, depth_flat, context_rows, point, pixel, target, chunk)
        ctx.save_for_backward(depth_flat, context_rows, point, pixel, target)
        ctx.chunk = chunk
        return out

    @staticmethod
    def backward(ctx, grad_out):
        depth_flat, context_rows, point, pixel, target = ctx.saved_tensors
        grad_depth = torch.zeros_like(depth_flat) if ctx.needs_input_grad[0] else None
        grad_context = torch.zeros_like(context_rows) if ctx.needs_input_grad[1] else None
        with _one_cpu_thread(grad_out):
            _backward_chunks(grad_out.contiguous(), grad_depth, grad_context, depth_flat, context_rows, point, pixel, target, ctx.chunk)
        return grad_depth, grad_context, None, None, None, None, None


def _forward_chunks(out, depth_flat, context_rows, point, pixel, target, chunk):
    for s in range(0, point.numel(), chunk):
        p, q, t = point[s : s + chunk], pixel[s : s + chunk], target[s : s + chunk]
        out.index_add_(0, t, context_rows.index_select(0, q).mul_(depth_flat.index_select(0, p)[:, None]))


def _backward_chunks(grad_out, grad_depth, grad_context, depth_flat, context_rows, point, pixel, target, chunk):
    for s in range(0, point.numel(), chunk):
        p, q, t = point[s : s + chunk], pixel[s : s + chunk], target[s : s + chunk]
        g = grad_out.index_select(0, t)  # (chunk, C)
        if grad_depth is not None:  # each point appears once: a plain copy
            grad_depth.index_copy_(0, p, torch.linalg.vecdot(g, context_rows.index_select(0, q)))
        if grad_context is not None:
            grad_context.index_add_(0, q, g.mul_(depth_flat.index_select(0, p)[:, None]))


def splat(depth: torch.Tensor, context: torch.Tensor, index: SplatIndex, chunk: int = CHUNK) -> torch.Tensor:
    """depth (B, N, D, H, W), context (B, N, C, H, W) -> BEV features, channels last:
    (B, N, cells, C), or (B, cells, C) when the index sums cameras."""
    if depth.ndim != 5 or context.ndim != 5 or depth.shape[:2] != context.shape[:2] or depth.shape[3:] != context.shape[3:]:
        raise ValueError(f"splat: depth (B,N,D,H,W) {tuple(depth.shape)} and context (B,N,C,H,W) {tuple(context.shape)} disagree")
    b, n, c = context.shape[:3]
    if (b, n) != (index.batch, index.cameras):
        raise ValueError(f"splat: index is for {index.batch}x{index.cameras} images, features for {b}x{n}")
    rows = context.permute(0, 1, 3, 4, 2).reshape(-1, c)
    out = _Splat.apply(depth.reshape(-1), rows, index.point, index.pixel, index.target, index.out_rows, chunk)
    return out.view(b, index.cells, c) if index.summed else out.view(b, n, index.cells, c)


def splat_count(index: SplatIndex) -> torch.Tensor:
    """How many lifted points land in each cell: (B, N, cells) or (B, cells) float."""
    out = torch.zeros(index.out_rows, dtype=torch.float32, device=index.target.device)
    out.index_add_(0, index.target, torch.ones_like(index.target, dtype=torch.float32))
    return out.view(index.batch, index.cells) if index.summed else out.view(index.batch, index.cameras, index.cells)
