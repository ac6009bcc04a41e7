"""Procedural assets as MeshData (pure numpy): vehicles, trees, buildings, street lights, bridges,
street furniture (traffic lights, hedges, bushes, benches, bins).

Material names used here are defined in blender_scripts/materials.py, each with its fine class.
Vehicles are built in their own frame: x forward, origin on the ground at the box centre.
"""

from __future__ import annotations

import math

import numpy as np

from .meshes import MeshData
from .vehicles import BELT, KIND_STYLES, build_vehicle

# kind -> (length, width, height) nominal, metres; wheel radius
VEHICLE_SIZES = {
    "car": ((4.4, 1.80, 1.45), 0.32),
    "suv": ((4.7, 1.90, 1.75), 0.36),
    "van": ((5.2, 2.00, 2.25), 0.34),
    "truck": ((8.5, 2.45, 3.50), 0.48),
    "bus": ((11.5, 2.50, 3.15), 0.48),
}


def vehicle_size(kind: str, rng: np.random.Generator, max_width: float) -> tuple[float, float, float]:
    (l, w, h), _ = VEHICLE_SIZES[kind]
    f = rng.uniform(0.93, 1.07, 3)
    return l * f[0], min(w * f[1], max_width), h * f[2]


def vehicle_mesh(kind: str, size, rng: np.random.Generator, style: str | None = None) -> MeshData:
    """A vehicle of `kind` filling its (length, width, height) box (blender_scripts/vehicles.py): cars
    are sedans, hatchbacks or wagons, SUVs are SUVs or pickups (`style`, else drawn)."""
    styles = KIND_STYLES[kind]
    if style is None:
        style = styles[int(rng.integers(len(styles)))] if len(styles) > 1 else styles[0]
    return build_vehicle(kind, size, VEHICLE_SIZES[kind][1], style)


TREE_SHAPES = ("round", "conifer", "clustered", "tall")


def tree_meshes(rng: np.random.Generator, overhang: bool, shape: str | None = None):
    """(trunk MeshData, canopy MeshData) built at the origin: a round crown, a conifer (stacked
    narrowing cones of leaves), a crown of several clustered blobs, or a tall narrow one (poplar).
    An overhanging tree is round or clustered and its crown leans toward local +y."""
    if shape is None:
        choices = ("round", "clustered") if overhang else TREE_SHAPES
        shape = choices[int(rng.integers(len(choices)))]
    trunk_h = rng.uniform(4.5, 7.0) if overhang else rng.uniform(2.5, 5.0)
    r = rng.uniform(3.0, 5.0) if overhang else rng.uniform(1.5, 3.5)
    lean = rng.uniform(1.0, 2.5) if overhang else 0.0
    canopy = MeshData()
    if shape == "conifer":
        trunk_h *= 0.4
        for k in range(3):
            rk = r * (0.9 - 0.25 * k)
            canopy.ellipsoid((0, 0, trunk_h + k * r * 0.7 + rk * 0.6), (rk, rk, rk * 0.75), mat="leaves", nu=14, nv=8)
    elif shape == "tall":
        canopy.ellipsoid((0, 0, trunk_h + r * 1.2), (r * 0.55, r * 0.55, r * 1.6), mat="leaves", nu=14, nv=10)
    elif shape == "clustered":
        zc = trunk_h + r * 0.55
        for k in range(int(rng.integers(3, 5))):
            a = rng.uniform(0, 2 * np.pi)
            d = r * rng.uniform(0.2, 0.5)
            rk = r * rng.uniform(0.55, 0.75)
            canopy.ellipsoid((d * np.cos(a), lean + d * np.sin(a), zc + rng.uniform(-0.3, 0.4) * r),
                             (rk, rk, rk * 0.75), mat="leaves", nu=14, nv=8)
    else:
        zc = trunk_h + r * 0.55
        canopy.ellipsoid((0, lean, zc), (r, r, r * rng.uniform(0.55, 0.8)), mat="leaves", nu=18, nv=10)
    top = trunk_h + r * (0.5 if shape in ("round", "clustered") else 0.3)
    trunk_r = rng.uniform(0.15, 0.3)
    trunk = MeshData().cylinder((0, 0, 0), trunk_r, top, n=8, mat="bark")
    # the details below come from their own stream (seeded by the draws above), so the layout's
    # generator advances exactly as it did before trees had them
    detail = np.random.default_rng([int(1e6 * trunk_h), int(1e6 * r), int(1e6 * trunk_r)])
    _lumpy(canopy, detail, r)
    if shape != "conifer":  # limbs belong to the crown: overhead, hidden with it from the label pass
        _branches(canopy, detail, trunk_h, top, trunk_r, r, lean)
    trunk.smooth_angle = canopy.smooth_angle = 60.0
    return trunk, canopy


def _lumpy(canopy: MeshData, rng: np.random.Generator, r: float) -> None:
    """Leaf clusters: every vertex of the crown pushed in or out by a few random waves over its
    direction, so the crown breaks into lobes instead of a smooth ellipsoid."""
    for k, v in enumerate(canopy.verts):
        c = v.mean(axis=0)
        d = v - c
        n = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)
        f = np.ones(len(v))
        for _ in range(4):
            axis = rng.normal(size=3)
            f += 0.12 * np.sin(rng.uniform(3, 7) * n @ (axis / np.linalg.norm(axis)) + rng.uniform(0, 2 * np.pi))
        f += rng.uniform(-0.06, 0.06, len(v))
        canopy.verts[k] = c + d * f[:, None]


def _branches(canopy: MeshData, rng: np.random.Generator, trunk_h, top, trunk_r, r, lean) -> None:
    """A few limbs from the upper trunk up and out into the crown, part of the crown's mesh (material
    `branch`, class canopy: an overhead occluder like the leaves; as `bark` on the trunk they stayed
    in the top-down ground pass as thin walls metres high that no camera is blocked by)."""
    for k in range(int(rng.integers(3, 6))):
        a = 2 * np.pi * k / 5 + rng.uniform(-0.4, 0.4)
        z0 = trunk_h * rng.uniform(0.7, 0.95)
        reach = r * rng.uniform(0.4, 0.7)
        end = (reach * np.cos(a), lean * 0.5 + reach * np.sin(a), min(top, z0 + reach * 0.9))
        canopy.tube((0.0, 0.0, z0), end, trunk_r * 0.35, trunk_r * 0.15, n=6, mat="branch")


def building_mesh(rng: np.random.Generator, length, depth, height) -> MeshData:
    """A building facing local -y (the street): a window grid (or bands) on every floor, balconies on
    some, often a glazed shop front on the ground floor under an awning or a fascia, a cornice on top."""
    m = MeshData().box((0, 0, 0), (length, depth, height), mat="wall")
    floor_h = rng.uniform(2.9, 3.6)
    floors = max(1, int(height / floor_h))
    shop = height > 5.0 and rng.random() < 0.5
    bands = rng.random() < 0.25
    win_w = rng.uniform(0.9, 1.8)
    pitch = win_w + rng.uniform(0.6, 2.0)
    n = max(1, int(length * 0.92 / pitch))
    win_h = floor_h * rng.uniform(0.4, 0.6)
    for f in range(1 if shop else 0, floors):
        z = f * floor_h + (floor_h - win_h) * 0.55
        if z + win_h > height - 0.3:
            break
        if bands:
            for side in (-1, 1):
                m.box((0, side * (depth / 2 + 0.03), z), (length * 0.9, 0.06, win_h), mat="window")
            continue
        # a grid on the street side only, one quad per window 3 cm off the wall (cheap to trace)
        y = -(depth / 2 + 0.03)
        for k in range(n):
            x = (k - (n - 1) / 2) * pitch
            m.add([(x - win_w / 2, y, z), (x + win_w / 2, y, z), (x + win_w / 2, y, z + win_h), (x - win_w / 2, y, z + win_h)],
                  [(0, 1, 2, 3)], "window")
        # balconies under every street-side window of about a third of the buildings (chosen from
        # the size already drawn: no draw more, so the layout's stream is unchanged)
        if f >= 1 and int(height * 10) % 3 == 0:
            for k in range(n):
                x = (k - (n - 1) / 2) * pitch
                m.box((x, y - 0.5, z - 0.12), (win_w + 0.4, 1.0, 0.12), mat="wall")  # slab
                m.box((x, y - 0.98, z), (win_w + 0.4, 0.04, 0.9), mat="railing")
                for sx in (-1, 1):
                    m.box((x + sx * (win_w / 2 + 0.18), y - 0.5, z), (0.04, 1.0, 0.9), mat="railing")
    if shop:
        m.box((0, -(depth / 2 + 0.03), 0.35), (length * 0.86, 0.06, 2.5), mat="window")
        y0 = -(depth / 2 + 0.03)
        if int(length * 10) % 3:  # an awning over two shop fronts in three, a fascia board over the rest
            hx = length * 0.43
            m.add([(-hx, y0, 3.05), (hx, y0, 3.05), (hx, y0 - 1.3, 2.55), (-hx, y0 - 1.3, 2.55)], [(0, 1, 2, 3)], "awning")
            m.add([(-hx, y0 - 1.3, 2.55), (hx, y0 - 1.3, 2.55), (hx, y0 - 1.3, 2.33), (-hx, y0 - 1.3, 2.33)], [(0, 1, 2, 3)],
                  "awning")  # valance
        else:
            m.box((0, y0 - 0.1, 2.95), (length * 0.9, 0.2, 0.5), mat="awning")  # fascia with the shop's colours
    m.box((0, 0, height), (length + 0.3, depth + 0.3, 0.3), mat="wall")  # cornice
    return m


def sign_mesh(rng: np.random.Generator) -> MeshData:
    """A road sign: a pole and a plate (round, square or a wide direction board) facing local -y."""
    h = rng.uniform(2.2, 3.0)
    m = MeshData().cylinder((0, 0, 0), 0.035, h, n=6, mat="metal")
    kind = int(rng.integers(3))
    if kind == 0:
        m.cylinder((0, -0.05, h - 0.1), 0.32, 0.03, n=12, mat="sign", axis="y")
    elif kind == 1:
        m.box((0, -0.05, h - 0.65), (0.6, 0.03, 0.6), mat="sign")
    else:
        m.box((0, -0.05, h - 0.75), (1.4, 0.03, 0.7), mat="sign")
    return m


SIGNAL_COLOURS = ("red", "amber", "green")  # top to bottom


def traffic_light_mesh(lit: int, height: float = 3.2) -> MeshData:
    """A traffic light facing local -y: a pole, a dark housing with a backplate, three lenses under
    visors (lens `lit` glows: 0 red, 1 amber, 2 green)."""
    m = MeshData().cylinder((0, 0, 0), 0.07, height, n=8, mat="metal")
    hz = height - 0.05
    m.box((0, -0.12, hz), (0.32, 0.24, 0.95), mat="signal_housing")
    m.box((0, -0.05, hz - 0.08), (0.55, 0.03, 1.1), mat="signal_housing")  # backplate
    for k, colour in enumerate(SIGNAL_COLOURS):
        z = hz + 0.95 - 0.16 - k * 0.3
        m.cylinder((0, -0.245, z), 0.1, 0.02, n=12, mat=f"signal_{colour}" if k == lit else "signal_off", axis="y")
        m.box((0, -0.3, z + 0.1), (0.24, 0.12, 0.02), mat="signal_housing")  # visor
    return m


def hedge_mesh(rng: np.random.Generator, length: float, height: float, depth: float) -> MeshData:
    """A clipped hedge along local x: a row of overlapping leafy blobs, bottom on z = 0."""
    m = MeshData()
    m.smooth_angle = 60.0
    n = max(2, int(length / 0.8))
    for k in range(n):
        x = (k + 0.5) * length / n - length / 2
        h = height * rng.uniform(0.9, 1.05)
        m.ellipsoid((x, rng.uniform(-0.05, 0.05), h / 2), (length / n * 0.75, depth / 2, h / 2), mat="hedge", nu=8, nv=5)
    return m


def bush_mesh(rng: np.random.Generator) -> MeshData:
    """A bush: a few leafy blobs round a centre, bottom on z = 0."""
    m = MeshData()
    m.smooth_angle = 60.0
    r = rng.uniform(0.4, 0.9)
    for _ in range(int(rng.integers(3, 6))):
        a = rng.uniform(0, 2 * math.pi)
        d = rng.uniform(0, r * 0.6)
        rr = r * rng.uniform(0.5, 0.8)
        m.ellipsoid((d * math.cos(a), d * math.sin(a), rr * 0.9), (rr, rr, rr * 0.9), mat="hedge", nu=8, nv=5)
    return m


def bench_mesh() -> MeshData:
    """A park bench along local x, its seat facing local -y: wooden slats on two metal frames."""
    m = MeshData()
    for x in (-0.7, 0.7):
        m.box((x, 0.0, 0.0), (0.06, 0.5, 0.42), mat="furniture_metal")
        m.box((x, 0.22, 0.42), (0.06, 0.06, 0.45), mat="furniture_metal")
    for k in range(3):
        m.box((0, -0.18 + k * 0.16, 0.42), (1.7, 0.12, 0.04), mat="bench_wood")  # seat slats
    for k in range(2):
        m.box((0, 0.24, 0.55 + k * 0.17), (1.7, 0.03, 0.11), mat="bench_wood")  # back slats
    return m


def bin_mesh() -> MeshData:
    """A litter bin on a post."""
    m = MeshData().cylinder((0, 0, 0), 0.04, 0.6, n=6, mat="furniture_metal")
    m.cylinder((0, 0, 0.35), 0.22, 0.6, n=12, mat="bin")
    return m


def bollard_mesh() -> MeshData:
    return MeshData().cylinder((0, 0, 0), 0.08, 0.9, n=8, mat="bollard")


def street_light_mesh(height: float, arm: float) -> tuple[MeshData, tuple[float, float, float]]:
    """Pole at the origin with an arm toward local +y; returns the mesh and the lamp position."""
    m = MeshData().cylinder((0, 0, 0), 0.09, height, n=8, mat="metal")
    m.box((0, arm / 2, height - 0.1), (0.12, arm, 0.1), mat="metal")
    m.box((0, arm, height - 0.25), (0.5, 0.25, 0.18), mat="lamp")
    return m, (0.0, arm, height - 0.3)


EGO_KINDS = ("car", "suv")  # hatchback, SUV
EGO_PAINT = ((0.55, 0.56, 0.58), (0.08, 0.09, 0.1), (0.8, 0.8, 0.78), (0.35, 0.05, 0.05), (0.1, 0.15, 0.3))


def ego_body(camera_positions, rng: np.random.Generator):
    """The ego car around the rig: (MeshData in the ego frame, footprint [x_min, x_max, y_min,
    y_max], kind, paint colour). The body ends 5 cm inside the outermost mounts (front and rear
    cameras stay in front of the bumpers, mirror cameras 8 cm outside the doors); a camera inside
    the cabin (a windscreen camera) drops the cabin and roof so it still sees out."""
    p = np.asarray(camera_positions, float).reshape(-1, 3)
    x0, x1 = p[:, 0].min() + 0.05, p[:, 0].max() - 0.05
    half_w = float(np.clip(np.abs(p[:, 1]).max() - 0.08, 0.7, 1.0))
    if x1 - x0 < 2.5:  # mounts too close together to bound a car: a nominal 4.4 m car round them
        c = (x0 + x1) / 2
        x0, x1 = c - 2.2, c + 2.2
    kind = EGO_KINDS[int(rng.integers(len(EGO_KINDS)))]
    (_, _, h), _ = VEHICLE_SIZES[kind]
    size = (x1 - x0, 2 * half_w, h * rng.uniform(0.97, 1.03))
    style = "hatchback" if kind == "car" else "suv"
    body = vehicle_mesh(kind, size, rng, style)
    v = body.vertices
    low = size[2] * BELT[style]  # the beltline: the glasshouse and roof sit above it
    faces_z = np.array([v[list(f)][:, 2].min() for f in body.faces])
    cab = faces_z >= low - 1e-6
    inside = [(x0 < x < x1 and abs(y) < half_w and low - 0.05 < z < size[2] + 0.05) for x, y, z in p]
    out = MeshData()
    out.smooth_angle = body.smooth_angle
    for f, mat, up in zip(body.faces, body.mats, cab):
        if up and any(inside):
            continue
        out.add(v[list(f)] + ((x0 + x1) / 2, 0.0, 0.0), [list(range(len(f)))], f"ego_{mat}")
    colour = EGO_PAINT[int(rng.integers(len(EGO_PAINT)))]
    return out, [float(x0), float(x1), -half_w, half_w], kind, colour
