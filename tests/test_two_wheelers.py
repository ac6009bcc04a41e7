"""Bicycles, motorcycles and their riders (pure numpy, no rendering): sized like the real thing,
wheels on the ground, painted only with their own class's materials, riders astride, placed on the
pavements and the same for the same draw."""

from __future__ import annotations

import numpy as np
import pytest

from blender_scripts import two_wheelers as tw
from blender_scripts.layouts import Layout, Z_KERB
from blender_scripts.materials import MATERIAL_CLASSES
from blender_scripts.meshes import line_path


@pytest.mark.parametrize("make,cls,length", [(tw.bicycle_mesh, "bicycle", (1.6, 1.9)),
                                             (tw.motorcycle_mesh, "motorcycle", (1.9, 2.3))])
def test_two_wheeler_size_wheels_and_materials(make, cls, length):
    m, contact = make()
    v = m.vertices
    assert length[0] <= np.ptp(v[:, 0]) <= length[1]
    assert np.ptp(v[:, 1]) < 0.9 and 0.95 < v[:, 2].max() < 1.2
    assert abs(v[:, 2].min()) < 0.01, "the wheels do not touch the ground (polygonal: within 1 cm)"
    assert {MATERIAL_CLASSES[n] for n in m.mats} == {cls}
    assert max(max(f) for f in m.faces) < len(v)
    rider = tw.rider_mesh(np.random.default_rng(0), contact)
    r = rider.vertices
    assert {MATERIAL_CLASSES[n] for n in rider.mats} == {"pedestrian"}
    assert r[:, 2].min() > 0.1, "a rider's feet rest on the pedals or pegs, not the ground"
    assert 1.5 < r[:, 2].max() < 2.0, "a seated rider's head is 1.5-2 m up"
    assert abs(r[:, 0].max() - contact["grips"][0]) < 0.2, "the hands reach the grips"


def _layout():
    lay = Layout()
    path = line_path((-200.0, 0.0), (200.0, 0.0), step=5.0)
    lay.walks += [(path, 5.0, 8.0), (path, -5.0, -8.0)]  # two 3 m pavements either side of a road
    return lay


def test_placed_on_the_pavements_riders_with_their_bikes_and_deterministic():
    a = tw.place_two_wheelers(_layout(), np.random.default_rng(4))
    b = tw.place_two_wheelers(_layout(), np.random.default_rng(4))
    assert [(c, loc, yaw) for c, _, loc, yaw, _ in a] == [(c, loc, yaw) for c, _, loc, yaw, _ in b]
    classes = [c for c, *_ in a]
    assert {"bicycle", "motorcycle", "pedestrian"} <= set(classes)
    assert sum(c != "pedestrian" for c in classes) <= tw.MAX_TWO_WHEELERS
    for k, (cls, mesh, (x, y, z), yaw, paint) in enumerate(a):
        assert z == Z_KERB and 5.0 <= abs(y) <= 8.0, "off the pavement"
        if cls == "pedestrian":  # a rider follows its two-wheeler, at the same place
            assert a[k - 1][0] != "pedestrian" and a[k - 1][2] == (x, y, z) and paint is None
        else:
            assert paint in tw.PAINT
            # the whole two-wheeler stays on the pavement, however it is turned
            c, s = np.cos(yaw), np.sin(yaw)
            wy = y + s * mesh.vertices[:, 0] + c * mesh.vertices[:, 1]
            assert 4.9 <= np.abs(wy).min() and np.abs(wy).max() <= 8.1, (cls, y, yaw)
