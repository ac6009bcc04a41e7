"""Procedural assets as MeshData (pure numpy): vehicles, trees, buildings, street lights, bridges.

Material names used here are defined in blender_scripts/materials.py, each with its fine class.
Vehicles are built in their own frame: x forward, origin on the ground at the box centre.
"""

from __future__ import annotations


import numpy as np

from .shapes import MeshData

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


def vehicle_mesh(kind: str, size, rng: np.random.Generator) -> MeshData:
    """Body in the 'car_paint' material (colour from the object), glass, tyres, lamps."""
    l, w, h = size
    wr = VEHICLE_SIZES[kind][1]
    m = MeshData()
    clear = wr * 0.6  # ground clearance of the body
    if kind in ("car", "suv"):
        low = h * 0.5
        m.box((0, 0, clear), (l, w, low - clear + 0.05), mat="car_paint")
        cab_l = l * rng.uniform(0.48, 0.58)
        cab_x = -l * rng.uniform(0.02, 0.08)
        m.box((cab_x, 0, low), (cab_l, w * 0.92, h - low - 0.06), mat="car_glass")
        m.box((cab_x, 0, h - 0.06), (cab_l * 0.92, w * 0.86, 0.06), mat="car_paint")
    elif kind == "van":
        m.box((0, 0, clear), (l, w, h * 0.55 - clear), mat="car_paint")
        m.box((-0.3, 0, h * 0.55), (l - 0.9, w * 0.98, h * 0.45), mat="car_paint")
        m.box((l / 2 - 0.75, 0, h * 0.55), (0.6, w * 0.94, h * 0.35), mat="car_glass")
    elif kind == "truck":
        cab = 2.2
        m.box((l / 2 - cab / 2, 0, clear), (cab, w, h * 0.55), mat="car_paint")
        m.box((l / 2 - cab / 2 + 0.1, 0, clear + h * 0.55), (cab - 0.2, w * 0.95, h * 0.25), mat="car_glass")
        m.box((-cab / 2 - 0.15, 0, clear + 0.2), (l - cab - 0.3, w, h - clear - 0.2), mat="cargo")
    else:  # bus
        m.box((0, 0, clear), (l, w, h * 0.45 - clear), mat="car_paint")
        m.box((0, 0, h * 0.45), (l - 0.05, w - 0.04, h * 0.35), mat="car_glass")
        m.box((0, 0, h * 0.8), (l, w, h * 0.2), mat="car_paint")
    # lamps on the front and rear faces
    for side in (-1, 1):
        m.box((l / 2 + 0.01, side * (w / 2 - 0.3), clear + 0.25), (0.04, 0.35, 0.15), mat="headlight")
        m.box((-l / 2 - 0.01, side * (w / 2 - 0.3), clear + 0.25), (0.04, 0.35, 0.15), mat="taillight")
    axles = [l / 2 - max(0.8, l * 0.17), -l / 2 + max(0.8, l * 0.2)]
    if kind in ("truck", "bus"):
        axles.append(-l / 2 + max(0.8, l * 0.2) + 1.3)
    for ax in axles:
        for side in (-1, 1):
            m.cylinder((ax, side * (w / 2 - 0.12), wr), wr, 0.24, n=10, mat="tyre", axis="y")
    return m


def tree_meshes(rng: np.random.Generator, overhang: bool):
    """(trunk MeshData, canopy MeshData, canopy centre offset toward +y local, canopy radius).
    Built at the origin; an overhanging tree's crown leans toward local +y."""
    trunk_h = rng.uniform(4.5, 7.0) if overhang else rng.uniform(2.5, 5.0)
    r = rng.uniform(3.0, 5.0) if overhang else rng.uniform(1.5, 3.5)
    lean = rng.uniform(1.0, 2.5) if overhang else 0.0
    trunk = MeshData().cylinder((0, 0, 0), rng.uniform(0.15, 0.3), trunk_h + r * 0.5, n=8, mat="bark")
    zc = trunk_h + r * 0.55
    canopy = MeshData().ellipsoid((0, lean, zc), (r, r, r * rng.uniform(0.55, 0.8)), mat="leaves", nu=10, nv=6)
    return trunk, canopy


def building_mesh(rng: np.random.Generator, length, depth, height) -> MeshData:
    """A box building facing local -y (the street), window bands on every floor."""
    m = MeshData().box((0, 0, 0), (length, depth, height), mat="wall")
    floors = max(1, int(height / 3.2))
    for f in range(floors):
        z = f * 3.2 + 1.0
        if z + 1.4 > height:
            break
        for side in (-1, 1):
            m.box((0, side * (depth / 2 + 0.03), z), (length * 0.9, 0.06, 1.4), mat="window")
    return m


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
    body = vehicle_mesh(kind, size, rng)
    v = body.vertices
    lower_top = size[2] * 0.5 + 0.05
    faces_z = np.array([v[list(f)][:, 2].min() for f in body.faces])
    cab = faces_z >= lower_top - 0.051  # the cabin (glass, roof) above the lower body
    inside = [(x0 < x < x1 and abs(y) < half_w and lower_top - 0.05 < z < size[2] + 0.05) for x, y, z in p]
    out = MeshData()
    for f, mat, up in zip(body.faces, body.mats, cab):
        if up and any(inside):
            continue
        out.add(v[list(f)] + ((x0 + x1) / 2, 0.0, 0.0), [list(range(len(f)))], f"ego_{mat}")
    colour = EGO_PAINT[int(rng.integers(len(EGO_PAINT)))]
    return out, [float(x0), float(x1), -half_w, half_w], kind, colour
