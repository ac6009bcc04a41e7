"""The procedural vehicles (pure numpy, no rendering): every body style stays inside its box, has the
parts that make it read as a vehicle, paints only vehicle materials, and is the same for the same draw."""

from __future__ import annotations

import numpy as np
import pytest

from blender_scripts import assets
from blender_scripts.materials import MATERIAL_CLASSES
from blender_scripts.vehicles import KIND_STYLES

STYLES = [(kind, style) for kind, styles in KIND_STYLES.items() for style in styles]
PARTS = {"car_paint", "car_glass", "tyre", "rim", "headlight", "taillight", "reverse_lamp", "plate", "grille", "trim"}


def _normal(p: np.ndarray) -> np.ndarray:
    """A polygon's (unnormalised) normal from its vertices in order (Newell's sum): outward for a
    face wound outward."""
    return sum(np.cross(p[k], p[(k + 1) % len(p)]) for k in range(len(p)))


@pytest.mark.parametrize("kind,style", STYLES)
def test_every_style_fills_its_box_with_the_parts_of_a_vehicle(kind, style):
    rng = np.random.default_rng(3)
    for _ in range(5):
        size = assets.vehicle_size(kind, rng, max_width=3.0)
        m = assets.vehicle_mesh(kind, size, rng, style)
        v = m.vertices
        l, w, h = size
        assert np.all(np.abs(v[:, 0]) <= l / 2 + 1e-6), f"{style}: a part sticks out of the box's length"
        assert np.all(np.abs(v[:, 1]) <= w / 2 + 1e-6), f"{style}: a part sticks out of the box's width"
        assert v[:, 2].min() >= -1e-6 and v[:, 2].max() <= h + 1e-6, f"{style}: a part above or below the box"
        # it reaches the box: the body is not a shrunken copy
        assert v[:, 0].max() > l / 2 - 0.03 and v[:, 0].min() < -l / 2 + 0.03 and v[:, 2].max() > 0.9 * h
        assert PARTS <= set(m.mats), f"{style}: missing {PARTS - set(m.mats)}"
        assert all(MATERIAL_CLASSES[n] == "vehicle" for n in m.mats)
        assert max(max(f) for f in m.faces) < len(v) and min(min(f) for f in m.faces) >= 0
        assert m.smooth_angle is not None
    wheels = m.mats.count("tyre") / (7 * 20)  # a tyre: 7 bands of its cross-section, 20 quads round
    assert wheels == (6 if kind == "truck" else 4)


@pytest.mark.parametrize("kind,style", STYLES)
def test_tyres_touch_the_ground_and_glass_sits_above_the_beltline(kind, style):
    l, w, h = assets.VEHICLE_SIZES[kind][0]
    m = assets.vehicle_mesh(kind, (l, w, h), np.random.default_rng(0), style)
    v, mats = m.vertices, np.array(m.mats)
    faces_z = {n: [] for n in ("tyre", "car_glass")}
    for f, n in zip(m.faces, mats):
        if n in faces_z:
            faces_z[n].append(v[list(f), 2])
    tyre = np.concatenate(faces_z["tyre"])
    assert tyre.min() < 0.01, "the tyres float above the road"
    glass = np.concatenate(faces_z["car_glass"])
    assert np.median(glass) > 0.35 * h, "the glasshouse is below the body"


def test_a_minibus_is_glazed_along_its_sides_and_a_panel_van_only_at_the_cab():
    """Side glass (facing sideways, above the beltline) over most of a minibus's length, split by
    pillars; a panel van's only beside the front seats."""
    l, w, h = assets.VEHICLE_SIZES["van"][0]

    def side_glass_x(style):
        m = assets.vehicle_mesh("van", (l, w, h), np.random.default_rng(0), style)
        xs = []
        for f, n in zip(m.faces, m.mats):
            p = m.vertices[list(f)]
            nrm = _normal(p)
            if n == "car_glass" and abs(nrm[1]) > 2 * max(abs(nrm[0]), abs(nrm[2])) and np.ptp(p[:, 0]) > 0.01:
                xs.append(p[:, 0].mean())
        return np.array(xs)

    bus, van = side_glass_x("minibus"), side_glass_x("van")
    assert np.ptp(bus) > 0.65 * l and np.ptp(van) < 0.25 * l
    gaps = np.diff(np.unique(np.round(bus, 2)))
    assert (gaps > 0.06).sum() >= 3, "no pillars between the panes"


def test_same_draw_same_vehicle_and_styles_differ():
    size = (4.4, 1.8, 1.45)
    a = assets.vehicle_mesh("car", size, np.random.default_rng(7), "sedan")
    b = assets.vehicle_mesh("car", size, np.random.default_rng(7), "sedan")
    assert np.array_equal(a.vertices, b.vertices) and a.faces == b.faces and a.mats == b.mats
    c = assets.vehicle_mesh("car", size, np.random.default_rng(7), "wagon")
    assert not (len(a.vertices) == len(c.vertices) and np.allclose(a.vertices, c.vertices))


def test_ego_body_keeps_the_smooth_shading_and_its_own_materials():
    mesh, box, kind, colour = assets.ego_body([(3.7, 0, 0.6), (-1.0, 0, 0.9), (1.9, 1.0, 1.0), (1.9, -1.0, 1.0)],
                                              np.random.default_rng(1))
    assert mesh.smooth_angle is not None
    assert all(n.startswith("ego_") and MATERIAL_CLASSES[n] == "ego" for n in mesh.mats)


@pytest.mark.parametrize("style", ["sedan", "hatchback", "wagon", "suv", "pickup"])
def test_a_car_front_is_laid_out_as_real_ones(style):
    """Headlights at the corners under the bonnet, the grille between them (not a dark block from the
    bumper up), the plate under the grille and a dark intake under the plate."""
    kind = "car" if style in KIND_STYLES["car"] else "suv"
    l, w, h = assets.VEHICLE_SIZES[kind][0]
    m = assets.vehicle_mesh(kind, (l, w, h), np.random.default_rng(0), style)
    v = m.vertices
    parts = {}
    for f, n in zip(m.faces, m.mats):
        p = v[list(f)]
        if p[:, 0].min() > l / 2 - 0.2:  # on the front face
            parts.setdefault(n, []).append(p)
    span = {n: (np.concatenate(ps).min(0), np.concatenate(ps).max(0)) for n, ps in parts.items()}
    lamps = np.concatenate(parts["headlight"])
    inner = np.abs(lamps[:, 1]).min()
    grille = np.concatenate([p for p in parts["grille"] if p[:, 2].min() > span["plate"][1][2] - 1e-6])
    intake = np.concatenate([p for p in parts["grille"] if p[:, 2].max() < span["plate"][0][2] + 1e-6])
    assert np.abs(grille[:, 1]).max() < inner, "the grille reaches past the headlights"
    assert grille[:, 2].max() > lamps[:, 2].min(), "the grille is not beside the headlights"
    assert grille[:, 2].max() - grille[:, 2].min() < 0.3 * h
    assert intake[:, 2].max() < span["plate"][0][2] and len(parts["rim"]) >= 5  # surround, bars and badge


@pytest.mark.parametrize("style", ["sedan", "hatchback", "wagon", "suv", "pickup", "van", "minibus"])
def test_a_car_rear_is_laid_out_as_real_ones(style):
    """Tail lights at the rear corners wrapping round onto both flanks (facing out), no taller than
    a real cluster but on a van's pillars, shut lines on the rear face, and on tailgate styles the
    high-mounted stop lamp at the top of the rear glass."""
    kind = next(k for k, ss in KIND_STYLES.items() if style in ss)
    l, w, h = assets.VEHICLE_SIZES[kind][0]
    m = assets.vehicle_mesh(kind, (l, w, h), np.random.default_rng(0), style)
    v = m.vertices
    flank, rear, high, seams = {1: 0, -1: 0}, [], [], 0
    for f, n in zip(m.faces, m.mats):
        p = v[list(f)]
        nrm = _normal(p)
        if n == "taillight" and np.ptp(p[:, 0]) > 0.04 and abs(nrm[1]) > abs(nrm[2]):  # a strip along a flank
            side = int(np.sign(p[:, 1].mean()))
            assert np.sign(nrm[1]) == side, "a wrapped lamp faces into the body"
            flank[side] += 1
        elif n == "taillight" and np.abs(p[:, 1]).max() < 0.25 and p[:, 2].min() > 0.8 * h:
            high.append(p)
        elif n == "taillight" and p[:, 0].max() < -l / 2 + 0.05:
            rear.append(p)
        elif n == "trim" and p[:, 0].max() < -l / 2 + 0.02 and np.ptp(p[:, 0]) < 1e-9:  # on the rear face
            dy, dz = np.ptp(p[:, 1]), np.ptp(p[:, 2])
            seams += min(dy, dz) < 0.01 and max(dy, dz) > 0.2  # a line, not the bumper
    assert flank[1] and flank[-1], "the tail lights stop at the rear face"
    z = np.concatenate(rear)[:, 2]
    assert z.max() - z.min() < (0.6 if style in ("van", "minibus") else 0.4), "a tail light cluster as tall as a van's"
    assert seams >= 1, "no shut line on the rear face"
    assert bool(high) == (style in ("hatchback", "wagon", "suv")), "the high-mounted stop lamp"


def _signed_volume(v, faces) -> float:
    """Positive where the faces wind outward (counter-clockwise seen from outside)."""
    t = 0.0
    for f in faces:
        p = v[list(f)]
        for k in range(1, len(f) - 1):
            t += float(np.dot(p[0], np.cross(p[k], p[k + 1]))) / 6
    return t


@pytest.mark.parametrize("kind,style", STYLES)
def test_every_face_of_a_vehicle_faces_outward(kind, style):
    """Cycles shades a back face as the inside of the material: glass seen from behind reflects
    totally past the critical angle (a mirror instead of a window), so the body, its caps and the
    wheels on both sides must wind outward."""
    from blender_scripts.meshes import MeshData
    from blender_scripts.vehicles import wheel

    m = assets.vehicle_mesh(kind, assets.VEHICLE_SIZES[kind][0], np.random.default_rng(0), style)
    v = m.vertices
    body = [f for f, n in zip(m.faces, m.mats) if n in ("car_paint", "car_glass", "cargo")]
    assert _signed_volume(v, body) > 0.3 * np.prod(assets.VEHICLE_SIZES[kind][0])
    for side in (1, -1):
        w = MeshData()
        wheel(w, 0.0, side * 0.9, 0.33, 0.2, side=side)
        wv = w.vertices
        for f, n in zip(w.faces, w.mats):
            p = wv[list(f)]
            nrm = _normal(p)
            radial = np.array([p[:, 0].mean(), 0.0, p[:, 2].mean() - 0.33])
            if n == "tyre" and np.linalg.norm(radial) > 0.32:  # the tread
                assert np.dot(nrm, radial) > 0, f"side {side}: the tread faces the axle"
            if n in ("rim", "trim") and abs(nrm[1]) > 0.8 * np.linalg.norm(nrm):
                assert np.sign(nrm[1]) == side, f"side {side}: the rim faces the car"


@pytest.mark.parametrize("axis", ["z", "y"])
def test_primitives_face_outward(axis):
    from blender_scripts.meshes import MeshData

    for m in (MeshData().cylinder((1, 2, 0), 0.5, 2, axis=axis), MeshData().box((1, 2, 0), (2, 1, 1)),
              MeshData().tube((0, 0, 0), (0, 0, 2), 0.5), MeshData().ellipsoid((0, 0, 1), (1, 1, 1))):
        assert _signed_volume(m.vertices, m.faces) > 0


@pytest.mark.parametrize("kind,style", STYLES)
def test_windscreen_and_rear_window_are_framed_by_pillars(kind, style):
    """The windscreen and the rear window lie between body-coloured pillars: beside each of their
    faces, along the length, a paint face rises as high as the glass. (Glass across the whole top
    of the body, down to the side windows' line, read as a dark band, not a window.)"""
    l, w, h = assets.VEHICLE_SIZES[kind][0]
    m = assets.vehicle_mesh(kind, (l, w, h), np.random.default_rng(0), style)
    v = m.vertices
    faces = list(zip(m.faces, m.mats))
    edges: dict = {}  # longitudinal edge (two vertices at different x) -> (material, top z) of its faces
    for f, n in faces:
        for a, b in zip(f, f[1:] + f[:1]):
            if abs(v[a, 0] - v[b, 0]) > 1e-6:
                edges.setdefault(frozenset((a, b)), []).append((n, v[list(f), 2].max()))
    sloped = 0
    for f, n in faces:
        p = v[list(f)]
        nrm = _normal(p)
        if n != "car_glass" or abs(nrm[0]) < 0.3 * np.linalg.norm(nrm) or np.abs(p[:, 1]).max() > 0.45 * w:
            continue  # side windows, mirrors
        sloped += 1
        top = p[:, 2].max()
        beside = [(mat, z) for a, b in zip(f, f[1:] + f[:1]) for mat, z in edges.get(frozenset((a, b)), [])]
        assert any(mat == "car_paint" and z >= top - 1e-6 for mat, z in beside), \
            f"{style}: sloped glass at x={p[:, 0].mean():.2f} without a pillar beside it"
    assert sloped, f"{style}: no windscreen"


@pytest.mark.parametrize("kind,style", [ks for ks in STYLES if ks[1] not in ("bus", "truck_cab")])
def test_windscreen_and_rear_window_stop_under_the_roof_rail(kind, style):
    """The glass of a windscreen or rear window ends HEADER under the roof, a body-coloured rail
    above it across the roof's edge, as on real cars. A bus's or a truck's near-upright windscreen
    rises to its roof: a rail that fine falls between its stations."""
    from blender_scripts.vehicles import HEADER

    l, w, h = assets.VEHICLE_SIZES[kind][0]
    m = assets.vehicle_mesh(kind, (l, w, h), np.random.default_rng(0), style)
    v = m.vertices
    body = np.concatenate([v[list(f)] for f, n in zip(m.faces, m.mats) if n == "car_paint"])
    roof = body[:, 2].max()
    rails = 0
    for f, n in zip(m.faces, m.mats):
        p = v[list(f)]
        nrm = _normal(p)
        if abs(nrm[0]) < 0.3 * np.linalg.norm(nrm) or np.abs(p[:, 1]).max() > 0.45 * w:
            continue  # not across the front or back of the glasshouse
        if n == "car_glass" and np.ptp(p[:, 0]) > 1e-6:
            assert p[:, 2].max() <= roof - HEADER + 1e-6, f"{style}: glass at x={p[:, 0].mean():.2f} up to the roof"
        rails += n == "car_paint" and p[:, 2].min() >= roof - HEADER - 1e-6 and np.ptp(p[:, 1]) > 0.5 * w
    assert rails >= 1, f"{style}: no roof rail above the glass"


def test_a_bus_rear_window_sits_over_its_engine_bay():
    """A city bus's rear window is in the top of its rear, paint (the engine bay) under it: a rear
    glazed down to the beltline read as a second windscreen."""
    l, w, h = assets.VEHICLE_SIZES["bus"][0]
    m = assets.vehicle_mesh("bus", (l, w, h), np.random.default_rng(0), "bus")
    v = m.vertices
    rear = [v[list(f)] for f, n in zip(m.faces, m.mats)
            if n == "car_glass" and v[list(f), 0].max() < -l / 2 + 0.3 and _normal(v[list(f)])[0] < 0]
    assert rear, "no rear window"
    z = np.concatenate(rear)[:, 2]
    assert z.min() > 0.55 * h and z.max() > 0.9 * h, f"the rear window spans {z.min():.2f}-{z.max():.2f} m of {h:.2f}"
