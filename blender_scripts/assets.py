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


def _cabin(m: MeshData, x0, x1, z0, z1, w, rake_rear, rake_front, roof_mat="car_paint"):
    """A glasshouse from the beltline (x0..x1, width w, height z0) to a narrower, shorter roof at
    z1: raked windscreen and rear window, side windows leaning in (glass sides, painted roof)."""
    wt = w * 0.84
    v = [(x0, -w / 2, z0), (x1, -w / 2, z0), (x1, w / 2, z0), (x0, w / 2, z0),
         (x0 + rake_rear, -wt / 2, z1), (x1 - rake_front, -wt / 2, z1), (x1 - rake_front, wt / 2, z1), (x0 + rake_rear, wt / 2, z1)]
    m.add(v, [(0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)], "car_glass")
    m.add(v, [(4, 5, 6, 7)], roof_mat)
    # the roof skin over the glass edge and the pillars' colour read as one body
    m.box(((x0 + rake_rear + x1 - rake_front) / 2, 0, z1 - 0.04), (x1 - rake_front - x0 - rake_rear + 0.02, wt + 0.02, 0.05), mat=roof_mat)


# body style per kind: (cabin start, cabin end) as fractions of the length from the rear, beltline
# as a fraction of the height, rear and front rake of the glasshouse (m)
CAR_STYLES = {
    "sedan": ((0.22, 0.70), 0.55, 0.45, 0.75),
    "hatchback": ((0.05, 0.68), 0.55, 0.25, 0.75),
    "wagon": ((0.04, 0.70), 0.55, 0.12, 0.75),
    "suv": ((0.04, 0.72), 0.55, 0.15, 0.6),
    "pickup": ((0.42, 0.72), 0.55, 0.05, 0.55),
}
KIND_STYLES = {"car": ("sedan", "hatchback", "wagon"), "suv": ("suv", "pickup")}


def vehicle_mesh(kind: str, size, rng: np.random.Generator, style: str | None = None) -> MeshData:
    """Body in 'car_paint' (colour from the object), glasshouse, bumpers and trim, wheels with rims,
    head and tail lights; every part inside the (length, width, height) box. Cars are sedans,
    hatchbacks or wagons, SUVs are SUVs or pickups (`style`, else drawn)."""
    l, w, h = size
    wr = VEHICLE_SIZES[kind][1]
    m = MeshData()
    clear = wr * 0.6  # ground clearance of the body
    if kind in ("car", "suv"):
        style = style or KIND_STYLES[kind][int(rng.integers(len(KIND_STYLES[kind])))]
        (c0, c1), belt, rake_r, rake_f = CAR_STYLES[style]
        low = h * belt
        m.box((0, 0, clear), (l, w, low - clear), mat="car_paint")
        # the hood slopes down to the nose: a wedge on the front third
        m.box((l * 0.36, 0, low - 0.06), (l * 0.26, w * 0.96, 0.06), mat="car_paint")
        _cabin(m, -l / 2 + c0 * l, -l / 2 + c1 * l, low, h, w * 0.97, rake_r, rake_f * rng.uniform(0.85, 1.1))
        if style == "pickup":  # open bed walls behind the cab
            bed0, bed1 = -l / 2 + 0.05, -l / 2 + c0 * l - 0.05
            for side in (-1, 1):
                m.box(((bed0 + bed1) / 2, side * (w / 2 - 0.05), low), (bed1 - bed0, 0.08, 0.22), mat="car_paint")
            m.box((bed0 + 0.04, 0, low), (0.08, w - 0.1, 0.22), mat="car_paint")
    elif kind == "van":
        m.box((-0.25, 0, clear), (l - 0.5, w, h - clear - 0.02), mat="car_paint")
        m.box((l / 2 - 0.5, 0, clear), (0.5, w, h * 0.5 - clear), mat="car_paint")  # the nose
        _cabin(m, l / 2 - 1.2, l / 2 - 0.05, h * 0.5, h * 0.9, w * 0.98, 0.0, 0.55)
        for side in (-1, 1):
            m.box((0.3, side * (w / 2 + 0.005), h * 0.58), (l * 0.35, 0.01, h * 0.22), mat="car_glass")
    elif kind == "truck":
        cab = 2.2
        m.box((l / 2 - cab / 2, 0, clear), (cab, w, h * 0.55), mat="car_paint")
        m.box((l / 2 - cab / 2 + 0.1, 0, clear + h * 0.55), (cab - 0.2, w * 0.95, h * 0.25), mat="car_glass")
        m.box((l / 2 - cab / 2 + 0.1, 0, clear + h * 0.8), (cab - 0.3, w * 0.95, 0.08), mat="car_paint")
        m.box((-cab / 2 - 0.15, 0, clear + 0.2), (l - cab - 0.3, w, h - clear - 0.2), mat="cargo")
        m.box((-cab / 2 - 0.15, 0, clear), (l - cab - 0.3, w * 0.9, 0.2), mat="trim")  # chassis
    else:  # bus
        m.box((0, 0, clear), (l, w, h * 0.45 - clear), mat="car_paint")
        m.box((0, 0, h * 0.45), (l - 0.05, w - 0.04, h * 0.35), mat="car_glass")
        m.box((0, 0, h * 0.8), (l, w, h * 0.2), mat="car_paint")
        for k in range(1, int(l / 1.6)):  # window pillars
            for side in (-1, 1):
                m.box((-l / 2 + k * 1.6, side * (w / 2 - 0.015), h * 0.45), (0.12, 0.04, h * 0.35), mat="car_paint")
    # bumpers, lamps on the front and rear faces
    for end in (-1, 1):
        m.box((end * (l / 2 - 0.06), 0, clear - 0.05), (0.14, w * 0.98, 0.22), mat="trim")
        for side in (-1, 1):
            lamp = "headlight" if end > 0 else "taillight"
            m.box((end * (l / 2 - 0.01), side * (w / 2 - 0.25), clear + 0.3), (0.04, 0.3, 0.13), mat=lamp)
    axles = [l / 2 - max(0.8, l * 0.17), -l / 2 + max(0.8, l * 0.2)]
    if kind in ("truck", "bus"):
        axles.append(-l / 2 + max(0.8, l * 0.2) + 1.3)
    for ax in axles:
        for side in (-1, 1):
            m.cylinder((ax, side * (w / 2 - 0.12), wr), wr, 0.24, n=14, mat="tyre", axis="y")
            m.cylinder((ax, side * (w / 2 - 0.005), wr), wr * 0.6, 0.01, n=10, mat="rim", axis="y")
    return m


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
            canopy.ellipsoid((0, 0, trunk_h + k * r * 0.7 + rk * 0.6), (rk, rk, rk * 0.75), mat="leaves", nu=8, nv=5)
    elif shape == "tall":
        canopy.ellipsoid((0, 0, trunk_h + r * 1.2), (r * 0.55, r * 0.55, r * 1.6), mat="leaves", nu=8, nv=6)
    elif shape == "clustered":
        zc = trunk_h + r * 0.55
        for k in range(int(rng.integers(3, 5))):
            a = rng.uniform(0, 2 * np.pi)
            d = r * rng.uniform(0.2, 0.5)
            rk = r * rng.uniform(0.55, 0.75)
            canopy.ellipsoid((d * np.cos(a), lean + d * np.sin(a), zc + rng.uniform(-0.3, 0.4) * r),
                             (rk, rk, rk * 0.75), mat="leaves", nu=8, nv=5)
    else:
        zc = trunk_h + r * 0.55
        canopy.ellipsoid((0, lean, zc), (r, r, r * rng.uniform(0.55, 0.8)), mat="leaves", nu=10, nv=6)
    top = trunk_h + r * (0.5 if shape in ("round", "clustered") else 0.3)
    trunk = MeshData().cylinder((0, 0, 0), rng.uniform(0.15, 0.3), top, n=8, mat="bark")
    return trunk, canopy


def building_mesh(rng: np.random.Generator, length, depth, height) -> MeshData:
    """A building facing local -y (the street): a window grid (or bands) on every floor, often a
    glazed shop front on the ground floor, a cornice on top."""
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
    if shop:
        m.box((0, -(depth / 2 + 0.03), 0.35), (length * 0.86, 0.06, 2.5), mat="window")
        m.box((0, -(depth / 2 + 0.25), 2.95), (length * 0.9, 0.5, 0.12), mat="wall")  # awning / fascia
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
    low = size[2] * CAR_STYLES[style][1]  # the beltline: the glasshouse and roof sit above it
    faces_z = np.array([v[list(f)][:, 2].min() for f in body.faces])
    cab = faces_z >= low - 1e-6
    inside = [(x0 < x < x1 and abs(y) < half_w and low - 0.05 < z < size[2] + 0.05) for x, y, z in p]
    out = MeshData()
    for f, mat, up in zip(body.faces, body.mats, cab):
        if up and any(inside):
            continue
        out.add(v[list(f)] + ((x0 + x1) / 2, 0.0, 0.0), [list(range(len(f)))], f"ego_{mat}")
    colour = EGO_PAINT[int(rng.integers(len(EGO_PAINT)))]
    return out, [float(x0), float(x1), -half_w, half_w], kind, colour
