"""Bicycles and motorcycles (pure numpy), parked on the pavements or ridden along them.

Each two-wheeler is one object of its own fine class (`bicycle`, `motorcycle`; materials bike_* and
moto_*), and its rider, when it has one, a second object of the class `pedestrian` (the people's
materials). Like the people they stand still over a scene's frames. Their draws come from their own
generator (build_scene passes scene_rng(seed, 9)), so the layout, traffic, people and ego drive of a
recipe are what they were before.
"""

from __future__ import annotations

import math

import numpy as np

from .layouts import Z_KERB, Layout
from .meshes import MeshData

PER_100M = 1.0  # two-wheelers per 100 m of pavement, on average (Poisson)
MAX_TWO_WHEELERS = 30
MOTORCYCLE = 0.35  # share of motorcycles
RIDDEN = 0.4  # share with a rider
# frame paint (RGB): black, dark grey, silver, red, blue, white, green
PAINT = ((0.02, 0.02, 0.02), (0.12, 0.12, 0.13), (0.55, 0.56, 0.58), (0.45, 0.03, 0.03), (0.04, 0.1, 0.35),
         (0.8, 0.8, 0.78), (0.05, 0.2, 0.08))


def _ring(m: MeshData, x: float, r: float, z: float, tube: float, mat: str, n: int = 18, k: int = 6, y: float = 0.0):
    """A torus in the x-z plane (axle along y) centred at (x, y, z): radius r, tube radius `tube`."""
    a = np.linspace(0, 2 * math.pi, n, endpoint=False)
    b = np.linspace(0, 2 * math.pi, k, endpoint=False)
    rad = r + tube * np.cos(b)[None, :]  # (1, k): distance from the axle around the tube
    v = np.stack(np.broadcast_arrays(x + rad * np.cos(a)[:, None], y + tube * np.sin(b)[None, :],
                                     z + rad * np.sin(a)[:, None]), -1).reshape(-1, 3)
    faces = [(i * k + j, i * k + (j + 1) % k, ((i + 1) % n) * k + (j + 1) % k, ((i + 1) % n) * k + j)
             for i in range(n) for j in range(k)]
    m.add(v, faces, mat)


def bicycle_mesh() -> tuple[MeshData, dict]:
    """A bicycle facing +x, wheels on z = 0; returns the mesh and the rider's contact points
    (saddle, grips, pedals) in its frame."""
    m = MeshData()
    m.smooth_angle = 50.0
    r, wb = 0.34, 1.04
    rear, front = (-wb / 2, 0.0, r), (wb / 2, 0.0, r)
    for x in (rear[0], front[0]):
        _ring(m, x, r - 0.015, r, 0.018, "bike_tyre")
        _ring(m, x, r - 0.045, r, 0.01, "bike_metal", k=4)
        for t in np.linspace(0, math.pi, 6, endpoint=False):  # spokes, hub to rim both ways
            d = np.array([math.cos(t), 0.0, math.sin(t)]) * (r - 0.05)
            m.tube(np.array([x, 0, r]) - d, np.array([x, 0, r]) + d, 0.004, n=3, mat="bike_metal", caps=False)
    bb, seat, head_hi, head_lo = (-0.02, 0.0, 0.3), (-0.2, 0.0, 0.82), (0.4, 0.0, 0.8), (0.44, 0.0, 0.64)
    for p0, p1 in ((rear, bb), (bb, seat), (seat, head_hi), (bb, head_lo), (seat, rear), (head_hi, head_lo)):
        m.tube(p0, p1, 0.018, n=6, mat="bike_frame")
    m.tube(head_lo, front, 0.014, n=6, mat="bike_frame")  # fork
    m.tube(head_hi, (0.38, 0.0, 0.98), 0.014, n=6, mat="bike_metal")  # stem
    m.tube((0.36, -0.26, 0.98), (0.36, 0.26, 0.98), 0.012, n=6, mat="bike_metal")  # bar
    for s in (-1, 1):
        m.tube((0.36, s * 0.2, 0.98), (0.36, s * 0.27, 0.98), 0.018, n=6, mat="bike_tyre")  # grips
    m.tube(seat, (-0.21, 0.0, 0.9), 0.012, n=6, mat="bike_metal")  # seat post
    m.ellipsoid((-0.19, 0.0, 0.92), (0.13, 0.07, 0.03), mat="bike_tyre", nu=8, nv=4)  # saddle
    for s in (-1, 1):
        m.box((bb[0] + s * 0.1, s * 0.1, bb[2] - 0.02 - s * 0.1), (0.1, 0.08, 0.02), mat="bike_tyre")  # pedals
    return m, {"seat": (-0.19, 0.0, 0.95), "grips": (0.36, 0.24, 0.98), "feet": (-0.02, 0.14, 0.2), "helmet": False}


def motorcycle_mesh() -> tuple[MeshData, dict]:
    """A motorcycle facing +x, wheels on z = 0; mesh and the rider's contact points."""
    m = MeshData()
    m.smooth_angle = 50.0
    r, wb = 0.31, 1.42
    for x in (-wb / 2, wb / 2):
        m.cylinder((x, 0.0, r), r, 0.13, n=18, mat="moto_tyre", axis="y")
        for s in (-1, 1):
            m.cylinder((x, s * 0.068, r), 0.62 * r, 0.005, n=12, mat="moto_metal", axis="y")  # wheel discs
    m.box((-0.05, 0.0, 0.22), (0.5, 0.3, 0.36), mat="moto_metal")  # engine
    m.ellipsoid((0.2, 0.0, 0.86), (0.3, 0.17, 0.13), mat="moto_body", nu=12, nv=6)  # tank
    m.ellipsoid((-0.3, 0.0, 0.8), (0.38, 0.14, 0.06), mat="moto_seat", nu=10, nv=4)  # seat
    m.ellipsoid((-0.66, 0.0, 0.74), (0.26, 0.1, 0.08), mat="moto_body", nu=10, nv=4)  # tail
    m.ellipsoid((wb / 2 - 0.02, 0.0, r + 0.2), (0.22, 0.08, 0.04), mat="moto_body", nu=8, nv=4)  # front mudguard
    for s in (-1, 1):
        m.tube((wb / 2, s * 0.09, r), (0.5, s * 0.09, 1.0), 0.025, n=6, mat="moto_metal")  # fork legs
        m.tube((-wb / 2, s * 0.1, r), (-0.15, s * 0.12, 0.45), 0.022, n=6, mat="moto_metal")  # swing arm
    m.tube((0.48, -0.38, 1.04), (0.48, 0.38, 1.04), 0.014, n=6, mat="moto_metal")  # bar
    m.ellipsoid((0.62, 0.0, 0.98), (0.07, 0.11, 0.11), mat="moto_lamp", nu=10, nv=6)  # headlamp
    m.tube((-0.1, -0.19, 0.28), (-0.78, -0.19, 0.42), 0.045, n=8, mat="moto_metal")  # exhaust
    return m, {"seat": (-0.28, 0.0, 0.86), "grips": (0.46, 0.34, 1.04), "feet": (0.0, 0.2, 0.35), "helmet": True}


def rider_mesh(rng: np.random.Generator, contact: dict) -> MeshData:
    """A person astride (the people's materials): hips on the seat, hands on the grips, feet on the
    pedals or pegs, a helmet on a motorcyclist."""
    m = MeshData()
    m.smooth_angle = 60.0
    sx, _, sz = contact["seat"]
    gx, gy, gz = contact["grips"]
    fx, fy, fz = contact["feet"]
    girth = rng.uniform(0.9, 1.1)
    hip = np.array([sx, 0.0, sz + 0.05])
    lean = rng.uniform(0.25, 0.55)  # torso lean forward (radians from upright)
    torso = 0.55 * rng.uniform(0.95, 1.08)
    shoulder = hip + torso * np.array([math.sin(lean), 0.0, math.cos(lean)])
    m.ellipsoid((hip + shoulder) / 2, (0.13 * girth, 0.19 * girth, torso / 2 + 0.05), mat="clothes", nu=10, nv=6)
    for s in (-1, 1):
        knee = np.array([fx + 0.18, s * (fy + 0.02), (hip[2] + fz) / 2 + 0.12])
        m.tube(hip + (0, s * 0.1, 0), knee, 0.08 * girth, 0.06, n=7, mat="trousers")
        m.tube(knee, (fx, s * fy, fz), 0.055, 0.045, n=7, mat="trousers")
        m.box((fx + 0.05, s * fy, fz - 0.03), (0.25, 0.1, 0.07), mat="clothes")  # shoe
        sh = shoulder + (0, s * 0.19 * girth, -0.04)
        m.tube(sh, (gx - 0.02, s * gy, gz), 0.05 * girth, 0.04, n=6, mat="clothes")
        m.ellipsoid((gx, s * gy, gz), (0.045, 0.035, 0.05), mat="skin", nu=6, nv=4)
    head = shoulder + (0.06, 0.0, 0.2)
    m.tube(shoulder, head - (0, 0, 0.1), 0.05, n=6, mat="skin")
    m.ellipsoid(head, (0.1, 0.085, 0.115), mat="skin", nu=10, nv=6)
    if contact["helmet"]:
        m.ellipsoid(head + (0, 0, 0.02), (0.14, 0.125, 0.14), mat="clothes", nu=12, nv=6)
    else:
        m.ellipsoid(head + (-0.015, 0, 0.02), (0.105, 0.09, 0.105), mat="hair", nu=10, nv=6)
    return m


def place_two_wheelers(layout: Layout, rng: np.random.Generator, per_100m: float = PER_100M):
    """[(class, MeshData, (x, y, z), yaw, paint)] along the layout's pavements, nearest the origin
    first (at most MAX_TWO_WHEELERS, each with its rider right after it): parked ones across the
    pavement's kerb side or along it, ridden ones along it either way. `paint` is the frame's colour
    (None for a rider)."""
    out = []
    for path, a, b in layout.walks:
        n = int(rng.poisson(per_100m * path.length / 100.0))
        if n == 0:
            continue
        s = rng.uniform(0, path.length, n)
        u = rng.random((n, 4))
        xy, heading = path.at(s)
        nrm = np.stack([-np.sin(heading), np.cos(heading)], -1)
        lo, hi = min(a, b), max(a, b)
        for k in range(n):
            moto = u[k, 0] < MOTORCYCLE
            ridden = u[k, 1] < RIDDEN
            mesh, contact = motorcycle_mesh() if moto else bicycle_mesh()
            half = 1.0 if moto else 0.9
            if ridden or hi - lo < 2.2:  # along the pavement, in its middle
                lateral, yaw = (lo + hi) / 2, heading[k] + (math.pi if u[k, 2] < 0.5 else 0.0)
            else:  # parked across it, the front wheel toward the kerb or the wall
                lateral = (a if u[k, 2] < 0.5 else b) + (half + 0.1) * np.sign((a + b) / 2 - (a if u[k, 2] < 0.5 else b))
                yaw = heading[k] + math.pi / 2 + (math.pi if u[k, 3] < 0.5 else 0.0)
            p = xy[k] + lateral * nrm[k]
            loc = (float(p[0]), float(p[1]), Z_KERB)
            paint = PAINT[int(rng.integers(len(PAINT)))]
            group = [("motorcycle" if moto else "bicycle", mesh, loc, float(yaw), paint)]
            if ridden:
                group.append(("pedestrian", rider_mesh(rng, contact), loc, float(yaw), None))
            out.append(group)
    out.sort(key=lambda g: g[0][2][0] ** 2 + g[0][2][1] ** 2)
    return [o for g in out[:MAX_TWO_WHEELERS] for o in g]
