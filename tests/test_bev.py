"""BEV grid orientation: up is +x, left is +y, cell centres as docs/geometry.md says."""

import numpy as np
import pytest
import torch

from geometry.bev import BevGrid


def test_label_and_model_grids():
    assert BevGrid().shape == (400, 400)
    assert BevGrid().with_res(0.25).shape == (200, 200)


def test_orientation_and_centres():
    g = BevGrid()
    c = g.cell_centres()
    assert c[0, 0].tolist() == [25 - 0.0625, 25 - 0.0625]  # top-left: far ahead, far left
    assert c[-1, -1].tolist() == [-25 + 0.0625, -25 + 0.0625]
    # a point ahead lands in an upper row, a point to the left in a left column
    row, col, inside = g.cell_of(np.array([[10.0, 0.01], [0.01, 10.0]]))
    assert inside.all()
    assert row[0] < 200 and col[0] == 199
    assert col[1] < 200 and row[1] == 199


def test_cell_of_inverts_centres_numpy_and_torch():
    g = BevGrid(res=0.25)
    c = g.cell_centres()
    row, col, inside = g.cell_of(c)
    assert inside.all()
    np.testing.assert_array_equal(row, np.arange(g.rows)[:, None].repeat(g.cols, 1))
    np.testing.assert_array_equal(col, np.arange(g.cols)[None, :].repeat(g.rows, 0))
    rt, ct, it = g.cell_of(torch.from_numpy(c))
    assert torch.equal(rt, torch.from_numpy(row)) and bool(it.all())
    _, _, out = g.cell_of(np.array([[25.01, 0.0], [0.0, -25.01]]))
    assert not out.any()


def test_bad_grids():
    with pytest.raises(ValueError, match="whole number"):
        BevGrid(res=0.3)
    with pytest.raises(ValueError, match="unknown key 'size'"):
        BevGrid.from_dict({"size": 3})
    assert BevGrid.from_dict({"bound": 10, "res": 0.5}).shape == (40, 40)
