"""Scenes that break target-free calibration: a symmetric studio and a far-range room.

``symstudio``: a regular N-gon room (N = 8..12 from the seed) whose wall panels, floor sectors and
ceiling sectors repeat exactly (same texture, same texture offset, same tint, same geometry every
360/N deg; a column at every corner), with a small asymmetric figure at the centre (a 1.75 m
figure, a coloured bag beside it, a box at its feet), still, or with ``SimConfig.dynamic`` turning,
stepping and swinging its limbs from frame to frame. Only the figure tells the N rotations of the
room apart. Cameras: one ring (``SimConfig.rig`` 'ring') or two rings (otherwise), evenly spaced
with the room's symmetry, looking at the figure (``studio_eyes``).

``farroom``: an 8.4 m square room with low-texture walls, floor and ceiling (the plain textures,
``PLAIN_CONTRAST`` of a normal texture's contrast), a few textured pieces of furniture along the
walls, and a person walking across the middle (a straight line there and back at 1 m/s, whatever
``SimConfig.dynamic`` says). Cameras: 3.6 m from the centre, 120 deg apart, 1.8-2.1 m high
(3.5-4 m from the person), best with ``noise='kinect2'``.

Both are built by ``build_studio`` (names in ``synth.config.SCENES``; the Simulator dispatches).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from fuseflow.synth.scene import Builder, MeshData, Scene, box, cylinder, figure, quad, rot, static, transform

__all__ = [
    "STUDIO_SCENES",
    "build_studio",
    "symmetric_studio",
    "far_room",
    "studio_eyes",
    "far_eyes",
    "sides_of",
    "PLAIN_CONTRAST",
    "plain_textures",
]

#: The scenes of this module.
STUDIO_SCENES = ("symstudio", "farroom")

#: Contrast of the plain (low-texture) surfaces of ``farroom`` relative to a normal texture.
PLAIN_CONTRAST = 0.12

SYM_APOTHEM = 3.6  # metres from the centre to each wall panel
SYM_HEIGHT = 3.0  # ceiling height
SYM_RING = ((2.6, 1.3), (2.3, 2.3))  # (radius, height) of the lower and upper camera rings


def sides_of(seed: int) -> int:
    """Number of sides (8..12) of the symmetric studio of ``seed``."""
    return 8 + int(np.random.default_rng([seed, 0x5105]).integers(5))


def _sector(radius: float, n: int) -> MeshData:
    """One floor sector: the triangle from the centre to two corners of a regular n-gon of
    circumradius ``radius``, in the local xy plane facing +z, centred on the +x axis;
    texture coordinates are the local metres (the same in every sector: an exact repeat)."""
    h = math.pi / n
    v = np.array([[0, 0, 0], [radius * math.cos(-h), radius * math.sin(-h), 0],
                  [radius * math.cos(h), radius * math.sin(h), 0]], float)  # fmt: skip
    tris = np.array([[0, 1, 2]])
    return MeshData(v, tris, v[tris][..., :2] + radius)


def _repeat(b: Builder, name: str, mesh: MeshData, local: np.ndarray, n: int, texture: int, tint) -> None:
    """``mesh`` at world pose Rz(2 pi k / n) @ local for k < n, all with one texture, offset and tint."""
    for k in range(n):
        b.add(f"{name}{k}", mesh, transform(rot("z", 2 * math.pi * k / n)) @ local, texture=texture, tint=tint)
        b.parts[-1] = replace(b.parts[-1], uv_offset=np.zeros(2))


#: ``symstudio`` with ``SimConfig.dynamic``: per frame the figure turns by this (deg) about its
#: vertical axis, steps this far (metres) along where it faces, and its arms and legs swing by
#: this phase (rad); frame 0 is the still scene's.
SYM_TURN_DEG, SYM_STEP_M, SYM_SWING_RAD = 12.0, 0.06, 0.6


def symmetric_studio(b: Builder, rng: np.random.Generator, seed: int, dynamic: bool = False, fps: float = 30.0) -> dict:
    """The ``symstudio`` scene (module docstring); returns the Scene's layout hints. ``dynamic``:
    the figure moves between frames (``SYM_TURN_DEG``, ``SYM_STEP_M``, ``SYM_SWING_RAD`` per frame
    at ``fps``); the bag and the crate stay where the still scene has them."""
    n = sides_of(seed)
    a, H = SYM_APOTHEM, SYM_HEIGHT
    r = a / math.cos(math.pi / n)  # circumradius
    width = 2 * a * math.tan(math.pi / n)
    tex_wall, tex_floor, tex_ceil = (int(t) for t in rng.permutation(b.n_textures)[:3])
    grey = np.array([0.85, 0.85, 0.85])
    # the wall panel facing the centre from +x: the quad's x along -y, its y up, its front (+z) to -x
    wall = transform(np.array([[0.0, 0, -1], [-1, 0, 0], [0, 1, 0]]), (a, 0, H / 2))
    _repeat(b, "panel", quad(width, H), wall, n, tex_wall, grey)
    _repeat(b, "floor", _sector(r, n), np.eye(4), n, tex_floor, grey)
    _repeat(b, "ceiling", _sector(r, n), transform(rot("x", math.pi), (0, 0, H)), n, tex_ceil, grey)
    # a column at every corner (repeated geometry, not only texture)
    corner = transform(rot("z", math.pi / n)) @ transform(t=(r - 0.2, 0, 0))
    _repeat(b, "column", cylinder(0.12, H, 16, caps=False), corner, n, tex_wall, np.array([0.6, 0.6, 0.65]))
    # the asymmetric subject: a figure facing a seeded direction, a bag beside it, a box at its feet
    yaw = rng.uniform(0, 2 * math.pi)
    place = transform(rot("z", yaw), (0.1, -0.05, 0.0))
    if dynamic:

        def pose(t: float) -> np.ndarray:
            k = t * fps  # frames since the first
            return place @ transform(rot("z", math.radians(SYM_TURN_DEG) * k), (SYM_STEP_M * k, 0.0, 0.0))

        figure(b, "figure", pose, lambda t: 0.5 + SYM_SWING_RAD * fps * t, True)
    else:
        figure(b, "figure", static(place), lambda t: 0.5, False)
    b.add("bag", box(0.3, 0.18, 0.4), place @ transform(t=(0.05, 0.42, 0.2)), tint=np.array([0.9, 0.3, 0.2]))
    b.add("crate", box(0.35, 0.3, 0.25), place @ transform(rot("z", 0.4), (0.45, -0.3, 0.125)),
          tint=np.array([0.2, 0.4, 0.9]))  # fmt: skip
    return dict(target=np.array([0.0, 0.0, 1.0]), ring_radius=SYM_RING[0][0], ring_height=SYM_RING[0][1],
                dome_radius=SYM_RING[1][0], dome_elevations=(0.0, 0.0), symmetry=n)  # fmt: skip


def studio_eyes(n_cameras: int, two_rings: bool, sides: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """(eye, target) of the symmetric studio's cameras: one ring of ``n_cameras``, or two rings
    (the lower with ceil(n/2), the upper with the rest, half a spacing apart), at angles that
    are multiples of the room's 360/sides deg where the counts allow (the rig shares the room's
    symmetry), looking at the figure's chest."""
    counts = [n_cameras] if not two_rings else [math.ceil(n_cameras / 2), n_cameras // 2]
    out = []
    for ring, count in enumerate(counts):
        radius, height = SYM_RING[ring]
        step = 2 * math.pi / count
        phase = 0.5 * step * ring
        if sides % count == 0:
            phase = round(phase / (2 * math.pi / sides)) * 2 * math.pi / sides
        for k in range(count):
            ang = phase + step * k
            eye = np.array([radius * math.cos(ang), radius * math.sin(ang), height])
            out.append((eye, np.array([0.0, 0.0, 1.0])))
    return out


def plain_textures(textures: np.ndarray) -> np.ndarray:
    """Two low-contrast textures (``PLAIN_CONTRAST``) made from the first two of ``textures``:
    the plain walls of ``farroom`` (appended after the normal ones; two so that the second
    texture layer of a plain surface, the next texture, is plain too)."""
    t = textures[:2].astype(np.float32)
    mean = t.mean(axis=(1, 2), keepdims=True)
    plain = 0.5 * mean + 0.5 * 170.0 + PLAIN_CONTRAST * (t - mean)
    return np.clip(np.rint(plain), 0, 255).astype(np.uint8)


FAR_HALF = 4.2  # half the side of the far room, metres
FAR_CAMERA_RADIUS = 3.6


def far_room(b: Builder, rng: np.random.Generator, plain: int) -> dict:
    """The ``farroom`` scene (module docstring); ``plain`` is the index of the first plain texture."""
    L, H = 2 * FAR_HALF, 2.8
    off = np.array([0.82, 0.8, 0.78])
    b.add("floor", quad(L, L), transform(), texture=plain, tint=off)
    b.add("ceiling", quad(L, L), transform(rot("x", math.pi), (0, 0, H)), texture=plain, tint=off)
    for k in range(4):
        ang = math.pi / 2 * k
        wall = transform(rot("z", ang)) @ transform(t=(FAR_HALF, 0, H / 2)) @ transform(rot("y", -math.pi / 2))
        b.add(f"wall{k}", quad(H, L), wall, texture=plain, tint=off)
    # a few textured pieces along the walls (a real room is not empty), away from the cameras
    for k in range(4):
        ang = rng.uniform(0, 2 * math.pi)
        d = FAR_HALF - 0.5
        pos = (d * math.cos(ang), d * math.sin(ang))
        s = rng.uniform(0.4, 0.9, 3)
        b.add(f"cabinet{k}", box(*s, bottom=False), transform(rot("z", ang), (pos[0], pos[1], s[2] / 2)))
    b.add("table", box(1.0, 0.6, 0.05), transform(rot("z", rng.uniform(0, 3)), (-1.6, 1.5, 0.74)))
    # the person: walks along a line through the centre (1 m/s, there and back over 2.4 m)
    head = rng.uniform(0, math.pi)
    d = np.array([math.cos(head), math.sin(head)])

    def walk(t: float) -> np.ndarray:
        u = (t % 4.8) / 2.4
        s = -1.2 + 2.4 * (u if u <= 1 else 2 - u)
        yaw = head if u <= 1 else head + math.pi
        return transform(rot("z", yaw), (d[0] * s, d[1] * s, 0.0))

    figure(b, "person", walk, lambda t: 2 * math.pi * 0.9 * t, moving=True)
    return dict(target=np.array([0.0, 0.0, 1.0]), ring_radius=FAR_CAMERA_RADIUS, ring_height=1.9,
                dome_radius=FAR_CAMERA_RADIUS, dome_elevations=(0.0, 0.0))  # fmt: skip


def far_eyes(n_cameras: int, rng: np.random.Generator) -> list[tuple[np.ndarray, np.ndarray]]:
    """(eye, target) of the far room's cameras: ``n_cameras`` evenly spaced (120 deg for 3) on a
    3.6 m circle at 1.8-2.1 m, looking at the middle of the person's path at 1 m height."""
    out = []
    phase = rng.uniform(0, 2 * math.pi)
    for k in range(n_cameras):
        ang = phase + 2 * math.pi * k / n_cameras
        eye = np.array([FAR_CAMERA_RADIUS * math.cos(ang), FAR_CAMERA_RADIUS * math.sin(ang), rng.uniform(1.8, 2.1)])
        out.append((eye, np.array([0.0, 0.0, 1.0])))
    return out


def build_studio(name: str, seed: int, n_textures: int, dynamic: bool = False, fps: float = 30.0) -> Scene:
    """The scene ``name`` ('symstudio' or 'farroom') laid out from ``seed``, with the same random
    stream as ``scene.build_scene``; 'farroom' uses the two plain textures at indices
    ``n_textures`` and ``n_textures + 1`` (``plain_textures``). Moving parts are their own: the
    far room's person walks whatever ``dynamic`` says; the symmetric studio's figure moves with
    ``dynamic`` (``symmetric_studio``), the same layout and the same first frame either way."""
    rng = np.random.default_rng([seed, 0x5CE7E])
    b = Builder(rng, n_textures)
    if name == "symstudio":
        hints = symmetric_studio(b, rng, seed, dynamic, fps)
    else:
        hints = far_room(b, rng, n_textures)
    return Scene(name=name, parts=tuple(b.parts), **hints)
