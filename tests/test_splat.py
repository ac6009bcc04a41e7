"""The splat against a naive per-point reference, forward and backward, and gradcheck."""

import pytest
import torch

from model.splat import splat, splat_count, splat_index


def random_case(b=2, n=3, d=4, h=3, w=5, c=6, cells=7, seed=0, dtype=torch.float32):
    g = torch.Generator().manual_seed(seed)
    depth = torch.rand(b, n, d, h, w, generator=g, dtype=dtype).softmax(2).requires_grad_()
    context = torch.randn(b, n, c, h, w, generator=g, dtype=dtype).requires_grad_()
    point_cell = torch.randint(-1, cells, (b, n, d, h, w), generator=g)  # about 1 in cells+1 outside
    return depth, context, point_cell, cells


def naive_splat(depth, context, point_cell, cells, sum_cameras):
    """Every point scattered one by one."""
    b, n, d, h, w = point_cell.shape
    c = context.shape[2]
    out = [[[torch.zeros(c, dtype=context.dtype) for _ in range(cells)] for _ in range(1 if sum_cameras else n)] for _ in range(b)]
    for bi in range(b):
        for ni in range(n):
            for di in range(d):
                for hi in range(h):
                    for wi in range(w):
                        cell = int(point_cell[bi, ni, di, hi, wi])
                        if cell < 0:
                            continue
                        k = 0 if sum_cameras else ni
                        out[bi][k][cell] = out[bi][k][cell] + depth[bi, ni, di, hi, wi] * context[bi, ni, :, hi, wi]
    t = torch.stack([torch.stack([torch.stack(cs) for cs in per_cam]) for per_cam in out])
    return t[:, 0] if sum_cameras else t


@pytest.mark.parametrize("sum_cameras", [False, True])
@pytest.mark.parametrize("chunk", [7, 1 << 16])
def test_splat_equals_naive_forward_and_backward(sum_cameras, chunk):
    depth, context, pc, cells = random_case()
    index = splat_index(pc, cells, sum_cameras)
    fast = splat(depth, context, index, chunk=chunk)
    ref = naive_splat(depth, context, pc, cells, sum_cameras)
    assert fast.shape == ref.shape
    assert torch.allclose(fast, ref, atol=1e-5, rtol=0)
    assert fast.abs().sum() > 0
    weights = torch.randn(fast.shape, generator=torch.Generator().manual_seed(1))
    g_fast = torch.autograd.grad((fast * weights).sum(), (depth, context))
    g_ref = torch.autograd.grad((ref * weights).sum(), (depth, context))
    for a, r in zip(g_fast, g_ref):
        assert torch.allclose(a, r, atol=1e-5, rtol=0)
    # points outside the grid get no gradient
    outside = pc < 0
    assert outside.any() and (g_fast[0][outside] == 0).all()


def test_splat_gradcheck_float64():
    depth, context, pc, cells = random_case(b=1, n=2, d=3, h=2, w=3, c=2, cells=4, dtype=torch.float64)
    index = splat_index(pc, cells)
    assert torch.autograd.gradcheck(lambda d, c: splat(d, c, index, chunk=5), (depth, context))


def test_splat_count_and_shape_errors():
    depth, context, pc, cells = random_case()
    counts = splat_count(splat_index(pc, cells))
    ref = torch.zeros(2, 3, cells)
    for bi in range(2):
        for ni in range(3):
            v = pc[bi, ni][pc[bi, ni] >= 0]
            ref[bi, ni] = torch.bincount(v, minlength=cells).float()
    assert torch.equal(counts, ref)
    with pytest.raises(ValueError, match="index is for"):
        splat(depth[:1], context[:1], splat_index(pc, cells))
    with pytest.raises(ValueError, match="point_cell"):
        splat_index(pc[0], cells)
