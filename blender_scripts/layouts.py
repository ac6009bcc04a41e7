"""Road layout families (pure numpy): static geometry, traffic lanes and the ego's lane.

World frame: x east, y north, z up; every family puts the ego's route through the origin.
Right-hand traffic: a lane runs along its path with the kerb on its right.
Heights (z of the top surface) keep coplanar surfaces apart: terrain 0, road 0.01, paint 0.02,
kerb and sidewalk 0.15.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from . import assets
from .meshes import MeshData, Path, arc_path, curved_path, line_path

Z_ROAD, Z_PAINT, Z_KERB = 0.01, 0.02, 0.15
FACADES = [(0.55, 0.5, 0.42), (0.45, 0.28, 0.2), (0.7, 0.68, 0.62), (0.35, 0.37, 0.4), (0.6, 0.52, 0.35),
           (0.25, 0.25, 0.27), (0.75, 0.72, 0.66)]
LINE_W = 0.15


@dataclass
class StaticObject:
    name: str
    mesh: MeshData
    location: tuple = (0.0, 0.0, 0.0)
    yaw: float = 0.0
    color: tuple | None = None  # object colour (facades)


@dataclass
class Lane:
    path: Path
    speed: float  # m/s; 0 = a queue waiting at the end of the path
    width: float


@dataclass
class Layout:
    objects: list[StaticObject] = field(default_factory=list)
    lanes: list[Lane] = field(default_factory=list)
    ego_lane: int = 0
    lamps: list[tuple] = field(default_factory=list)  # street-light bulbs: (x, y, z) or (x, y, z, watts)
    parked: list[tuple] = field(default_factory=list)  # (x, y, yaw, max_length) parking bays in use
    walks: list[tuple] = field(default_factory=list)  # (Path, offset a, offset b): pavements people walk on
    signals: list[tuple] = field(default_factory=list)  # (x, y, z, yaw): traffic lights at stop lines

    def add(self, name, mesh, location=(0.0, 0.0, 0.0), yaw=0.0, color=None):
        if len(mesh):
            self.objects.append(StaticObject(name, mesh, tuple(location), yaw, color))


@dataclass
class Edge:
    """A roadside: positions at lateral offset `offset` (signed, + left) along `path` in [s0, s1],
    with `out` = +1/-1 the direction away from the road."""
    path: Path
    offset: float
    out: int
    s0: float
    s1: float
    skip: list = field(default_factory=list)  # (s_a, s_b) intervals without roadside things


def _intervals(s0, s1, skip):
    """[s0, s1] minus the skip intervals."""
    out = [(s0, s1)]
    for a, b in skip:
        nxt = []
        for x, y in out:
            if b <= x or a >= y:
                nxt.append((x, y))
            else:
                if a > x:
                    nxt.append((x, a))
                if b < y:
                    nxt.append((b, y))
        out = nxt
    return [(x, y) for x, y in out if y - x > 0.5]


def _dashes(s0, s1, dash, gap, skip):
    out = []
    for a, b in _intervals(s0, s1, skip):
        s = a
        while s < b:
            out.append((s, min(s + dash, b)))
            s += dash + gap
    return out


def _paint_line(mesh, path, offset, intervals, mat="paint_white", width=LINE_W):
    for a, b in intervals:
        if b - a > 0.2:
            sub = Path(path.sub(a, b, step=2.0))
            mesh.ribbon(sub, offset + width / 2, offset - width / 2, Z_PAINT, mat)


class Road:
    """A two-way road along a path: cross-section, markings, lanes."""

    def __init__(self, path: Path, lanes: int, lane_w: float, median: str, shoulder: float):
        self.path, self.n, self.w = path, lanes, lane_w
        self.median = median
        self.m = {"none": 0.0, "double_solid": 0.2, "barrier": 0.5}[median]
        self.shoulder = shoulder
        self.half = self.m + lanes * lane_w + shoulder  # asphalt half width

    def lane_offset(self, i: int) -> float:
        """Offset (right of centre, negative) of forward lane i, 0 = rightmost."""
        return -(self.m + (self.n - i - 0.5) * self.w)

    def surface(self, layout: Layout, name: str, s0=None, s1=None, z=Z_ROAD):
        s0 = 0.0 if s0 is None else s0
        s1 = self.path.length if s1 is None else s1
        sub = Path(self.path.sub(s0, s1, 2.0), self.path.closed)
        layout.add(name, MeshData().ribbon(sub, self.half, -self.half, z, "asphalt"))

    def markings(self, layout: Layout, name: str, skip=(), dash=3.0, gap=6.0):
        mesh = MeshData()
        L = self.path.length
        solid = _intervals(0.0, L, skip)
        edge = self.m + self.n * self.w
        for side in (-1, 1):
            _paint_line(mesh, self.path, side * edge, solid)
            for k in range(1, self.n):
                _paint_line(mesh, self.path, side * (self.m + k * self.w), _dashes(0.0, L, dash, gap, skip))
        if self.median == "double_solid":
            for side in (-1, 1):
                _paint_line(mesh, self.path, side * 0.1, solid, "paint_yellow", 0.12)
        elif self.median == "none":
            _paint_line(mesh, self.path, 0.0, _dashes(0.0, L, dash, gap, skip))
        layout.add(name, mesh)
        if self.median == "barrier":
            bar = MeshData()
            for a, b in solid:
                bar.ribbon(Path(self.path.sub(a, b)), 0.3, -0.3, 0.9, "barrier_concrete", depth=0.9)
            layout.add(name + "_barrier", bar)

    def lanes(self, layout: Layout, speeds, s_end=None):
        """Add forward and backward lanes; speeds: one per lane (m/s). Returns forward indices."""
        fwd = []
        for i in range(self.n):
            fwd.append(len(layout.lanes))
            layout.lanes.append(Lane(self.path.offset(self.lane_offset(i)), speeds[i], self.w))
        for i in range(self.n):
            layout.lanes.append(Lane(self.path.offset(-self.lane_offset(i)).reversed(), speeds[self.n + i], self.w))
        return fwd

    def edges(self, extra: float = 0.0, skip=()):
        return [Edge(self.path, side * (self.half + extra), side, 0.0, self.path.length, list(skip))
                for side in (-1, 1)]


def _sidewalk(layout, name, path, s0, s1, inner, width, side):
    """Kerb (0.25 m) and sidewalk along path from s0 to s1, starting at |offset| inner on `side`."""
    sub = Path(path.sub(s0, s1))
    kerb, walk = MeshData(), MeshData()
    a, b = side * inner, side * (inner + 0.25)
    kerb.ribbon(sub, max(a, b), min(a, b), Z_KERB, "kerb", depth=Z_KERB)
    a, b = side * (inner + 0.25), side * (inner + width)
    walk.ribbon(sub, max(a, b), min(a, b), Z_KERB, "pavement", depth=Z_KERB)
    layout.add(name + "_kerb", kerb)
    layout.add(name + "_walk", walk)
    layout.walks.append((sub, a, b))


def _speeds(rng, n, speed_range, ego_speed, ego_lane):
    sp = list(rng.uniform(speed_range[0], speed_range[1], 2 * n) / 3.6)
    sp[ego_lane] = ego_speed / 3.6
    return sp


# the road plan's numbers (route length, junction positions and size, room for overpasses) are shared
# with the sampler, which must only draw what builds: dataset_tools.generation.recipe
from dataset_tools.generation.recipe import bridge_stations, junction_crossings, junction_zone, route_length  # noqa: E402


# ---------------------------------------------------------------- families


def highway(recipe, rng) -> tuple[Layout, list[Edge]]:
    lay, p = Layout(), recipe["layout"]
    path = curved_path(route_length(recipe), p["curvature"])
    road = Road(path, p["lanes_per_direction"], p["lane_width"], p["median"], p["shoulder"])
    road.surface(lay, "road")
    road.markings(lay, "markings", dash=3.0, gap=9.0)
    sp = _speeds(rng, road.n, recipe["traffic"]["speed_kmh"], recipe["ego"]["speed_kmh"], recipe["ego"]["lane"])
    lay.ego_lane = road.lanes(lay, sp)[recipe["ego"]["lane"]]
    sw = recipe["roadside"]["sidewalk_width"]
    skip = []
    for k in range(recipe["roadside"]["bridges"]):
        # the first overpass stands within the top-down view of the ego's first frame
        s = path.length / 2 + rng.uniform(-18, 18) if k == 0 else rng.uniform(0.2, 0.8) * path.length
        _overpass(lay, f"overpass{k}", path, s, road.half + sw, rng)
        skip.append((s - 8, s + 8))
    if sw > 0:
        for side in (-1, 1):
            _sidewalk(lay, f"side{side:+d}", path, 0, path.length, road.half, sw, side)
    return lay, road.edges(sw, skip)


def _overpass(lay, name, path, s, half, rng):
    """A bridge deck crossing the path at arc length s, pillars outside the road."""
    (x, y), h = path.at(s)
    span = 2 * half + 12.0
    clear = rng.uniform(5.2, 6.5)
    width = rng.uniform(7.0, 12.0)
    deck = MeshData().box((0, 0, clear), (width, span, 0.9), mat="bridge")
    deck.box((0, -span / 2 + 0.3, clear + 0.9), (width, 0.25, 1.0), mat="bridge")
    deck.box((0, span / 2 - 0.3, clear + 0.9), (width, 0.25, 1.0), mat="bridge")
    lay.add(name + "_deck", deck, (x, y, 0.0), h)
    pillars = MeshData()
    for side in (-1, 1):
        for dx in (-width / 3, width / 3):
            pillars.box((dx, side * (half + 2.5), 0), (0.9, 0.9, clear), mat="concrete")
    lay.add(name + "_pillars", pillars, (x, y, 0.0), h)


def _junction_arm(lay, name, origin, direction, start, length, n, w, rng, speed_range, z=Z_ROAD):
    """A road arm leaving `origin` along unit `direction` from distance `start`. Adds a queued
    incoming lane (waiting at the stop line), a crosswalk and a stop line."""
    o, d = np.asarray(origin, float), np.asarray(direction, float)
    path = line_path(o + d * start, o + d * (start + length), step=5.0)
    road = Road(path, n, w, "double_solid", 0.5)
    road.surface(lay, name, z=z)
    cw0, cw1 = 1.0, 4.0
    road.markings(lay, name + "_markings", skip=[(0.0, cw1 + 1.5)])
    zebra, stop = MeshData(), MeshData()
    edge = road.m + n * w
    for k in range(int(2 * edge / 1.0)):
        c = -edge + 0.5 + k * 1.0
        zebra.ribbon(Path(path.sub(cw0, cw1, 1.0)), c + 0.25, c - 0.25, Z_PAINT, "paint_crosswalk")
    # incoming lanes are on the arm's left (they drive toward the origin)
    stop.ribbon(Path(path.sub(cw1 + 0.6, cw1 + 1.0, 0.2)), edge, 0.0, Z_PAINT, "paint_stop")
    lay.add(name + "_crosswalk", zebra)
    lay.add(name + "_stopline", stop)
    incoming = path.offset(-road.lane_offset(0)).reversed()
    s_stop = incoming.length - (cw1 + 1.2)
    lay.lanes.append(Lane(Path(incoming.sub(0.0, s_stop, 2.0)), 0.0, w))
    # no traffic leaves along the arm: wrapping it around would pop cars up beside the junction
    return road


def junctions(recipe, rng, crossings, arms=(1, -1), buildings=False) -> tuple[Layout, list[Edge]]:
    """A straight main road along x with cross streets at x in `crossings` (intersection,
    T-junction, urban block)."""
    lay, p, rs = Layout(), recipe["layout"], recipe["roadside"]
    L = route_length(recipe)
    path = line_path((-L / 2, 0), (L / 2, 0), step=5.0)
    n, w = p["lanes_per_direction"], p["lane_width"]
    median = p["median"] if p["median"] != "barrier" else "double_solid"
    road = Road(path, n, w, median, 0.5)
    arm_half = 0.2 + n * w + 0.5
    sw = rs["sidewalk_width"]
    zone = junction_zone(recipe)  # half size of a junction along the main road
    skip = [(x + L / 2 - zone, x + L / 2 + zone) for x in crossings]
    road.surface(lay, "main_road")
    road.markings(lay, "main_markings", skip=skip, dash=3.0, gap=5.0)
    sp = _speeds(rng, n, recipe["traffic"]["speed_kmh"], recipe["ego"]["speed_kmh"], recipe["ego"]["lane"])
    lay.ego_lane = road.lanes(lay, sp)[recipe["ego"]["lane"]]
    edges = road.edges(sw, [(a - 2, b + 2) for a, b in skip])
    zebra, stop = MeshData(), MeshData()
    for j, x in enumerate(crossings):
        for side in arms:
            arm = _junction_arm(lay, f"arm{j}{'n' if side > 0 else 's'}", (x, 0), (0, side), road.half,
                                60.0, n, w, rng, recipe["traffic"]["speed_kmh"])
            if sw > 0:
                for s2 in (-1, 1):
                    _sidewalk(lay, f"arm{j}{side:+d}{s2:+d}", arm.path, sw, arm.path.length, arm.half, sw, s2)
            edges += [e for e in arm.edges(sw, [(0, sw + 2)])]
        # crosswalks and stop lines across the main road on both sides of the junction
        edge = road.m + n * w
        for sgn in (-1, 1):
            xa = x + sgn * (arm_half + 1.0)
            xb = x + sgn * (arm_half + 4.0)
            for k in range(int(2 * edge)):
                c = -edge + 0.5 + k
                zebra.rect(min(xa, xb), max(xa, xb), c - 0.25, c + 0.25, Z_PAINT, "paint_crosswalk")
            xs = x + sgn * (arm_half + 4.6)
            # incoming lanes: y < 0 for traffic heading +x (coming from -x), y > 0 from +x
            y0, y1 = (-edge, 0.0) if sgn < 0 else (0.0, edge)
            stop.rect(xs - 0.2, xs + 0.2, y0, y1, Z_PAINT, "paint_stop")
            # a traffic light at the kerb on the incoming traffic's right, facing it
            lay.signals.append((xs, sgn * (road.half + 0.6), Z_KERB if sw > 0 else 0.0, sgn * math.pi / 2))
        if sw > 0:
            walk = MeshData()
            for sx in (-1, 1):
                for sy in arms if len(arms) == 2 else (-1, 1):
                    if sy not in arms:
                        continue
                    xa, xb = x + sx * arm_half, x + sx * (arm_half + sw)
                    ya, yb = sy * road.half, sy * (road.half + sw)
                    walk.rect(min(xa, xb), max(xa, xb), min(ya, yb), max(ya, yb), Z_KERB, "pavement")
            lay.add(f"corner{j}", walk)
    lay.add("main_crosswalks", zebra)
    lay.add("main_stoplines", stop)
    if sw > 0:
        for side in (-1, 1):
            gaps = skip if side in arms else []
            inner_skip = [(a + zone - arm_half - sw, b - zone + arm_half + sw) for a, b in gaps]
            for k, (a, b) in enumerate(_intervals(0, L, inner_skip)):
                _sidewalk(lay, f"main{side:+d}_{k}", path, a, b, road.half, sw, side)
    bridges = recipe["roadside"]["bridges"]
    for k in range(bridges):
        cands = bridge_stations(recipe)
        if not cands:
            raise ValueError(f"roadside.bridges: {bridges}, but no overpass fits between the junctions of this "
                             f"{recipe['family']} (block_length {recipe['layout'].get('block_length')} m)")
        s = cands[int(rng.integers(len(cands)))] if k else min(cands, key=lambda s: abs(s - L / 2 - 12))
        _overpass(lay, f"overpass{k}", path, s, road.half + sw, rng)
        for e in edges:
            if e.path is path:
                e.skip.append((s - 8, s + 8))
    return lay, edges


def roundabout(recipe, rng) -> tuple[Layout, list[Edge]]:
    lay, p, rs = Layout(), recipe["layout"], recipe["roadside"]
    R, w = p["ring_radius"], p["lane_width"]
    ring_w = 2 * w
    ring = arc_path((0, 0), R, 0, 2 * math.pi, step=1.5, closed=True)
    r_in, r_out = R - ring_w / 2, R + ring_w / 2
    lay.add("ring", MeshData().ribbon(ring, ring_w / 2, -ring_w / 2, Z_ROAD, "asphalt"))
    paint = MeshData()
    paint.ribbon(ring, ring_w / 2 - 0.2, ring_w / 2 - 0.35, Z_PAINT, "paint_white")
    paint.ribbon(ring, -ring_w / 2 + 0.35, -ring_w / 2 + 0.2, Z_PAINT, "paint_white")
    lay.add("ring_markings", paint)
    island = MeshData().disc((0, 0), r_in - 0.25, Z_KERB, n=48, mat="grass")
    island.ribbon(arc_path((0, 0), r_in - 0.125, 0, 2 * math.pi, 1.5, True), 0.125, -0.125, Z_KERB, "kerb", depth=Z_KERB)
    lay.add("island", island)
    n = p["lanes_per_direction"]
    edges = []
    for k, ang in enumerate((0, math.pi / 2, math.pi, 3 * math.pi / 2)):
        d = (math.cos(ang), math.sin(ang))
        # the arm overlaps the ring's edge: lift it 4 mm so the two never z-fight
        arm = _junction_arm(lay, f"arm{k}", (0, 0), d, r_out - 1.0, 120.0, n, w, rng,
                            recipe["traffic"]["speed_kmh"], z=Z_ROAD + 0.004)
        edges += arm.edges(rs["sidewalk_width"], [(0, 3)])
    # the ego and the ring traffic circle counter-clockwise (right-hand traffic) at one speed
    lay.lanes.append(Lane(arc_path((0, 0), R - w / 2 + 0.3, 0, 2 * math.pi, 1.0, True),
                          recipe["ego"]["speed_kmh"] / 3.6, w))
    lay.ego_lane = len(lay.lanes) - 1
    # island trees: canopies stay over the island
    for k in range(int(rng.integers(1, 4))):
        a, r = rng.uniform(0, 2 * math.pi), rng.uniform(0, max(0.1, r_in - 5))
        trunk, canopy = assets.tree_meshes(rng, overhang=False)
        loc = (r * math.cos(a), r * math.sin(a), Z_KERB)
        lay.add(f"island_tree{k}_trunk", trunk, loc)
        lay.add(f"island_tree{k}_canopy", canopy, loc)
    return lay, edges


def parking_lot(recipe, rng) -> tuple[Layout, list[Edge]]:
    lay, p = Layout(), recipe["layout"]
    rows, per_row = p["bay_rows"], p["bays_per_row"]
    bay_w, bay_d, aisle = 2.6, 5.0, 7.0
    L = max(per_row * bay_w + 20.0, 60.0)
    # rows alternate along y: aisle 0 at y=0, bays on both sides, then the next aisle, ...
    half_y = aisle / 2 + rows * bay_d + (rows - 1) // 2 * aisle + 3.0
    lot = MeshData().rect(-L / 2, L / 2, -half_y, half_y, Z_ROAD, "asphalt_lot")
    lay.add("lot", lot)
    lines = MeshData()
    x0 = -per_row * bay_w / 2
    row_y = []
    for side in (-1, 1):
        y = aisle / 2
        for r in range(rows):
            row_y.append((side, y))
            y += bay_d + (aisle if r % 2 == 1 else 0.0)
    for side, y in row_y:
        ya, yb = side * y, side * (y + bay_d)
        for b in range(per_row + 1):
            xb = x0 + b * bay_w
            lines.rect(xb - 0.06, xb + 0.06, min(ya, yb), max(ya, yb), Z_PAINT, "paint_white")
        for b in range(per_row):
            if rng.random() < p["occupancy"]:
                cx = x0 + (b + 0.5) * bay_w
                cy = side * (y + bay_d / 2)
                yaw = -side * math.pi / 2 if rng.random() < 0.7 else side * math.pi / 2
                lay.parked.append((cx, cy, yaw, bay_d - 0.3, bay_w - 0.4))
    lay.add("bay_lines", lines)
    _lot_lights(lay, row_y, x0, bay_d, L, half_y)
    # the ego drives the middle aisle; one more car may follow the aisle ahead at its speed
    path = line_path((-L / 2 - 150, -1.5), (L / 2 + 150, -1.5), step=5.0)
    lay.lanes.append(Lane(path, recipe["ego"]["speed_kmh"] / 3.6, 3.0))
    lay.ego_lane = 0
    access = Road(line_path((-L / 2 - 150, 0), (-L / 2, 0)), 1, 3.5, "none", 0.3)
    access.surface(lay, "access_w")
    access2 = Road(line_path((L / 2, 0), (L / 2 + 150, 0)), 1, 3.5, "none", 0.3)
    access2.surface(lay, "access_e")
    edges = [Edge(line_path((-L / 2, s * half_y), (L / 2, s * half_y)), 0.0, s, 0.0, L) for s in (-1, 1)]
    edges += access.edges() + access2.edges()
    return lay, edges


LOT_LAMP_W = 1500.0  # a lot's lamps stand closer together than a street's (4500 W): each dimmer


def _lot_lights(lay: Layout, row_y, x0: float, bay_d: float, length: float, half_y: float, spacing: float = 25.0,
                bay_w: float = 2.6, every: int = 8):
    """Lamp posts of a parking lot (lots are lit at night): on the back line of every row of bays
    at every `every`-th bay line (in the corner between bays, clear of the cars in them; back-to-back
    rows share one line), at both ends of every row, in line with it (clear of the aisles the ego
    drives), and along both long sides, `spacing` apart. Placed without drawing, so the layout's
    stream is unchanged."""
    spots = [(sx * (abs(x0) + 2.0), side * (y + bay_d / 2), sx * math.pi / 2) for side, y in row_y for sx in (-1, 1)]
    per_row = int(round(2 * abs(x0) / bay_w))
    lines = sorted({round(side * (y + bay_d), 3) for side, y in row_y})
    spots += [(x0 + b * bay_w, yl, 0.0) for yl in lines for b in range(every // 2, per_row, every)]
    n = max(1, int(length // spacing))
    spots += [((k + 0.5) * length / n - length / 2, s * (half_y + 0.8), math.pi if s > 0 else 0.0)
              for s in (-1, 1) for k in range(n)]  # arms toward the lot
    for k, (x, y, yaw) in enumerate(spots):
        mesh, bulb = assets.street_light_mesh(8.0, 0.4)
        lay.add(f"lot_light{k}", mesh, (x, y, 0.0), yaw)
        c, s = math.cos(yaw), math.sin(yaw)
        lay.lamps.append((x + c * bulb[0] - s * bulb[1], y + s * bulb[0] + c * bulb[1], bulb[2], LOT_LAMP_W))


# ---------------------------------------------------------------- roadside


def _beside(path: Path, s: float, off: float) -> tuple[float, float, float]:
    """(x, y, heading) of the point `off` metres left of `path` at arc length s (right when < 0)."""
    (x, y), h = path.at(s)
    return x - math.sin(h) * off, y + math.cos(h) * off, h


def furnish(lay: Layout, edges: list[Edge], recipe, rng) -> None:
    """Trees (some overhanging the road), street lights and buildings along the edges."""
    rs = recipe["roadside"]
    n_tree = n_light = n_bld = 0
    for e in edges:
        spans = _intervals(e.s0, e.s1, e.skip)
        total = sum(b - a for a, b in spans)
        if total <= 0:
            continue

        def where(s, off):
            return _beside(e.path, s, e.offset + e.out * off)

        def pick():
            u = rng.uniform(0, total)
            for a, b in spans:
                if u <= b - a:
                    return a + u
                u -= b - a
            return spans[-1][1]

        # buildings first: they take slots along the edge
        taken = []
        if rs["buildings"] > 0:
            s = spans[0][0]
            while s < e.s1:
                length = rng.uniform(10, 25)
                mid = s + length / 2
                if rng.random() < rs["buildings"] and all(a <= s and s + length <= b for a, b in [
                        sp for sp in spans if sp[0] <= mid <= sp[1]]) and any(a <= mid <= b for a, b in spans):
                    depth = rng.uniform(10, 18)
                    height = rng.uniform(*rs["building_height"])
                    x, y, h = where(mid, 1.5 + depth / 2)
                    facade = FACADES[int(rng.integers(len(FACADES)))]
                    lay.add(f"building{n_bld}", assets.building_mesh(rng, length, depth, height), (x, y, 0), h,
                            tuple(float(c) for c in np.clip(np.array(facade) * rng.uniform(0.8, 1.15), 0, 1)))
                    n_bld += 1
                    taken.append((s, s + length))
                s += length + rng.uniform(1, 6)
        for _ in range(int(rng.poisson(rs["trees"] * total / 10))):
            overhang = rng.random() < rs["overhanging"]
            s = pick()
            # an overhanging tree's trunk stands on the sidewalk (or just off the asphalt)
            lo = -0.6 if rs["sidewalk_width"] > 0 else 0.3
            off = rng.uniform(lo, lo + 1.4) if overhang else rng.uniform(2.0, 8.0)
            if not overhang and any(a - 4 < s < b + 4 for a, b in taken):
                continue
            x, y, h = where(s, off)
            trunk, canopy = assets.tree_meshes(rng, overhang)
            yaw = h + (math.pi / 2 if e.out < 0 else -math.pi / 2)  # crown leans toward the road
            z = Z_KERB if off < 0 and rs["sidewalk_width"] > 0 else 0.0
            lay.add(f"tree{n_tree}_trunk", trunk, (x, y, z), yaw)
            lay.add(f"tree{n_tree}_canopy", canopy, (x, y, z), yaw)
            n_tree += 1
        for _ in range(int(rng.poisson(rs["street_lights"] * total / 10))):
            s = pick()
            x, y, h = where(s, -0.4 if rs["sidewalk_width"] > 0 else 0.8)
            height = rng.uniform(7.0, 9.0)
            mesh, bulb = assets.street_light_mesh(height, 1.8)
            yaw = h + (math.pi / 2 if e.out < 0 else -math.pi / 2)
            lay.add(f"light{n_light}", mesh, (x, y, 0.0), yaw)
            c, sn = math.cos(yaw), math.sin(yaw)
            lay.lamps.append((x + c * bulb[0] - sn * bulb[1], y + sn * bulb[0] + c * bulb[1], bulb[2]))
            n_light += 1
    # a stream of its own, drawn after everything above, so the furniture leaves the rest as it was
    street_furniture(lay, edges, recipe, np.random.default_rng(rng.integers(2**63)))


SIGN_COLOURS = [(0.75, 0.05, 0.04), (0.05, 0.2, 0.6), (0.8, 0.8, 0.78), (0.85, 0.65, 0.05), (0.05, 0.4, 0.15)]


def street_furniture(lay: Layout, edges: list, recipe, rng) -> None:
    """Road signs along every edge (about one per 60 m) and bollards on sidewalks (one per 40 m),
    then traffic lights at the junctions' stop lines, guard rails, hedges and bushes, benches and bins."""
    sw = recipe["roadside"]["sidewalk_width"]
    n_sign = n_bollard = 0
    for e in edges:
        spans = _intervals(e.s0, e.s1, e.skip)
        total = sum(b - a for a, b in spans)
        if total <= 0:
            continue
        for count, kind in ((rng.poisson(total / 60), "sign"), (rng.poisson(total / 40) if sw > 0 else 0, "bollard")):
            for _ in range(int(count)):
                u = rng.uniform(0, total)
                s = spans[-1][1]
                for a, b in spans:
                    if u <= b - a:
                        s = a + u
                        break
                    u -= b - a
                x, y, h = _beside(e.path, s, e.offset + e.out * ((-0.3 if kind == "sign" else -0.25) if sw > 0 else 1.2))
                z = Z_KERB if sw > 0 else 0.0
                yaw = h + math.pi / 2  # plates face along the road
                if kind == "sign":
                    colour = SIGN_COLOURS[int(rng.integers(len(SIGN_COLOURS)))]
                    lay.add(f"sign{n_sign}", assets.sign_mesh(rng), (x, y, z), yaw, colour)
                    n_sign += 1
                else:
                    lay.add(f"bollard{n_bollard}", assets.bollard_mesh(), (x, y, z), yaw)
                    n_bollard += 1
    # drawn after the signs and bollards, so those stay where they were
    for k, (x, y, z, yaw) in enumerate(lay.signals):
        lay.add(f"traffic_light{k}", assets.traffic_light_mesh(int(rng.integers(3))), (x, y, z), yaw)
    _roadside_green_and_rails(lay, edges, recipe, rng)
    _pavement_furniture(lay, rng)


GUARD_RAIL_P = 0.7  # chance that a highway roadside has a guard rail


def _roadside_green_and_rails(lay: Layout, edges: list, recipe, rng) -> None:
    """Guard rails along highway roadsides (a steel beam on posts, class barrier); hedges (about one
    per 40 m, 4-12 m long) and bushes (one per 25 m) just beyond the other roadsides."""
    highway = recipe["family"] == "highway"
    n_hedge = n_bush = 0
    for k, e in enumerate(edges):
        for a, b in _intervals(e.s0, e.s1, e.skip):
            if b - a < 4:
                continue
            if highway:
                if rng.random() < GUARD_RAIL_P:
                    off = e.offset + e.out * 0.7
                    rail = MeshData().ribbon(Path(e.path.sub(a, b)), off + 0.05, off - 0.05, 0.8, "guardrail", depth=0.32)
                    for s in np.arange(a + 1.0, b, 4.0):
                        x, y, h = _beside(e.path, s, off)
                        rail.box((x, y, 0.0), (0.1, 0.08, 0.75), h, "guardrail")
                    lay.add(f"guard_rail{k}_{int(a)}", rail)
                continue
            for _ in range(int(rng.poisson((b - a) / 40))):
                length = rng.uniform(4.0, 12.0)
                s = rng.uniform(a, max(a, b - length)) + length / 2
                x, y, h = _beside(e.path, s, e.offset + e.out * rng.uniform(0.6, 1.2))
                mesh = assets.hedge_mesh(rng, length, rng.uniform(0.7, 1.4), rng.uniform(0.6, 1.0))
                lay.add(f"hedge{n_hedge}", mesh, (x, y, 0.0), h)
                n_hedge += 1
            for _ in range(int(rng.poisson((b - a) / 25))):
                x, y, _ = _beside(e.path, rng.uniform(a, b), e.offset + e.out * rng.uniform(0.8, 3.0))
                lay.add(f"bush{n_bush}", assets.bush_mesh(rng), (x, y, 0.0), float(rng.uniform(0, 2 * math.pi)))
                n_bush += 1


def _pavement_furniture(lay: Layout, rng) -> None:
    """Benches (one per 100 m) and litter bins (one per 60 m) on the pavements, at their outer edge
    (the side away from the road), benches facing the road."""
    n = 0
    for path, a, b in lay.walks:
        side = 1.0 if b > a else -1.0
        for kind, per_m, inset in (("bench", 100.0, 0.45), ("bin", 60.0, 0.35)):
            for s in rng.uniform(0, path.length, int(rng.poisson(path.length / per_m))):
                x, y, h = _beside(path, float(s), b - side * inset)
                yaw = h + (0.0 if side > 0 else math.pi)  # a bench's seat faces local -y: toward the road
                mesh = assets.bench_mesh() if kind == "bench" else assets.bin_mesh()
                lay.add(f"{kind}{n}", mesh, (x, y, Z_KERB), yaw)
                n += 1


def terrain(lay: Layout, size: float = 600.0) -> None:
    lay.add("terrain", MeshData().rect(-size / 2, size / 2, -size / 2, size / 2, 0.0, "grass"))


def build_layout(recipe, rng: np.random.Generator) -> Layout:
    fam, p = recipe["family"], recipe["layout"]
    if fam == "highway":
        lay, edges = highway(recipe, rng)
    elif fam in ("intersection", "urban_block"):
        lay, edges = junctions(recipe, rng, junction_crossings(recipe))
    elif fam == "t_junction":
        lay, edges = junctions(recipe, rng, junction_crossings(recipe), arms=(1,))
    elif fam == "roundabout":
        lay, edges = roundabout(recipe, rng)
    elif fam == "parking_lot":
        lay, edges = parking_lot(recipe, rng)
    else:
        raise ValueError(f"unknown family {fam!r}")
    furnish(lay, edges, recipe, rng)
    terrain(lay)
    return lay
