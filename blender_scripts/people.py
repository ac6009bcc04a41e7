"""People on the pavements (pure numpy): a walking figure per person, placed along the layout's
pavements. They stand still over a scene's frames (a pose mid-stride), carry their own fine class
`pedestrian` (materials skin, hair, clothes, trousers) and, like every object, an instance id.

Their draws come from their own generator (build_scene passes scene_rng(seed, 8)), so the layout,
traffic and ego drive of a recipe are what they were before people were added.
"""

from __future__ import annotations

import math

import numpy as np

from .layouts import Z_KERB, Layout
from .meshes import MeshData

PER_100M = 2.0  # people per 100 m of pavement, on average (Poisson)
MAX_PEOPLE = 60


def person_mesh(rng: np.random.Generator) -> MeshData:
    """A person facing +x with the feet on z = 0, mid-stride: legs, torso, arms, neck, head, hair."""
    h = float(np.clip(rng.normal(1.72, 0.09), 1.5, 1.95))
    stride = rng.uniform(0.0, 0.35)  # 0: standing
    girth = rng.uniform(0.9, 1.15)
    m = MeshData()
    m.smooth_angle = 60.0
    hip, shoulder = 0.5 * h, 0.81 * h
    for side, swing in ((-1, 1), (1, -1)):
        y = side * 0.1 * girth
        foot = (swing * stride / 2, y, 0.0)
        m.tube(foot, (0.0, y, hip), 0.055, 0.085 * girth, n=7, mat="trousers")
        m.box((foot[0] + 0.06, y, 0.0), (0.26, 0.1, 0.07), mat="clothes")  # shoe
        hand = (-swing * stride * 0.6, side * 0.24 * girth, 0.43 * h)
        m.tube((0.0, side * 0.21 * girth, shoulder), hand, 0.05 * girth, 0.04, n=6, mat="clothes")
        m.ellipsoid(hand, (0.045, 0.035, 0.07), mat="skin", nu=6, nv=4)
    m.ellipsoid((0.0, 0.0, (hip + shoulder) / 2 + 0.02), (0.12 * girth, 0.2 * girth, (shoulder - hip) / 2 + 0.06),
                mat="clothes", nu=10, nv=6)
    m.tube((0.0, 0.0, shoulder), (0.0, 0.0, 0.88 * h), 0.05, n=6, mat="skin")
    head = (0.01, 0.0, 0.935 * h)
    m.ellipsoid(head, (0.1, 0.085, 0.115), mat="skin", nu=10, nv=6)
    hair = rng.uniform(0.0, 0.04)
    m.ellipsoid((head[0] - 0.015, 0.0, head[2] + 0.02), (0.1 + hair, 0.09 + hair / 2, 0.1 + hair * 0.5), mat="hair",
                nu=10, nv=6)
    return m


def place_people(layout: Layout, rng: np.random.Generator, per_100m: float = PER_100M):
    """[(MeshData, (x, y, z), yaw)] of people on the layout's pavements, nearest the origin first
    (at most MAX_PEOPLE), facing along the pavement either way."""
    out = []
    for path, a, b in layout.walks:
        n = int(rng.poisson(per_100m * path.length / 100.0))
        s = rng.uniform(0, path.length, n)
        lateral = rng.uniform(min(a, b) + 0.4, max(a, b) - 0.4, n) if abs(a - b) > 0.9 else np.full(n, (a + b) / 2)
        turn = rng.random(n) < 0.5
        meshes = [person_mesh(rng) for _ in range(n)]
        if n == 0:
            continue
        xy, heading = path.at(s)
        nrm = np.stack([-np.sin(heading), np.cos(heading)], -1)
        for k in range(n):
            p = xy[k] + lateral[k] * nrm[k]
            out.append((meshes[k], (float(p[0]), float(p[1]), Z_KERB), float(heading[k] + (math.pi if turn[k] else 0.0))))
    out.sort(key=lambda o: o[1][0] ** 2 + o[1][1] ** 2)
    return out[:MAX_PEOPLE]
