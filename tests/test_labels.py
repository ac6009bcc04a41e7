"""Label fusion on constructed frames: a plane and boxes ray-cast through the rig's camera models,
written as real EXR files (testing.constructed), fused by dataset_tools.fuse and read back by
dataset_tools.format.reader."""

import numpy as np
import pytest

from dataset_tools.labels.classes import CLASS_IDS, class_lut
from dataset_tools.format.labels import write_labels
from dataset_tools.format.passes import read_topdown
from dataset_tools.format.reader import DatasetIndex, downsample_labels, read_frame
from dataset_tools.labels.label_fusion import FusionConfig, fuse_frame
from geometry.bev import BevGrid
from geometry.rig import Rig, load_rig
from testing.constructed import Box, render_camera, write_dataset, write_frame

STREET, LANE, VEHICLE, BACKGROUND, INVALID = 3, 2, 1, 4, 0


@pytest.fixture(scope="module")
def rig():
    return load_rig("configs/rigs/default.yaml")


@pytest.fixture(scope="module")
def front_only(rig):
    return Rig([rig["front"]], "front_only")


@pytest.fixture(scope="module")
def grid():
    return BevGrid()


def cells(grid, x0, x1, y0, y1):
    c = grid.cell_centres()
    return (c[..., 0] >= x0) & (c[..., 0] <= x1) & (c[..., 1] >= y0) & (c[..., 1] <= y1)


def fused(tmp_path, name, rig, grid, boxes, cfg=None):
    d = write_frame(tmp_path / name, rig, grid, boxes)
    return fuse_frame(d, cfg or FusionConfig())


def test_box_on_plane_leaves_cells_behind_it_unseen(tmp_path, front_only, grid):
    wall = Box(6.0, 6.5, -1.0, 1.0, 0.0, 2.0, "building", 9)
    open_ = fused(tmp_path, "open", front_only, grid, [])["visibility"]
    boxed = fused(tmp_path, "box", front_only, grid, [wall])["visibility"]
    # the wall's shadow from the front camera (x 3.75 m, 0.6 m high) is |y| < 2.3 m at x = 9 m
    behind = cells(grid, 9.0, 13.0, -1.5, 1.5)
    beside = cells(grid, 9.0, 12.0, 4.0, 5.0)
    print(f"behind the box: open min p {open_[behind].min():.2f}, with box max p {boxed[behind].max():.3f}")
    assert open_[behind].min() > 0.5  # the same cells are seen without the box
    assert np.all(boxed[behind] == 0.0)
    assert boxed[beside].min() > 0.5
    np.testing.assert_array_equal(boxed[beside], open_[beside])


def test_cells_under_canopy_are_street_not_vegetation(tmp_path, rig, grid):
    canopy = Box(5.0, 12.0, -3.0, 3.0, 4.0, 6.0, "canopy", 7)
    d = write_frame(tmp_path / "canopy", rig, grid, [canopy])
    lab = fuse_frame(d)
    td = read_topdown(d)
    under = cells(grid, 5.1, 11.9, -2.9, 2.9)
    first_hit = class_lut()[td["semantic_all"]]
    assert np.all(td["semantic_all"][under] == CLASS_IDS["canopy"])
    assert np.all(first_hit[under] == BACKGROUND)  # what a plain top-down view would label
    assert set(np.unique(lab["semantic"][under])) == {STREET, LANE}
    road = td["semantic"][under] == CLASS_IDS["road"]
    assert road.mean() > 0.9 and np.all(lab["semantic"][under][road] == STREET)


def test_partly_seen_vehicle_is_visible_over_its_whole_footprint(tmp_path, front_only, grid):
    wall = Box(8.0, 8.5, -3.0, 0.0, 0.0, 2.5, "building", 9)
    car = Box(12.0, 16.5, -2.0, 1.5, 0.0, 1.5, "vehicle", 5)
    d = write_frame(tmp_path / "car", front_only, grid, [wall, car])
    on = fuse_frame(d)
    off = fuse_frame(d, FusionConfig(min_vehicle_pixels=10**9))
    foot = on["instance"] == 5
    seen = (render_camera(front_only["front"], [wall, car])["instance"] == 5).sum()
    alone = (render_camera(front_only["front"], [car])["instance"] == 5).sum()
    print(f"vehicle pixels seen {seen} of {alone} unoccluded; footprint cells {foot.sum()}")
    assert 20 <= seen < 0.8 * alone  # partly seen
    assert foot.sum() == cells(grid, 12.0, 16.5, -2.0, 1.5).sum()
    assert np.mean(off["visibility"][foot] < 0.5) > 0.1  # without the rule, part of it is hidden
    assert np.all(on["visibility"][foot] == 1.0)
    assert np.all(on["semantic"][foot] == VEHICLE)


def test_ego_footprint_is_invalid(tmp_path, rig, grid):
    lab = fused(tmp_path, "ego", rig, grid, [])
    ego = cells(grid, -1.0, 3.8, -0.9, 0.9)
    assert np.all(lab["semantic"][ego] == INVALID) and np.all(lab["visibility"][ego] == 0)
    assert np.all(lab["semantic"][cells(grid, 5.0, 10.0, -1.0, 1.0)] == STREET)


def test_fusion_is_deterministic_and_reads_back(tmp_path, rig, grid):
    boxes = [Box(6.0, 10.5, 2.0, 4.0, 0.0, 1.6, "vehicle", 3), Box(-9.0, -8.0, -6.0, -2.0, 0.0, 3.0, "building", 4)]
    root = write_dataset(tmp_path / "ds", rig, grid, [("s0", 0, "train", boxes)])
    frame = root / "s0/000000"
    write_labels(frame, fuse_frame(frame))
    first = {p.name: p.read_bytes() for p in (frame / "labels").glob("*.png")}
    write_labels(frame, fuse_frame(frame))
    second = {p.name: p.read_bytes() for p in (frame / "labels").glob("*.png")}
    assert sorted(first) == ["instance.png", "semantic.png", "visibility.png"]
    assert first == second
    idx = DatasetIndex(root)
    (ref,) = idx.frames("train")
    f = read_frame(ref)
    lab = fuse_frame(frame)
    assert sorted(f["images"]) == ["front", "left", "rear", "right"]
    assert f["images"]["front"].shape == (302, 480, 3) and f["images"]["front"].dtype == np.uint8
    np.testing.assert_array_equal(f["semantic"], lab["semantic"])
    np.testing.assert_array_equal(f["instance"], lab["instance"])
    assert f["visibility"].dtype == np.float32
    assert np.abs(f["visibility"] - lab["visibility"]).max() <= 0.5 / 65535 + 1e-7
    assert idx.grid == grid and idx.rig.names == rig.names


def test_downsample_keeps_thin_lane_markings(tmp_path, rig, grid):
    lab = fused(tmp_path, "lanes", rig, grid, [Box(6.0, 10.5, 2.0, 4.0, 0.0, 1.6, "vehicle", 3)])
    sem, vis = downsample_labels(lab["semantic"], lab["visibility"], 2)
    assert sem.shape == vis.shape == (200, 200)
    coarse = grid.with_res(0.25)
    c = coarse.cell_centres()
    # every coarse row keeps the 15 cm lines at y = -1.75 m and 1.75 m (outside the ego box)
    for yl in (-1.75, 1.75):
        rows = (np.abs(c[..., 1] - yl) < 0.25) & ((c[..., 0] > 5) | (c[..., 0] < -3))
        per_row = (sem == LANE) & rows
        assert np.all(per_row.any(axis=1)[rows.any(axis=1)])
    fine_lane = (lab["semantic"] == LANE).mean()
    assert (sem == LANE).mean() < 3 * fine_lane  # kept, not smeared
    assert np.all(sem[cells(coarse, 6.0, 10.5, 2.0, 4.0)] == VEHICLE)
    np.testing.assert_allclose(vis, lab["visibility"].reshape(200, 2, 200, 2).mean((1, 3)), atol=1e-6)
    # majority elsewhere: a block of 3 street + 1 background is street
    s = np.array([[3, 3], [4, 3]], np.uint8)
    assert downsample_labels(s, np.ones((2, 2), np.float32), 2)[0][0, 0] == STREET
