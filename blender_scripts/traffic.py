"""Traffic (pure numpy): vehicles placed on lanes, moved along them frame by frame.

Every vehicle in a lane moves at the lane's speed, so the gaps set at placement hold for the whole
sequence and nobody overlaps; open lanes wrap around (a vehicle leaving the far end re-enters at the
start, far from the ego). Queued lanes (speed 0) hold vehicles waiting behind their stop line.
The ego takes a gap in its lane.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .assets import vehicle_size
from .layouts import Layout

MIN_GAP = 3.0  # m bumper to bumper
# what stands in parking bays: mostly cars, some SUVs, few vans (vans are about a tenth of
# the vehicles registered in Europe and the US, fewer of those parked at shops and homes)
PARKED_MIX = {"car": 6, "suv": 3, "van": 1}
EGO_REAR, EGO_FRONT = 1.0, 3.8  # the ego's extent behind / ahead of its origin (rear axle), m


@dataclass
class Vehicle:
    kind: str
    size: tuple  # length, width, height
    lane: int  # -1 for parked
    s0: float  # arc length at t = 0 (parked: unused)
    color: tuple
    parked_pose: tuple | None = None  # (x, y, yaw)


# paint (linear RGB, metallic 0/1), one entry a tenth of the traffic: white, black, grey and silver
# make up four fifths of the cars on European and North American roads, blue and red most of the rest
COLORS = [(0.80, 0.80, 0.79, 0.0), (0.70, 0.71, 0.72, 1.0), (0.74, 0.72, 0.66, 0.0),  # white, pearl, cream
          (0.015, 0.015, 0.016, 0.0), (0.02, 0.025, 0.04, 1.0),  # black, blue-black metallic
          (0.12, 0.125, 0.13, 1.0), (0.26, 0.27, 0.28, 1.0), (0.55, 0.56, 0.58, 1.0),  # dark grey, grey, silver
          (0.03, 0.09, 0.35, 1.0), (0.45, 0.03, 0.025, 0.0)]  # blue, red


def ego_s0(layout: Layout, recipe) -> float:
    """The ego's arc length at t = 0: its drive is centred on the origin (plus ego.start)."""
    lane = layout.lanes[layout.ego_lane]
    travel = lane.speed * recipe["frames"]["count"] / recipe["frames"]["rate_hz"]
    if lane.path.closed:
        return recipe["ego"]["start"] % lane.path.length
    d = np.linalg.norm(lane.path.points, axis=1)
    s_mid = lane.path.s[int(np.argmin(d))]
    return float(s_mid + recipe["ego"]["start"] - travel / 2)


def place_traffic(layout: Layout, recipe, rng: np.random.Generator) -> list[Vehicle]:
    tr = recipe["traffic"]
    kinds = tr["kinds"]
    # buses and trucks are rarer than cars
    weights = np.array([{"car": 5, "suv": 3, "van": 2, "truck": 1, "bus": 1}[k] for k in kinds], float)
    weights /= weights.sum()
    out: list[Vehicle] = []
    ego_s = ego_s0(layout, recipe)
    for li, lane in enumerate(layout.lanes):
        L = lane.path.length
        mean_gap = 30.0 / max(tr["density"], 1e-6)
        occupied = []  # (s_back, s_front) of placed vehicles, in arc length at t = 0
        if li == layout.ego_lane:
            occupied.append((ego_s - EGO_REAR, ego_s + EGO_FRONT))
        if tr["density"] <= 0:
            continue
        if lane.speed == 0:  # queue from the stop line backwards
            s = L
            while True:
                kind = str(rng.choice(kinds, p=weights))
                size = vehicle_size(kind, rng, lane.width - 0.35)
                s -= 1.5 + size[0] / 2
                if s - size[0] / 2 < 0 or rng.random() > min(0.95, tr["density"]):
                    break
                out.append(Vehicle(kind, size, li, s, COLORS[int(rng.integers(len(COLORS)))]))
                s -= size[0] / 2 + rng.uniform(1.0, 3.0)
            continue
        s = rng.uniform(0, mean_gap)
        while s < L:
            kind = str(rng.choice(kinds, p=weights))
            size = vehicle_size(kind, rng, lane.width - 0.35)
            lo, hi = s - size[0] / 2 - MIN_GAP, s + size[0] / 2 + MIN_GAP
            clash = any(_overlap(lo, hi, a, b, L if lane.path.closed else None) for a, b in occupied)
            if not clash and s + size[0] / 2 + MIN_GAP < L and s - size[0] / 2 > 0:
                occupied.append((s - size[0] / 2, s + size[0] / 2))
                out.append(Vehicle(kind, size, li, s, COLORS[int(rng.integers(len(COLORS)))]))
                s += size[0] + MIN_GAP + rng.exponential(mean_gap)
            else:
                s += 2.0
    parked_kinds = [k for k in kinds if k in PARKED_MIX] or ["car"]
    parked_p = np.array([PARKED_MIX[k] for k in parked_kinds], float)
    for x, y, yaw, max_l, max_w in layout.parked:
        kind = str(rng.choice(parked_kinds, p=parked_p / parked_p.sum()))
        size = vehicle_size(kind, rng, max_w)
        size = (min(size[0], max_l), size[1], size[2])
        out.append(Vehicle(kind, size, -1, 0.0, COLORS[int(rng.integers(len(COLORS)))], (x, y, yaw)))
    return out


def _overlap(a0, a1, b0, b1, period):
    if period is None:
        return a0 < b1 and b0 < a1
    return any(a0 + k * period < b1 and b0 < a1 + k * period for k in (-1, 0, 1))


def pose_at(layout: Layout, lane_index: int, s0: float, t: float) -> tuple[float, float, float]:
    """(x, y, yaw) of something at arc length s0 + speed * t, wrapping open lanes."""
    lane = layout.lanes[lane_index]
    s = s0 + lane.speed * t
    if not lane.path.closed and lane.speed > 0:
        s = s % lane.path.length
    (x, y), h = lane.path.at(s)
    return float(x), float(y), float(h)


def vehicle_pose(layout: Layout, v: Vehicle, t: float) -> tuple[float, float, float]:
    if v.parked_pose is not None:
        return v.parked_pose
    return pose_at(layout, v.lane, v.s0, t)


def ego_pose(layout: Layout, recipe, t: float) -> tuple[float, float, float]:
    """(x, y, yaw) of the ego origin (rear axle) at time t."""
    lane = layout.lanes[layout.ego_lane]
    s = ego_s0(layout, recipe) + lane.speed * t
    (x, y), h = lane.path.at(s)
    return float(x), float(y), float(h)
