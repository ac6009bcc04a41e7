"""Procedural vehicles as MeshData (pure numpy): lofted bodies with wheel arches, a glasshouse with
pillars, tyres with sidewalls, spoked rims, lamps, grille, plates, mirrors, door seams and a dark
interior behind the glass.

A body is a loft: one ring of 16 points per station along the length, the ring's shape set by
per-style profiles of the station's position u (0 at the rear, 1 at the front): the bottom (raised
over each wheel into an arch), the beltline (bonnet, boot deck and door tops), the top of the
glasshouse and the body's half-width. The material of every face follows from where it is: side
glass between the pillars, sloped glass where the roof line falls steeply (windscreen, rear window:
across the roof, between the corner pillars, under a rail at the roof's edge), paint elsewhere, a
dark liner under the arches. Everything stays inside the vehicle's (length, width, height) box, in
its own frame: x forward, y left, origin on the ground at the box centre.
"""

from __future__ import annotations

import math

import numpy as np

from .meshes import MeshData

# body styles: profiles as (u, fraction of the height) points, interpolated linearly.
# belt: top of the lower body; roof: top of the glasshouse (below belt = no glasshouse there);
# glass: (u0, u1) of the side windows; pillars: u of the pillars inside that range; bed: (u0, u1) of
# an open load bed (pickup); cladding: dark plastic on the lower sides (SUVs). The rear: corner_lamps,
# tail light clusters at the top corners under the rear window (estates, SUVs, pickups); high_stop, a
# tailgate with the high-mounted stop lamp inside the top of its glass; lid, a boot lid or tailgate
# whose edge runs under the lamps (sedan, pickup)
STYLES = {
    "sedan": dict(belt=[(0, .50), (.05, .60), (.25, .62), (.72, .60), (.93, .52), (1, .44)],
                  roof=[(.18, .55), (.34, 1.0), (.60, 1.0), (.76, .55)], glass=(.27, .70), pillars=(.47,),
                  lid=True),
    "hatchback": dict(belt=[(0, .52), (.05, .60), (.70, .60), (.92, .52), (1, .45)],
                      roof=[(0, .62), (.03, .86), (.12, 1.0), (.58, 1.0), (.74, .55)], glass=(.10, .68),
                      pillars=(.40,), high_stop=True),
    "wagon": dict(belt=[(0, .52), (.04, .60), (.72, .60), (.93, .52), (1, .45)],
                  roof=[(0, .62), (.025, .93), (.07, 1.0), (.60, 1.0), (.76, .55)], glass=(.06, .70),
                  pillars=(.22, .45), corner_lamps=True, high_stop=True),
    "suv": dict(belt=[(0, .52), (.04, .60), (.74, .60), (.94, .55), (1, .48)],
                roof=[(0, .62), (.025, .94), (.07, 1.0), (.63, 1.0), (.78, .58)], glass=(.06, .72),
                pillars=(.24, .48), cladding=True, corner_lamps=True, high_stop=True),
    "pickup": dict(belt=[(0, .56), (.04, .60), (.74, .60), (.94, .55), (1, .48)],
                   roof=[(.40, .55), (.43, 1.0), (.66, 1.0), (.78, .58)], glass=(.45, .74), pillars=(.58,),
                   bed=(.02, .40), cladding=True, corner_lamps=True, lid=True),
    "van": dict(belt=[(0, .45), (.03, .47), (.80, .47), (.95, .42), (1, .36)],
                roof=[(0, .52), (.02, 1.0), (.72, 1.0), (.86, .50)], glass=(.66, .80), pillars=(),
                panel_seams=(.30, .58)),
    # a van with windows all along (a minibus, a crew or passenger van): pillars between the panes
    "minibus": dict(belt=[(0, .45), (.03, .47), (.80, .47), (.95, .42), (1, .36)],
                    roof=[(0, .52), (.02, 1.0), (.72, 1.0), (.86, .50)], glass=(.04, .80),
                    pillars=(.24, .45, .64), panel_seams=(.45, .64)),
    # a city bus: its rear window over the engine bay, in the top third of its rear
    "bus": dict(belt=[(0, .36), (.01, .38), (.99, .38), (1, .33)],
                roof=[(0, .62), (.012, .97), (.983, .97), (1, .40)], glass=(.02, .97), pillars="every 1.5 m"),
    "truck_cab": dict(belt=[(0, .40), (.05, .45), (.90, .45), (1, .36)],
                      roof=[(0, .97), (.88, .97), (1, .40)], glass=(.55, .88), pillars=()),
}
KIND_STYLES = {"car": ("sedan", "hatchback", "wagon"), "suv": ("suv", "pickup"), "van": ("van", "minibus"),
               "truck": ("truck_cab",), "bus": ("bus",)}
BOXY = ("bus", "truck_cab", "van", "minibus")  # upright sides and a flat front
BELT = {name: max(v for _, v in s["belt"]) for name, s in STYLES.items()}  # highest beltline (ego cabin cut)

HEADER = 0.05  # m: the body-coloured rail across the roof's edge above a windscreen or rear window
SMOOTH_ANGLE = 35.0  # degrees: edges sharper than this stay sharp, the rest is shaded smooth
RING = 16  # points per station
SIDE = 8  # per side: inner bottom, arch edge, rocker, door, shoulder, belt, glass top, roof edge


def _stations(length, axles, arch_r, extra=()):
    """Station positions u: evenly spaced, denser over the arches, plus the profiles' breakpoints."""
    u = list(np.linspace(0, 1, 36)) + list(extra)
    for ax in axles:
        a = np.linspace(-1, 1, 11)
        u += list((ax + arch_r * a * 1.02) / length + 0.5)
    u = np.clip(np.array(sorted(u)), 0, 1)
    keep = [u[0]]
    for v in u[1:]:
        if v - keep[-1] > 0.004:
            keep.append(v)
    keep[-1] = 1.0
    return np.array(keep)


def _rings(style, u, size, clear, axles, arch_r, wheel_r):
    """(S, 16, 3) ring points and per-station (belt z, top z, half-width)."""
    s = STYLES[style]
    l, w, h = size
    x = (u - 0.5) * (l - 0.04)  # 2 cm inside the box at each end: lamps and plates sit there
    belt = np.interp(u, *zip(*s["belt"])) * h
    rx, rz = zip(*s["roof"])
    roof = np.interp(u, rx, rz, left=0.0, right=0.0) * h
    top = np.maximum(belt, roof)
    g = top - belt
    hw = w / 2 * np.interp(u, [0, .03, .1, .9, .97, 1], [.86, .95, 1, 1, .95, .88])
    if style in BOXY:
        hw = w / 2 * np.interp(u, [0, .01, .99, 1], [.94, 1, 1, .94])
    rw = hw * (0.80 if style not in BOXY else 0.93)
    zb = np.full_like(u, clear)
    zb = np.where(u < 0.05, clear + (0.05 - u) / 0.05 * 0.12, zb)
    zb = np.where(u > 0.95, clear + (u - 0.95) / 0.05 * 0.10, zb)
    arch = np.zeros_like(u)
    for ax in axles:
        d = np.clip(1 - ((x - ax) / arch_r) ** 2, 0, None)
        arch = np.maximum(arch, wheel_r + arch_r * np.sqrt(d) * (d > 0))
    z_arch = np.maximum(zb, arch)
    t = np.clip(g / 0.25, 0, 1)
    inner = np.maximum(hw - 0.32, 0.2)
    side = np.stack([
        np.stack([-inner, zb], 1),  # inner bottom (stays down under the arch: the liner)
        np.stack([-0.95 * hw, z_arch], 1),  # outer bottom edge, following the arch
        # the side curves: the lower door tucks in, the shoulder rolls over to the beltline (so it
        # reflects the ground below and the sky above, as car sides do)
        np.stack([-0.985 * hw, z_arch + 0.3 * (belt - z_arch)], 1),  # rocker / lower door
        np.stack([-hw, z_arch + 0.7 * (belt - z_arch)], 1),  # door / shoulder
        np.stack([-0.95 * hw, belt], 1),  # beltline
        np.stack([-(0.95 * hw - 0.02 * t), belt + 0.03 * t + 0.01 * (1 - t)], 1),  # glass bottom
        np.stack([-(0.85 * hw * (1 - t) + rw * t), belt + (g - 0.06) * t + 0.02 * (1 - t)], 1),  # glass top
        np.stack([-(0.55 * hw * (1 - t) + 0.86 * rw * t), top + 0.03 * (1 - t)], 1),  # roof edge
    ], 1)  # (S, 8, 2): y, z of the right side (y < 0)
    left = side[:, ::-1] * np.array([-1, 1])
    yz = np.concatenate([side, left], 1)  # (S, 16, 2), a closed ring
    pts = np.concatenate([np.repeat(x[:, None, None], RING, 1), yz], 2)
    return pts, belt, top, hw


def _face_materials(style, u, x, belt, top, length):
    """(S-1, 16) material names of the loft's quads (band j joins ring points j and j+1)."""
    s = STYLES[style]
    S = len(u)
    um = (u[:-1] + u[1:]) / 2
    xm = (x[:-1] + x[1:]) / 2
    g = np.minimum(top - belt, np.roll(top - belt, -1))[:-1]
    g_max = np.maximum(top - belt, np.roll(top - belt, -1))[:-1]
    slope = np.abs(np.diff(top)) / np.maximum(np.diff(x), 1e-6)
    sloped = (slope > 0.35) & (g > 0.12)
    cabin = g > 0.15
    g0, g1 = s["glass"]
    pill = s["pillars"]
    if isinstance(pill, str):  # evenly spaced (bus)
        n = max(1, int(length * (g1 - g0) / 1.5))
        pill = tuple(np.linspace(g0, g1, n + 1)[1:-1])
    at_pillar = np.zeros(S - 1, bool)
    for p in pill:
        at_pillar |= np.abs(xm - (p - 0.5) * length) < 0.05
    side_glass = cabin & ~sloped & (um > g0) & (um < g1) & ~at_pillar
    mats = np.full((S - 1, RING), "car_paint", dtype=object)
    for j in (0, 14):  # arch liners / underbody edge
        mats[:, j] = "trim"
    mats[:, 15] = "trim"  # underbody
    if s.get("cladding"):
        mats[:, 1] = mats[:, 13] = "trim"
    for j in (5, 9):  # side windows
        mats[side_glass, j] = "car_glass"
        frame = cabin & ~side_glass & ~sloped & ~at_pillar & (um > g0 - 0.03) & (um < g1 + 0.03)
        mats[frame, j] = "trim"  # window frames
    # windscreen and rear window across the roof (band 7); the corner bands from the glass top to the
    # roof edge beside them stay paint: the A- and C-pillars that frame the glass; and the top
    # HEADER of the slope too: the roof's rail, under which real windscreens and rear windows stop
    header = np.minimum(top[:-1], top[1:]) >= top.max() - HEADER - 1e-6
    mats[sloped & ~header, 7] = "car_glass"
    if "bed" in s:
        b0, b1 = s["bed"]
        bed = (um > b0) & (um < b1)
        back = (um > b1) & (um < b1 + 0.04) & (slope > 0.35) & (g_max > 0.12)  # the cab's back wall: its window
        for j in (6, 7, 8):
            mats[bed, j] = "trim"
        mats[back, 7] = "car_glass"  # between pillars, as the windscreen
    return mats


def _loft(m: MeshData, pts, mats, cap_mat="car_paint"):
    S = len(pts)
    verts = pts.reshape(-1, 3)
    faces, fm = [], []
    for i in range(S - 1):
        for j in range(RING):
            a, b = i * RING + j, i * RING + (j + 1) % RING
            faces.append((a, a + RING, b + RING, b))  # outward: Cycles' Fresnel of a back face is total reflection
            fm.append(mats[i, j])
    groups: dict = {}
    for f, mat in zip(faces, fm):
        groups.setdefault(mat, []).append(f)
    # one vertex block shared by every material: add it once, faces by material
    m.add(verts, groups.pop("car_paint", []), "car_paint")
    off = m._n - len(verts)
    for mat, fs in groups.items():
        m.add(np.zeros((0, 3)), [tuple(off + i - m._n for i in f) for f in fs], mat)
    m.add(np.zeros((0, 3)), [tuple(off + i - m._n for i in range(RING))], cap_mat)  # rear cap
    m.add(np.zeros((0, 3)), [tuple(off + (S - 1) * RING + i - m._n for i in range(RING - 1, -1, -1))], cap_mat)  # front cap


def wheel(m: MeshData, x, y_outer, r, width, n=20, spokes=5, side=1):
    """Tyre (sidewalls, rounded shoulders, tread) and a spoked rim, axle along y; the tyre's outer
    face at y_outer (side: +1 left, -1 right)."""
    rr = 0.64 * r  # rim radius
    # tyre cross-section (radius, y from the outer face inward)
    prof = [(rr, 0.0), (0.86 * r, -0.012), (0.97 * r, 0.0), (r, 0.03), (r, width - 0.03), (0.97 * r, width),
            (0.86 * r, width + 0.012), (rr, width)]
    a = np.linspace(0, 2 * math.pi, n, endpoint=False)
    ca, sa = np.cos(a), np.sin(a)
    v = []
    for rad, dy in prof:
        v.append(np.column_stack([x + rad * ca, np.full(n, y_outer - side * dy), r + rad * sa]))
    v = np.vstack(v)
    P = len(prof)
    faces = [(k * n + i, k * n + (i + 1) % n, (k + 1) * n + (i + 1) % n, (k + 1) * n + i)
             for k in range(P - 1) for i in range(n)]
    # every face outward (Cycles' Fresnel of a back face is total reflection): the profile runs
    # the other way round on the right side, the rim's discs face -y unless turned
    m.add(v, faces if side > 0 else [f[::-1] for f in faces], "tyre")
    out = (lambda fs: [f[::-1] for f in fs]) if side > 0 else (lambda fs: fs)
    # rim: a lip ring, a dark recessed well, spokes from a hub to the lip
    y_rim = y_outer - side * 0.015
    lip = np.column_stack([x + rr * ca, np.full(n, y_outer), r + rr * sa])
    lip_in = np.column_stack([x + 0.88 * rr * ca, np.full(n, y_rim), r + 0.88 * rr * sa])
    m.add(np.vstack([lip, lip_in]), out([(i, (i + 1) % n, n + (i + 1) % n, n + i) for i in range(n)]), "rim")
    well = np.column_stack([x + 0.88 * rr * ca, np.full(n, y_outer - side * 0.07), r + 0.88 * rr * sa])
    m.add(well, out([tuple(range(n))]), "trim")
    hub = np.column_stack([x + 0.2 * rr * ca[::2], np.full(n // 2, y_rim), r + 0.2 * rr * sa[::2]])
    m.add(hub, out([tuple(range(n // 2))]), "rim")
    for k in range(spokes):
        t = 2 * math.pi * k / spokes + 0.3
        c, s_ = math.cos(t), math.sin(t)
        half = 0.07 * rr
        p = [(0.18 * rr, -half), (0.9 * rr, -half * 1.5), (0.9 * rr, half * 1.5), (0.18 * rr, half)]
        q = [(x + d * c - o * s_, y_rim + side * 0.002, r + d * s_ + o * c) for d, o in p]
        m.add(q, out([(0, 1, 2, 3)]), "rim")


def _box_at(m, x0, x1, y0, y1, z0, z1, mat):
    m.box(((x0 + x1) / 2, (y0 + y1) / 2, z0), (x1 - x0, y1 - y0, z1 - z0), mat=mat)


def rear_lamps(m: MeshData, xr, hw, belt, clear, low=False, tall=False, corner=False, ceiling=None):
    """Tail lights, a dark lower bumper and a plate on a rear face at x = xr: wide clusters under
    the boot lid, tall ones up the pillars (`tall`: vans), clusters at the top corners under the
    rear window (`corner`: SUVs, pickups, estates), low ones on a truck's box (`low`); never above
    `ceiling`, the rear face's top. -> the clusters' (bottom, top) z and inner edge (fraction of hw)."""
    if low:
        z = (clear + 0.35, clear + 0.55)
    elif tall:
        z = (belt - 0.45, belt + 0.1)
    elif corner:
        z = (belt - 0.22, belt + 0.12)
    else:
        z = (belt - 0.2, belt - 0.03)
    if ceiling is not None:
        z = (z[0], min(z[1], ceiling - 0.04))
    inner = 0.72 if tall else 0.62 if corner else 0.55
    for sd in (-1, 1):
        y0, y1 = sorted((sd * 0.95 * hw, sd * inner * hw))
        _box_at(m, xr, xr + 0.035, y0, y1, *z, "taillight")
        # the reversing lamp beside it: a clear lens over chrome (a red lamp on a red car reads as paint)
        y0, y1 = sorted((sd * (inner - 0.1) * hw, sd * inner * hw))
        _box_at(m, xr, xr + 0.03, y0, y1, z[0], z[0] + 0.4 * (z[1] - z[0]), "reverse_lamp")
    _box_at(m, xr + 0.004, xr + 0.12, -0.9 * hw, 0.9 * hw, clear + 0.02, clear + 0.16, "trim")
    _box_at(m, xr, xr + 0.025, -0.26, 0.26, clear + 0.2, clear + 0.31, "plate")
    return z, inner


def _half_width(ring, z):
    """The body's half-width at height z on one station's ring (its right side, arch edge to roof edge)."""
    return float(np.interp(z, ring[1:8, 2], -ring[1:8, 1]))


def _wrap_lamps(m: MeshData, pts, z, depth=0.16):
    """The tail light clusters wrapped round the rear corners onto the flanks, as real ones are:
    a strip `depth` long on each side, 4 mm proud of the body, between heights z."""
    x = pts[:, 0, 0]
    ks = np.nonzero(x <= x[0] + depth)[0]
    if len(ks) < 2:
        return
    for sd in (-1, 1):
        v = []
        for k in ks:
            for zz in z:
                v.append((x[k], sd * (_half_width(pts[k], zz) + 0.004), zz))
        n = len(ks)
        faces = [(2 * i, 2 * i + 2, 2 * i + 3, 2 * i + 1) for i in range(n - 1)]
        m.add(v, faces if sd < 0 else [f[::-1] for f in faces], "taillight")  # outward


def _high_brake_light(m: MeshData, x, top, half=0.16):
    """The centre high-mounted stop lamp: a red strip at the top of the rear glass, just inside it,
    its lens facing back on a dark housing (lit, it must not show through the windscreen)."""
    near = np.nonzero(top >= top.max() - 0.03)[0]
    if not len(near) or x[near[0]] - x[0] > 0.5 * (x[-1] - x[0]):
        return
    xt = float(x[near[0]]) - 0.02
    zg = float(np.interp(xt - 0.05, x, top))  # the glass's height at the strip's rear edge
    z0, z1 = zg - 0.045, zg - 0.01
    _box_at(m, xt - 0.048, xt, -half - 0.01, half + 0.01, z0 - 0.01, z1 + 0.005, "trim")
    m.add([(xt - 0.05, -half, z0), (xt - 0.05, half, z0), (xt - 0.05, half, z1), (xt - 0.05, -half, z1)],
          [(0, 3, 2, 1)], "taillight")  # facing -x


def _rear_seams(m: MeshData, xr, hw, clear, lamp_z, inner, ceiling, lid):
    """The rear face's shut lines, 3 mm proud: a boot lid's edge under the lamps (`lid`), or a
    tailgate's sides inside the lamps from the bumper up and its bottom edge over the bumper."""
    t = 0.006
    x0, x1 = xr + 0.014, xr + 0.017
    if lid:
        _box_at(m, x0, x1, -inner * hw, inner * hw, lamp_z[0] - t, lamp_z[0], "trim")
        return
    zb = clear + 0.36
    _box_at(m, x0, x1, -(inner - 0.12) * hw, (inner - 0.12) * hw, zb - t, zb, "trim")
    for sd in (-1, 1):
        y = sd * (inner - 0.12) * hw
        _box_at(m, x0, x1, min(y, y + sd * t), max(y, y + sd * t), zb, ceiling - 0.03, "trim")


def car_front(m: MeshData, xf, hw, belt, clear):
    """A car's face at x = xf, as real ones are laid out: headlights at the corners under the
    bonnet, a grille between them in a chrome surround with bars and a badge, the plate on a
    body-coloured bumper, a wide dark air intake under it and a dark lip at the bottom. (One dark
    block from the bumper to the bonnet read as a face or an appliance to the classifier.)"""
    lamp = (belt - 0.14, belt - 0.03)
    for sd in (-1, 1):
        y0, y1 = sorted((sd * 0.46 * hw, sd * 0.9 * hw))
        _box_at(m, xf - 0.035, xf, y0, y1, *lamp, "headlight")
    plate = (clear + 0.17, clear + 0.28)
    g0, g1 = min(plate[1] + 0.05, belt - 0.14), belt - 0.05  # taller on SUVs and pickups
    gy = 0.4 * hw
    _box_at(m, xf - 0.03, xf - 0.005, -gy, gy, g0, g1, "grille")
    t = 0.014  # the chrome surround and bars
    for z0, z1 in ((g1 - t, g1), (g0, g0 + t)):
        _box_at(m, xf - 0.03, xf, -gy - t, gy + t, z0, z1, "rim")
    for sd in (-1, 1):
        y0, y1 = sorted((sd * gy, sd * (gy + t)))
        _box_at(m, xf - 0.03, xf, y0, y1, g0, g1, "rim")
    bars = max(1, int((g1 - g0) / 0.06))
    for k in range(1, bars + 1):
        z = g0 + (g1 - g0) * k / (bars + 1)
        _box_at(m, xf - 0.02, xf - 0.002, -gy, gy, z - 0.005, z + 0.005, "rim")
    zc = (g0 + g1) / 2
    _box_at(m, xf - 0.03, xf, -0.04, 0.04, zc - 0.03, zc + 0.03, "rim")  # the badge
    _box_at(m, xf - 0.025, xf, -0.26, 0.26, *plate, "plate")
    _box_at(m, xf - 0.03, xf - 0.004, -0.6 * hw, 0.6 * hw, clear + 0.05, plate[0] - 0.02, "grille")  # lower intake
    _box_at(m, xf - 0.12, xf - 0.004, -0.92 * hw, 0.92 * hw, clear + 0.0, clear + 0.05, "trim")  # the lip


def body(m: MeshData, style, size, wheel_r, axles, x0=None, rear_details=True):
    """A lofted body of `style` filling `size` (length, width, height), its rear at x0 (default:
    centred); details (lamps, grille, plates, mirrors, seams, interior) on it."""
    l, w, h = size
    off = 0.0 if x0 is None else x0 + l / 2
    clear = wheel_r * 0.55
    arch_r = wheel_r + 0.06
    local_axles = [a - off for a in axles]
    s = STYLES[style]
    extra = [v for pts in (s["belt"], s["roof"]) for v, _ in pts]
    # a station where the roof line crosses HEADER under its top (the lower edge of the roof's rail)
    r = np.array(s["roof"], float)
    zc = r[:, 1].max() - HEADER / h
    for (u0, v0), (u1, v1) in zip(r[:-1], r[1:]):
        if (v0 - zc) * (v1 - zc) < 0:
            extra.append(u0 + (zc - v0) / (v1 - v0) * (u1 - u0))
    if not isinstance(s["pillars"], str):  # a pillar's edges are stations
        extra += [p + d / l for p in s["pillars"] for d in (-0.05, 0.05)]
    u = _stations(l, local_axles, arch_r, extra)
    pts, belt, top, hw = _rings(style, u, size, clear, local_axles, arch_r, wheel_r)
    pts[..., 0] += off
    x = pts[:, 0, 0]
    mats = _face_materials(style, u, x - off, belt, top, l)
    _loft(m, pts, mats)
    hw_max = float(hw.max())
    xf, xr = off + l / 2, off - l / 2
    bf, br = float(belt[-1]), float(belt[0])
    hf, hr = float(hw[-1]), float(hw[0])
    # lamps, grille and plates on the front and rear faces (1-2 cm proud, inside the box)
    if style in BOXY:
        lamp_z = (clear + 0.25, clear + 0.42) if style == "bus" else (bf - 0.2, bf - 0.03)
        for sd in (-1, 1):
            y0, y1 = sorted((sd * 0.42 * hf, sd * 0.8 * hf))
            _box_at(m, xf - 0.035, xf, y0, y1, *lamp_z, "headlight")
        _box_at(m, xf - 0.03, xf - 0.005, -0.38 * hf, 0.38 * hf, clear + 0.2, max(clear + 0.3, lamp_z[1] - 0.02), "grille")
        _box_at(m, xf - 0.12, xf - 0.004, -0.9 * hf, 0.9 * hf, clear + 0.02, clear + 0.16, "trim")  # lower bumper
        _box_at(m, xf - 0.025, xf, -0.26, 0.26, clear + 0.05, clear + 0.16, "plate")
    else:
        car_front(m, xf, hf, bf, clear)
    if rear_details:
        lamp_z, inner = rear_lamps(m, xr, hr, br, clear, tall=style in KIND_STYLES["van"], corner=s.get("corner_lamps", False),
                                   ceiling=float(top[0]))
        _wrap_lamps(m, pts, lamp_z)
        if s.get("high_stop"):
            _high_brake_light(m, x, top)
        if style != "bus":
            _rear_seams(m, xr, hr, clear, lamp_z, inner, float(top[0]), lid=s.get("lid", False))
    # mirrors at the foot of the windscreen, outside the doors (the body is narrower than the box)
    g = top - belt
    cab = np.nonzero(g > 0.15)[0]
    if len(cab):
        xm = float(x[cab[-1]]) - 0.15
        zm = float(np.interp(xm, x, belt)) + 0.06
        for sd in (-1, 1):
            y0, y1 = sorted((sd * (hw_max - 0.02), sd * (hw_max + 0.12)))
            _box_at(m, xm - 0.08, xm + 0.06, y0, y1, zm, zm + 0.12, "car_paint")
            y0, y1 = sorted((sd * (hw_max + 0.12), sd * (hw_max + 0.125)))
            _box_at(m, xm - 0.06, xm + 0.04, y0, y1, zm + 0.01, zm + 0.11, "car_glass")
        # a dark interior: seats and dashboard seen through the glass
        c0, c1 = float(x[cab[0]]) + 0.1, float(x[cab[-1]]) - 0.2
        zi = float(belt[cab].min())
        _box_at(m, c0, c1, -0.85 * hw_max, 0.85 * hw_max, zi - 0.25, zi + 0.05, "interior")
        for xs in np.arange(c0 + 0.4, c1 - 0.3, 0.95) if c1 - c0 > 1.0 else ():
            for sd in (-1, 1):
                y0, y1 = sorted((sd * 0.15 * hw_max, sd * 0.7 * hw_max))
                _box_at(m, xs - 0.08, xs + 0.02, y0, y1, zi, zi + 0.42, "interior")
    # door seams: thin dark lines on the sides
    doors = s.get("panel_seams") or s.get("pillars") or ()
    xs_list = [] if isinstance(doors, str) else [(p - 0.5) * l for p in doors]
    if len(local_axles) >= 2 and style not in ("bus", "truck_cab"):
        xs_list += [max(local_axles) - arch_r - 0.08, min(local_axles) + arch_r + 0.08]
    for xs in xs_list:
        zt = float(np.interp(xs, x - off, belt)) - 0.04
        for sd in (-1, 1):
            y = sd * (hw_max + 0.004)
            m.add([(off + xs - 0.006, y, clear + 0.12), (off + xs + 0.006, y, clear + 0.12), (off + xs + 0.006, y, zt),
                   (off + xs - 0.006, y, zt)], [(0, 1, 2, 3)], "trim")
    return belt, top, hw


def build_vehicle(kind: str, size, wheel_r: float, style: str) -> MeshData:
    l, w, h = size
    m = MeshData()
    m.smooth_angle = SMOOTH_ANGLE
    tyre_w = 0.2 if kind in ("car", "suv") else 0.26
    body_w = w - 0.26  # mirrors take the rest
    if kind == "truck":
        cab = min(2.3, l * 0.3)
        gap = 0.25
        ax_f = l / 2 - max(0.9, cab * 0.5)
        axles = [ax_f, -l / 2 + 1.6, -l / 2 + 2.9]
        body(m, "truck_cab", (cab, body_w, h * 0.92), wheel_r, [ax_f], x0=l / 2 - cab, rear_details=False)
        # the load box: rounded loft without glass, on a chassis
        bx0, bx1 = -l / 2, l / 2 - cab - gap
        _cargo_box(m, bx0 + 0.03, bx1, w - 0.02, wheel_r * 2 + 0.2, h)
        rear_lamps(m, bx0, (w - 0.02) / 2, 0.0, wheel_r * 0.55, low=True)
        for y in (-0.004, 0.004):  # the rear doors' seam
            _box_at(m, bx0 + 0.025, bx0 + 0.03, y - 0.006, y + 0.006, wheel_r * 2 + 0.25, h - 0.05, "trim")
        _box_at(m, bx0 + 0.3, l / 2 - 0.4, -0.45, 0.45, wheel_r * 0.7, wheel_r * 0.7 + 0.3, "trim")  # chassis
    else:
        if kind == "bus":
            axles = [l / 2 - 2.6, -l / 2 + 3.2]
        elif kind == "van":
            axles = [l / 2 - 0.9, -l / 2 + 1.0]
        else:
            axles = [l / 2 - max(0.8, l * 0.19), -l / 2 + max(0.75, l * 0.2)]
        body(m, style, (l, body_w, h), wheel_r, axles)
    hw = body_w / 2
    for ax in axles:
        for sd in (-1, 1):
            wheel(m, ax, sd * (hw - 0.01), wheel_r, tyre_w, side=sd)
    return m


def _cargo_box(m, x0, x1, w, z0, z1):
    """A box body with rounded vertical edges and ribs (a truck's load box)."""
    n = 3
    r = 0.06
    corners = []
    for cx, cy, a0 in ((x1 - r, w / 2 - r, 0), (x0 + r, w / 2 - r, 90), (x0 + r, -w / 2 + r, 180), (x1 - r, -w / 2 + r, 270)):
        for k in range(n + 1):
            a = math.radians(a0 + 90 * k / n)
            corners.append((cx + r * math.cos(a), cy + r * math.sin(a)))
    c = np.array(corners)
    k = len(c)
    v = np.vstack([np.column_stack([c, np.full(k, z0)]), np.column_stack([c, np.full(k, z1)])])
    m.add(v, [(i, (i + 1) % k, k + (i + 1) % k, k + i) for i in range(k)] + [tuple(range(k, 2 * k)),
                                                                              tuple(range(k - 1, -1, -1))], "cargo")
    for xr in np.arange(x0 + 0.8, x1 - 0.3, 1.2):  # ribs
        for sd in (-1, 1):
            y0, y1 = sorted((sd * w / 2, sd * (w / 2 - 0.015)))
            _box_at(m, xr - 0.03, xr + 0.03, y0, y1, z0 + 0.02, z1 - 0.02, "trim")
