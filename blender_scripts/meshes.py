"""Pure-numpy mesh building: paths (polylines with arc length) and primitives merged into one
mesh per object with a material name per face. No bpy here, so layouts are cheap and testable."""

from __future__ import annotations

import math

import numpy as np


class Path:
    """A 2D polyline with arc length; `closed` paths wrap around."""

    def __init__(self, points, closed: bool = False):
        self.points = np.asarray(points, dtype=np.float64)
        self.closed = closed
        pts = np.vstack([self.points, self.points[:1]]) if closed else self.points
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        self._pts = pts
        self.s = np.concatenate([[0.0], np.cumsum(seg)])
        self.length = float(self.s[-1])

    def at(self, s):
        """(xy (..., 2), heading (...)) at arc length s (wrapped if closed, clamped if not)."""
        s = np.asarray(s, dtype=np.float64)
        s = np.mod(s, self.length) if self.closed else np.clip(s, 0.0, self.length)
        i = np.clip(np.searchsorted(self.s, s, side="right") - 1, 0, len(self.s) - 2)
        a, b = self._pts[i], self._pts[i + 1]
        seglen = np.maximum(self.s[i + 1] - self.s[i], 1e-12)
        t = ((s - self.s[i]) / seglen)[..., None]
        d = b - a
        return a + t * d, np.arctan2(d[..., 1], d[..., 0])

    def normals(self) -> np.ndarray:
        """Unit left normals at the vertices (averaged over neighbouring segments)."""
        p = self.points
        if self.closed:
            t = np.roll(p, -1, axis=0) - np.roll(p, 1, axis=0)
        else:
            t = np.gradient(p, axis=0)
        t /= np.linalg.norm(t, axis=1, keepdims=True)
        return np.stack([-t[:, 1], t[:, 0]], axis=1)

    def offset(self, d: float) -> "Path":
        return Path(self.points + d * self.normals(), self.closed)

    def reversed(self) -> "Path":
        return Path(self.points[::-1], self.closed)

    def sub(self, s0: float, s1: float, step: float = 2.0) -> np.ndarray:
        """Points from s0 to s1 (s0 < s1) at about `step` spacing, ends included."""
        n = max(2, int(math.ceil((s1 - s0) / step)) + 1)
        return self.at(np.linspace(s0, s1, n))[0]


def line_path(p0, p1, step: float = 5.0) -> Path:
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    n = max(2, int(math.ceil(np.linalg.norm(p1 - p0) / step)) + 1)
    return Path(p0 + np.linspace(0, 1, n)[:, None] * (p1 - p0))


def arc_path(center, radius, a0, a1, step: float = 2.0, closed=False) -> Path:
    n = max(3, int(math.ceil(abs(a1 - a0) * radius / step)) + (0 if closed else 1))
    a = np.linspace(a0, a1, n, endpoint=not closed)
    return Path(np.stack([center[0] + radius * np.cos(a), center[1] + radius * np.sin(a)], 1), closed)


def curved_path(length: float, curvature: float, step: float = 2.0) -> Path:
    """A path of constant curvature whose midpoint is the origin, heading +x there."""
    s = np.linspace(-length / 2, length / 2, int(math.ceil(length / step)) + 1)
    if abs(curvature) < 1e-9:
        return Path(np.stack([s, np.zeros_like(s)], 1))
    r = 1.0 / curvature
    a = s * curvature
    return Path(np.stack([r * np.sin(a), r * (1 - np.cos(a))], 1))


class MeshData:
    """Vertices, faces and one material name per face; primitives append to it. `smooth_angle`
    (degrees): shade smooth except across edges sharper than it (None: flat, the default)."""

    smooth_angle: float | None = None

    def __init__(self):
        self.verts: list[np.ndarray] = []
        self.faces: list[tuple] = []
        self.mats: list[str] = []
        self._n = 0

    def add(self, verts, faces, mat: str):
        verts = np.asarray(verts, dtype=np.float64).reshape(-1, 3)
        self.verts.append(verts)
        self.faces.extend(tuple(int(i) + self._n for i in f) for f in faces)
        self.mats.extend([mat] * len(faces))
        self._n += len(verts)
        return self

    @property
    def vertices(self) -> np.ndarray:
        return np.vstack(self.verts) if self.verts else np.zeros((0, 3))

    def __len__(self):
        return len(self.faces)

    # ---- primitives

    def box(self, center, size, yaw: float = 0.0, mat: str = "default", top: bool = True):
        """Box with bottom centre `center` (x, y, z), size (length, width, height), turned by yaw."""
        l, w, h = size
        x = np.array([-1, 1, 1, -1, -1, 1, 1, -1]) * l / 2
        y = np.array([-1, -1, 1, 1, -1, -1, 1, 1]) * w / 2
        z = np.array([0, 0, 0, 0, 1, 1, 1, 1]) * h
        c, s = math.cos(yaw), math.sin(yaw)
        v = np.stack([center[0] + c * x - s * y, center[1] + s * x + c * y, center[2] + z], 1)
        faces = [(0, 3, 2, 1), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]
        if top:
            faces.append((4, 5, 6, 7))
        return self.add(v, faces, mat)

    def cylinder(self, center, radius, height, n=10, mat="default", axis="z", yaw=0.0):
        """Cylinder around `axis` ('z': bottom centre at center; 'y': centred, for wheels)."""
        a = np.linspace(0, 2 * math.pi, n, endpoint=False)
        ring = np.stack([radius * np.cos(a), radius * np.sin(a)], 1)
        if axis == "z":
            lo = np.column_stack([ring, np.zeros(n)])
            hi = np.column_stack([ring, np.full(n, height)])
        else:  # axis along local y, centred
            lo = np.column_stack([ring[:, 0], np.full(n, -height / 2), ring[:, 1]])
            hi = np.column_stack([ring[:, 0], np.full(n, height / 2), ring[:, 1]])
        v = np.vstack([lo, hi])
        c, s = math.cos(yaw), math.sin(yaw)
        v = np.column_stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1], v[:, 2]]) + center
        faces = [(i, (i + 1) % n, n + (i + 1) % n, n + i) for i in range(n)]
        faces += [tuple(range(n - 1, -1, -1)), tuple(range(n, 2 * n))]
        if axis != "z":  # (x, z) for (x, y) mirrors the ring: turn the faces back outward
            faces = [f[::-1] for f in faces]
        return self.add(v, faces, mat)

    def tube(self, p0, p1, r0, r1=None, n=6, mat="default", caps=True):
        """A (tapered) cylinder from point p0 (radius r0) to p1 (radius r1, default r0)."""
        p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
        axis = p1 - p0
        length = float(np.linalg.norm(axis))
        z = axis / max(length, 1e-12)
        x = np.cross([0.0, 0.0, 1.0], z) if abs(z[2]) < 0.999 else np.array([1.0, 0.0, 0.0])
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        a = np.linspace(0, 2 * math.pi, n, endpoint=False)
        ring = np.cos(a)[:, None] * x + np.sin(a)[:, None] * y
        r1 = r0 if r1 is None else r1
        v = np.vstack([p0 + r0 * ring, p1 + r1 * ring])
        faces = [(i, (i + 1) % n, n + (i + 1) % n, n + i) for i in range(n)]
        if caps:
            faces += [tuple(range(n - 1, -1, -1)), tuple(range(n, 2 * n))]
        return self.add(v, faces, mat)

    def ellipsoid(self, center, radii, mat="default", nu=10, nv=6):
        faces, verts = [], [(0, 0, -1)]
        for j in range(1, nv):
            phi = -math.pi / 2 + math.pi * j / nv
            for i in range(nu):
                th = 2 * math.pi * i / nu
                verts.append((math.cos(phi) * math.cos(th), math.cos(phi) * math.sin(th), math.sin(phi)))
        verts.append((0, 0, 1))
        top = len(verts) - 1
        for i in range(nu):
            faces.append((0, 1 + (i + 1) % nu, 1 + i))
        for j in range(nv - 2):
            r0, r1 = 1 + j * nu, 1 + (j + 1) * nu
            for i in range(nu):
                faces.append((r0 + i, r0 + (i + 1) % nu, r1 + (i + 1) % nu, r1 + i))
        last = 1 + (nv - 2) * nu
        for i in range(nu):
            faces.append((last + i, last + (i + 1) % nu, top))
        v = np.asarray(verts) * np.asarray(radii) + np.asarray(center)
        return self.add(v, faces, mat)

    def ribbon(self, points, left: float, right: float, z: float, mat="default",
               depth: float | None = None, closed: bool = False):
        """Flat strip between lateral offsets `right` < `left` of a polyline at height z; with
        `depth`, side walls go down by that much (a raised kerb or barrier)."""
        path = points if isinstance(points, Path) else Path(points, closed)
        nrm = path.normals()
        p = path.points
        L = np.column_stack([p + left * nrm, np.full(len(p), z)])
        R = np.column_stack([p + right * nrm, np.full(len(p), z)])
        n = len(p)
        m = n if path.closed else n - 1
        v = [R, L]
        faces = [(i, (i + 1) % n, n + (i + 1) % n, n + i) for i in range(m)]
        if depth:
            v += [R - [0, 0, depth], L - [0, 0, depth]]
            faces += [(2 * n + i, 2 * n + (i + 1) % n, (i + 1) % n, i) for i in range(m)]
            faces += [(n + i, n + (i + 1) % n, 3 * n + (i + 1) % n, 3 * n + i) for i in range(m)]
        return self.add(np.vstack(v), faces, mat)

    def rect(self, x0, x1, y0, y1, z, mat="default"):
        v = [(x0, y0, z), (x1, y0, z), (x1, y1, z), (x0, y1, z)]
        return self.add(v, [(0, 1, 2, 3)], mat)

    def quad(self, corners_xy, z, mat="default"):
        v = [(c[0], c[1], z) for c in corners_xy]
        return self.add(v, [(0, 1, 2, 3)], mat)

    def disc(self, center, radius, z, n=32, mat="default"):
        a = np.linspace(0, 2 * math.pi, n, endpoint=False)
        v = np.column_stack([center[0] + radius * np.cos(a), center[1] + radius * np.sin(a), np.full(n, z)])
        return self.add(v, [tuple(range(n))], mat)
