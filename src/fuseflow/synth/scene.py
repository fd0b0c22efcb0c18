"""Scene geometry: textured triangle primitives (box, quad, cylinder, sphere) and the scenes.

World frame: metres, z up, floor at z = 0. Every part is a triangle mesh in its own local
frame with, per triangle corner, texture coordinates in *metres* along the surface, so a
texture keeps its physical scale on every object. A part is placed by a 4x4 world-from-local
transform that is constant (static part) or a function of time (moving part).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

__all__ = ["Part", "Scene", "build_scene", "box", "quad", "cylinder", "sphere"]


@dataclass(frozen=True)
class MeshData:
    """vertices (V, 3) float64 local metres; triangles (T, 3) int; uv (T, 3, 2) metres."""

    vertices: np.ndarray
    triangles: np.ndarray
    uv: np.ndarray


@dataclass(frozen=True)
class Part:
    """One textured mesh of a scene.

    pose: world-from-local 4x4 at time t (seconds); ``moving`` False means pose(t) is constant.
    texture: index into the scene's texture atlas; uv_offset (2,) metres shifts the texture so
    that objects sharing a texture do not look alike; tint (3,) multiplies the texture colour.
    """

    name: str
    mesh: MeshData
    pose: Callable[[float], np.ndarray]
    moving: bool
    texture: int
    uv_offset: np.ndarray
    tint: np.ndarray


@dataclass(frozen=True)
class Scene:
    """The parts of a scene, the point cameras look at and the camera layout hints."""

    name: str
    parts: tuple[Part, ...]
    target: np.ndarray  # (3,) world point the rig looks at
    ring_radius: float  # metres, horizontal distance of ring cameras from the target
    ring_height: float  # metres, camera height of a ring
    dome_radius: float  # metres, distance of dome cameras from the target
    dome_elevations: tuple[float, float]  # degrees, lowest and highest dome ring
    symmetry: int = 1  # the layout repeats every 360 / symmetry deg about the vertical (symstudio)

    def triangles_at(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """All parts placed at time t: world vertices of every triangle corner (T, 3, 3) float32,
        corner uv (T, 3, 2) float32 (offset applied), texture id (T,), tint (T, 3), part id (T,)."""
        tri_xyz, tri_uv, tex, tint, pid = [], [], [], [], []
        for k, p in enumerate(self.parts):
            T = p.pose(t)
            v = p.mesh.vertices @ T[:3, :3].T + T[:3, 3]
            tri_xyz.append(v[p.mesh.triangles])
            tri_uv.append(p.mesh.uv + p.uv_offset)
            n = len(p.mesh.triangles)
            tex.append(np.full(n, p.texture, np.int32))
            tint.append(np.broadcast_to(p.tint, (n, 3)))
            pid.append(np.full(n, k, np.int32))
        return (
            np.concatenate(tri_xyz).astype(np.float32),
            np.concatenate(tri_uv).astype(np.float32),
            np.concatenate(tex),
            np.concatenate(tint).astype(np.float32),
            np.concatenate(pid),
        )


# --------------------------------------------------------------------------- primitives


def _quad_tris(a, b, c, d, ua, ub, uc, ud):
    """Two triangles (a, b, c), (a, c, d) with counter-clockwise order seen from the front."""
    return [(a, b, c), (a, c, d)], [(ua, ub, uc), (ua, uc, ud)]


def quad(w: float, h: float) -> MeshData:
    """A w x h rectangle in the local xy plane, centred, facing +z (single-sided surface)."""
    v = np.array([[-w / 2, -h / 2, 0], [w / 2, -h / 2, 0], [w / 2, h / 2, 0], [-w / 2, h / 2, 0]], float)
    tris = np.array([[0, 1, 2], [0, 2, 3]])
    uv = v[tris][..., :2] + np.array([w / 2, h / 2])
    return MeshData(v, tris, uv)


def box(sx: float, sy: float, sz: float, bottom: bool = True) -> MeshData:
    """Axis-aligned box centred at the origin, outward-facing triangles; ``bottom`` False omits
    the bottom face (boxes standing on the floor: that face is never seen)."""
    h = np.array([sx, sy, sz]) / 2
    verts, tris, uvs = [], [], []
    # each face: normal axis, sign; two in-plane axes (u, v) chosen so u x v = normal
    for ax, sgn in ((0, 1), (0, -1), (1, 1), (1, -1), (2, 1), (2, -1)):
        if ax == 2 and sgn == -1 and not bottom:
            continue
        u_ax, v_ax = [(1, 2), (2, 0), (0, 1)][ax]
        if sgn < 0:
            u_ax, v_ax = v_ax, u_ax
        corners = []
        for su, sv in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
            p = np.zeros(3)
            p[ax] = sgn * h[ax]
            p[u_ax] = su * h[u_ax]
            p[v_ax] = sv * h[v_ax]
            corners.append(p)
        base = len(verts)
        verts.extend(corners)
        tris.extend([(base, base + 1, base + 2), (base, base + 2, base + 3)])
        cu = [np.array([c[u_ax] + h[u_ax], c[v_ax] + h[v_ax]]) + 7.0 * ax + 3.0 * (sgn > 0) for c in corners]
        uvs.extend([(cu[0], cu[1], cu[2]), (cu[0], cu[2], cu[3])])
    return MeshData(np.array(verts), np.array(tris), np.array(uvs))


def cylinder(r: float, h: float, segments: int = 32, caps: bool = True) -> MeshData:
    """Vertical cylinder of radius r from z = 0 to z = h, outward-facing."""
    a = np.linspace(0, 2 * math.pi, segments + 1)
    verts, tris, uvs = [], [], []
    for i in range(segments):
        a0, a1 = a[i], a[i + 1]
        p = [
            (r * math.cos(a0), r * math.sin(a0), 0.0),
            (r * math.cos(a1), r * math.sin(a1), 0.0),
            (r * math.cos(a1), r * math.sin(a1), h),
            (r * math.cos(a0), r * math.sin(a0), h),
        ]
        u = [(r * a0, 0.0), (r * a1, 0.0), (r * a1, h), (r * a0, h)]
        base = len(verts)
        verts.extend(p)
        tris.extend([(base, base + 1, base + 2), (base, base + 2, base + 3)])
        uvs.extend([(u[0], u[1], u[2]), (u[0], u[2], u[3])])
        if caps:
            for z, order in ((h, 1), (0.0, -1)):
                c = (0.0, 0.0, z)
                q0 = (r * math.cos(a0), r * math.sin(a0), z)
                q1 = (r * math.cos(a1), r * math.sin(a1), z)
                base = len(verts)
                verts.extend([c, q0, q1] if order > 0 else [c, q1, q0])
                tris.append((base, base + 1, base + 2))
                tri_uv = [(x + 5.0, y + 5.0) for x, y, _ in (verts[base], verts[base + 1], verts[base + 2])]
                uvs.append(tuple(tri_uv))
    return MeshData(np.array(verts, float), np.array(tris), np.array(uvs, float))


def sphere(r: float, n_lon: int = 24, n_lat: int = 14) -> MeshData:
    """UV sphere of radius r centred at the origin, outward-facing."""
    verts, tris, uvs = [], [], []
    lat = np.linspace(-math.pi / 2, math.pi / 2, n_lat + 1)
    lon = np.linspace(0, 2 * math.pi, n_lon + 1)

    def pt(i, j):
        return (r * math.cos(lat[i]) * math.cos(lon[j]), r * math.cos(lat[i]) * math.sin(lon[j]), r * math.sin(lat[i]))

    for i in range(n_lat):
        for j in range(n_lon):
            p = [pt(i, j), pt(i, j + 1), pt(i + 1, j + 1), pt(i + 1, j)]
            u = [(r * lon[j], r * lat[i]), (r * lon[j + 1], r * lat[i]), (r * lon[j + 1], r * lat[i + 1]),
                 (r * lon[j], r * lat[i + 1])]  # fmt: skip
            base = len(verts)
            verts.extend(p)
            cand = [(base, base + 1, base + 2), (base, base + 2, base + 3)]
            cand_uv = [(u[0], u[1], u[2]), (u[0], u[2], u[3])]
            for tri, tuv in zip(cand, cand_uv):
                a, b, c = (np.array(verts[k]) for k in tri)
                if np.linalg.norm(np.cross(b - a, c - a)) > 1e-12:  # drop degenerate pole triangles
                    tris.append(tri)
                    uvs.append(tuv)
    return MeshData(np.array(verts, float), np.array(tris), np.array(uvs, float))


# --------------------------------------------------------------------------- transforms


def _T(R: np.ndarray | None = None, t=(0.0, 0.0, 0.0)) -> np.ndarray:
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    T[:3, 3] = t
    return T


def _rot(axis: str, a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    if axis == "x":
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    if axis == "y":
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _static(T: np.ndarray) -> Callable[[float], np.ndarray]:
    T = np.array(T, float)
    return lambda t: T


# --------------------------------------------------------------------------- scenes


class _Builder:
    def __init__(self, rng: np.random.Generator, n_textures: int):
        self.rng = rng
        self.n_textures = n_textures
        self.parts: list[Part] = []

    def add(self, name, mesh, pose, moving=False, tint=None, texture=None):
        rng = self.rng
        if tint is None:
            tint = rng.uniform(0.55, 1.0, 3)
        tex = int(rng.integers(self.n_textures)) if texture is None else texture
        self.parts.append(
            Part(
                name,
                mesh,
                pose if callable(pose) else _static(pose),
                moving,
                tex,
                rng.uniform(0, 40, 2),
                np.asarray(tint),
            )
        )


def _figure(b: _Builder, name: str, place: Callable[[float], np.ndarray], gait: Callable[[float], float], moving: bool):
    """An articulated human-sized figure (1.75 m): torso, head, two-segment arms and legs.

    ``place(t)`` is world-from-figure (figure origin on the floor between the feet, facing +x);
    ``gait(t)`` the swing phase in radians (limbs swing by +-0.5 rad with it).
    """
    hip_z, shoulder_z = 0.92, 1.45
    skin = np.array([0.95, 0.8, 0.7])
    b.add(f"{name}.torso", box(0.22, 0.38, 0.58), lambda t: place(t) @ _T(t=(0, 0, 1.19)), moving)
    b.add(f"{name}.head", sphere(0.11), lambda t: place(t) @ _T(t=(0, 0, 1.62)), moving, tint=skin)
    for side, y in (("l", 0.11), ("r", -0.11)):
        sgn = 1.0 if side == "l" else -1.0

        def thigh(t, y=y, sgn=sgn):
            return place(t) @ _T(_rot("y", 0.5 * sgn * math.sin(gait(t))), (0, y, hip_z)) @ _T(_rot("x", math.pi))

        def shin(t, y=y, sgn=sgn):
            knee = 0.35 * max(0.0, math.sin(gait(t) + sgn * math.pi / 2))
            up = place(t) @ _T(_rot("y", 0.5 * sgn * math.sin(gait(t))), (0, y, hip_z))
            return up @ _T(_rot("y", -knee), (0, 0, -0.45)) @ _T(_rot("x", math.pi))

        b.add(f"{name}.thigh_{side}", cylinder(0.07, 0.45, 16), thigh, moving)
        b.add(f"{name}.shin_{side}", cylinder(0.055, 0.46, 16), shin, moving)
        ya = 0.25 * sgn

        def upper(t, ya=ya, sgn=sgn):
            return (
                place(t) @ _T(_rot("y", -0.5 * sgn * math.sin(gait(t))), (0, ya, shoulder_z)) @ _T(_rot("x", math.pi))
            )

        def lower(t, ya=ya, sgn=sgn):
            up = place(t) @ _T(_rot("y", -0.5 * sgn * math.sin(gait(t))), (0, ya, shoulder_z))
            return up @ _T(_rot("y", 0.4), (0, 0, -0.3)) @ _T(_rot("x", math.pi))

        b.add(f"{name}.upperarm_{side}", cylinder(0.045, 0.3, 12), upper, moving, tint=skin)
        b.add(f"{name}.forearm_{side}", cylinder(0.04, 0.28, 12), lower, moving, tint=skin)


def _dynamic_objects(b: _Builder, centre: np.ndarray, radius: float) -> None:
    """A figure walking a circle at 0.8 m/s, a box sliding back and forth, a rolling sphere."""
    cx, cy = float(centre[0]), float(centre[1])
    w = 0.8 / radius  # angular speed, rad/s

    def walk(t):
        a = w * t
        return _T(_rot("z", a + math.pi / 2), (cx + radius * math.cos(a), cy + radius * math.sin(a), 0.0))

    _figure(b, "walker", walk, lambda t: 2 * math.pi * 0.9 * t, moving=True)

    def slide(t):
        return _T(
            _rot("z", 0.6 * t),
            (cx + 0.5 * math.sin(1.3 * t), cy - 0.3 + 0.25 * math.cos(0.7 * t), 0.2 + 0.15 * abs(math.sin(2.0 * t))),
        )

    b.add("moving_box", box(0.35, 0.3, 0.3), slide, True)
    rs = 0.18

    def roll(t):
        x = cx - 0.4 + 0.6 * math.sin(0.9 * t)
        return _T(_rot("y", (x - cx) / rs), (x, cy + 0.45, rs))

    b.add("rolling_sphere", sphere(rs), roll, True)


def _studio(b: _Builder, rng: np.random.Generator) -> dict:
    # floor and an octagon of backdrop walls at 4 m
    b.add("floor", quad(9.0, 9.0), _T())
    for k in range(8):
        a = 2 * math.pi * k / 8
        R = np.stack([[math.sin(a), -math.cos(a), 0], [0, 0, 1], [-math.cos(a), -math.sin(a), 0]]).T
        b.add(f"backdrop{k}", quad(3.4, 3.0), _T(R, (4.0 * math.cos(a), 4.0 * math.sin(a), 1.5)))
    # people-sized objects in the middle
    _figure(b, "mannequin", _static(_T(_rot("z", rng.uniform(0, 6.28)), (0.35, -0.25, 0))), lambda t: 0.6, False)
    b.add("column", cylinder(0.22, 1.7), _T(t=(-0.45, 0.4, 0)))
    b.add("crate", box(0.5, 0.45, 1.2, bottom=False), _T(_rot("z", rng.uniform(0, 1.5)), (0.5, 0.7, 0.6)))
    b.add("stool", cylinder(0.2, 0.5), _T(t=(-0.6, -0.6, 0)))
    b.add("ball", sphere(0.25), _T(t=(-0.1, -0.05, 0.25)))
    return dict(target=np.array([0.0, 0.0, 0.9]), ring_radius=2.6, ring_height=1.8, dome_radius=2.8,
                dome_elevations=(8.0, 55.0))  # fmt: skip


def _room(b: _Builder, rng: np.random.Generator) -> dict:
    L, W, H = 6.5, 5.5, 2.7
    b.add("floor", quad(L, W), _T())
    b.add("ceiling", quad(L, W), _T(_rot("x", math.pi), (0, 0, H)))
    for name, R, t, w in (
        ("wall_px", _rot("y", -math.pi / 2), (L / 2, 0, H / 2), W),
        ("wall_nx", _rot("y", math.pi / 2), (-L / 2, 0, H / 2), W),
        ("wall_py", _rot("x", math.pi / 2), (0, W / 2, H / 2), L),
        ("wall_ny", _rot("x", -math.pi / 2), (0, -W / 2, H / 2), L),
    ):
        # quad faces +z; rotate so it faces the room centre
        Rw = R if name in ("wall_px", "wall_nx") else R
        b.add(name, quad(w, H) if name.endswith("y") else quad(H, w), _T(Rw, t))
    j = lambda s: rng.uniform(-s, s)  # noqa: E731
    # table: top + four thin legs (thin parts)
    tx, ty = 0.3 + j(0.1), -0.2 + j(0.1)
    b.add("table_top", box(1.2, 0.8, 0.04), _T(t=(tx, ty, 0.75)))
    for sx in (-0.55, 0.55):
        for sy in (-0.35, 0.35):
            b.add(
                "table_leg", box(0.04, 0.04, 0.73, bottom=False), _T(t=(tx + sx, ty + sy, 0.365)), tint=(0.4, 0.3, 0.2)
            )
    # chair
    cx, cy = tx - 0.9, ty + j(0.2)
    b.add("chair_seat", box(0.45, 0.45, 0.04), _T(t=(cx, cy, 0.45)))
    b.add("chair_back", box(0.04, 0.45, 0.5), _T(t=(cx - 0.2, cy, 0.72)))
    for sx in (-0.2, 0.2):
        for sy in (-0.2, 0.2):
            b.add("chair_leg", cylinder(0.015, 0.43, 8, caps=False), _T(t=(cx + sx, cy + sy, 0)))
    # shelf against the +y wall: two sides, four boards (thin parts)
    sx0 = -1.6 + j(0.2)
    for dx in (-0.5, 0.5):
        b.add("shelf_side", box(0.02, 0.35, 1.8, bottom=False), _T(t=(sx0 + dx, W / 2 - 0.2, 0.9)))
    for z in (0.05, 0.6, 1.15, 1.7):
        b.add("shelf_board", box(1.0, 0.35, 0.02), _T(t=(sx0, W / 2 - 0.2, z)))
    b.add("shelf_box", box(0.3, 0.25, 0.25, bottom=False), _T(t=(sx0 - 0.2, W / 2 - 0.2, 0.74)))
    # boxes, cylinders, a lamp with a thin pole
    for k in range(4):
        s = rng.uniform(0.25, 0.6, 3)
        ang = rng.uniform(0, 2 * math.pi)
        pos = (rng.uniform(-2.6, 2.6), rng.uniform(-2.2, 2.2))
        if abs(pos[0]) < 1.4 and abs(pos[1]) < 1.2:
            pos = (pos[0] + math.copysign(1.4, pos[0]), pos[1])
        b.add(f"box{k}", box(*s, bottom=False), _T(_rot("z", ang), (pos[0], pos[1], s[2] / 2)))
    b.add("bin", cylinder(0.18, 0.5), _T(t=(1.8 + j(0.2), 1.5 + j(0.2), 0)))
    b.add("pillar", cylinder(0.12, H, caps=False), _T(t=(-1.2 + j(0.2), -1.4 + j(0.2), 0)))
    lx, ly = 2.2 + j(0.2), -1.8 + j(0.2)
    b.add("lamp_pole", cylinder(0.012, 1.5, 8, caps=False), _T(t=(lx, ly, 0)))
    b.add("lamp_base", cylinder(0.15, 0.03), _T(t=(lx, ly, 0)))
    b.add("lamp_shade", sphere(0.16), _T(t=(lx, ly, 1.6)))
    b.add("sofa", box(0.9, 2.0, 0.45, bottom=False), _T(t=(-L / 2 + 0.5, 0.3, 0.225)))
    b.add("sofa_back", box(0.2, 2.0, 0.45, bottom=False), _T(t=(-L / 2 + 0.1, 0.3, 0.675)))
    return dict(target=np.array([0.0, 0.0, 0.8]), ring_radius=2.1, ring_height=1.7, dome_radius=2.1,
                dome_elevations=(10.0, 45.0))  # fmt: skip


def _wall(b: _Builder, rng: np.random.Generator) -> dict:
    # one flat wall in the plane x = 2 facing -x (cameras at the origin look along +x)
    b.add("wall", quad(8.0, 6.0), _T(_rot("y", -math.pi / 2), (2.0, 0, 1.0)))
    return dict(target=np.array([2.0, 0.0, 1.0]), ring_radius=2.0, ring_height=1.0, dome_radius=2.0,
                dome_elevations=(0.0, 0.0))  # fmt: skip


# the building blocks under public names, for the scenes of other modules (synth.studios)
Builder, figure, rot, static, transform = _Builder, _figure, _rot, _static, _T


def build_scene(name: str, seed: int, dynamic: bool, n_textures: int) -> Scene:
    """The named scene, laid out from ``seed`` (same seed, same scene); 'symstudio' and 'farroom'
    are built by ``synth.studios.build_studio``."""
    rng = np.random.default_rng([seed, 0x5CE7E])
    b = _Builder(rng, n_textures)
    hints = {"studio": _studio, "room": _room, "wall": _wall}[name](b, rng)
    if dynamic and name != "wall":
        _dynamic_objects(b, hints["target"], 0.9 if name == "studio" else 1.0)
    return Scene(name=name, parts=tuple(b.parts), **hints)
