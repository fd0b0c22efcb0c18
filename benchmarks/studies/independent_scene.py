"""A repeating studio rendered by numpy ray casting, written apart from the simulator's studio
families (``fuseflow.synth``) so that calibration is measured on scenes nobody tuned it on.

The scene (world: z up, metres, origin on the floor at the room's centre):

* a regular N-gon room (N in 6, 8, 10, 12; circumradius 3.5-5 m; height 2.6-3.2 m) whose wall
  panels, floor sectors and ceiling sectors repeat exactly with period 360/N degrees: every wall
  carries the same raster texture, the floor and the ceiling are textured in the coordinates of
  one sector folded onto all of them, and the light (ambient + a point light under the centre of
  the ceiling) is rotationally symmetric;
* a seated figure of boxes, cylinders and a sphere (chair, legs, torso, arms, head; 1.2-1.4 m to
  the top of the head) at the centre, facing a random direction; ``pose(t)`` moves its torso,
  head and arms between frames;
* 5-10 cameras on one or two rings 2.5-3.5 m from the centre, 1.2-2.4 m high, looking at the
  figure with a few degrees of yaw / pitch / roll jitter.

Textures come from this module's own functions: panels of printed-poster-like blocks, vertical
stripes, bands and smooth noise; floor sectors of rings, checker and inlay blocks; ceilings of
light panels between dark beams.

Sensors (:data:`SENSORS`): Kinect v2 (512x424, fx ~365), Azure Kinect NFOV (640x576, fx ~504,
the octagonal valid region) and a 320x240 Kinect-v2-like camera. Depth is z-depth with noise
growing with distance, flying pixels at depth edges, missing pixels on dark and grazing
surfaces and beyond the range; colour is registered to depth (one ray per pixel) with a gain and
white balance per camera, vignetting and pixel noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

# ----------------------------------------------------------------------------- sensors


@dataclass(frozen=True)
class Sensor:
    """A depth camera model: resolution, focal length, depth noise sigma(z) = a + b z^2 (m),
    nominal and maximal range (m), the preset name written into rig.json."""

    name: str
    width: int
    height: int
    fx: float
    sigma_a: float
    sigma_b: float
    nominal: float
    max_range: float
    preset: str
    octagon: bool = False


SENSORS = {
    "320x240": Sensor("kinect2-320", 320, 240, 228.0, 0.002, 0.0008, 4.5, 8.0, "kinect_v2"),
    "512x424": Sensor("kinect2", 512, 424, 365.5, 0.0015, 0.0006, 4.5, 8.0, "kinect_v2"),
    "640x576": Sensor("azure-nfov", 640, 576, 504.0, 0.001, 0.0004, 3.9, 5.5, "azure_kinect", octagon=True),
}


# ----------------------------------------------------------------------------- small maths


def rot(axis: str, deg: float) -> np.ndarray:
    """3x3 rotation about a world axis by ``deg`` degrees (right-handed)."""
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    i, j = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def look_at(centre: np.ndarray, target: np.ndarray, roll_deg: float = 0.0) -> np.ndarray:
    """T_cam_world (camera-from-world, OpenCV axes: x right, y down, z forward) of a camera at
    ``centre`` looking at ``target`` with world z up, rolled by ``roll_deg`` about its axis."""
    z = np.asarray(target, float) - centre
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R_wc = np.stack([x, y, z], axis=1) @ rot("z", roll_deg)  # world-from-camera (roll about cam z)
    T = np.eye(4)
    T[:3, :3] = R_wc.T
    T[:3, 3] = -R_wc.T @ centre
    return T


def smooth_noise(rng: np.random.Generator, n: int, scale: int) -> np.ndarray:
    """1-D smooth noise of length n in [0, 1]: random values every ``scale`` samples, cosine
    interpolated, periodic over n."""
    k = max(2, n // max(1, scale))
    v = rng.random(k)
    x = np.arange(n) * k / n
    i = np.floor(x).astype(int)
    f = (1 - np.cos(np.pi * (x - i))) / 2
    return v[i % k] * (1 - f) + v[(i + 1) % k] * f


# ----------------------------------------------------------------------------- textures

PX_PER_M = 50.0  # texels per metre of every raster texture (2 cm texels)


def _palette(rng: np.random.Generator, muted: bool) -> np.ndarray:
    """A random RGB colour in [0, 1]: muted (walls, floors) or saturated (posters, clothes)."""
    hue = rng.random()
    sat = rng.uniform(0.1, 0.35) if muted else rng.uniform(0.5, 0.95)
    val = rng.uniform(0.35, 0.8) if muted else rng.uniform(0.15, 0.95)
    i = int(hue * 6) % 6
    f = hue * 6 - int(hue * 6)
    p, q, t = val * (1 - sat), val * (1 - f * sat), val * (1 - (1 - f) * sat)
    return np.array([(val, t, p), (q, val, p), (p, val, t), (p, q, val), (t, p, val), (val, p, q)][i])


def _poster(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """A printed-poster-like block: a background split into coloured rectangles, with rows of
    dark 'text' dashes."""
    img = np.empty((h, w, 3))
    img[:] = _palette(rng, False)
    for _ in range(rng.integers(2, 6)):
        y0, x0 = rng.integers(0, max(1, h - 4)), rng.integers(0, max(1, w - 4))
        y1, x1 = y0 + rng.integers(3, max(4, h // 2)), x0 + rng.integers(3, max(4, w // 2))
        img[y0:y1, x0:x1] = _palette(rng, False)
    rows = range(int(h * 0.65), h - 2, 3)
    for r in rows:
        x = 2
        while x < w - 3:
            n = int(rng.integers(2, 7))
            img[r, x : min(w - 2, x + n)] = rng.uniform(0.02, 0.12)
            x += n + int(rng.integers(1, 3))
    return img


def wall_texture(rng: np.random.Generator, width_m: float, height_m: float) -> np.ndarray:
    """The texture every wall panel carries: (rows = height from the floor up, cols = along
    the wall), RGB in [0, 1]."""
    h, w = max(8, int(height_m * PX_PER_M)), max(8, int(width_m * PX_PER_M))
    base = _palette(rng, True)
    img = np.tile(base, (h, w, 1))
    band = smooth_noise(rng, w, int(rng.integers(8, 40)))  # smooth luminance bands along the wall
    img *= (0.8 + 0.35 * band)[None, :, None]
    if rng.random() < 0.6:  # vertical stripes
        period = int(rng.integers(6, 30))
        duty = rng.uniform(0.2, 0.6)
        stripe = (np.arange(w) % period) < duty * period
        img[:, stripe] *= rng.uniform(0.55, 0.85)
    skirting = int(rng.uniform(0.1, 0.2) * PX_PER_M)
    img[:skirting] = _palette(rng, True) * rng.uniform(0.3, 0.7)
    rail = int(rng.uniform(0.8, 1.2) * PX_PER_M)
    img[rail : rail + 2] = rng.uniform(0.05, 0.9)
    for _ in range(rng.integers(2, 6)):  # posters (rows counted from the floor: flipped on paste)
        ph, pw = int(rng.uniform(0.4, 1.4) * PX_PER_M), int(rng.uniform(0.3, 1.2) * PX_PER_M)
        y0 = int(rng.uniform(0.5, max(0.55, height_m - 0.3)) * PX_PER_M) - ph
        x0 = int(rng.integers(0, max(1, w - pw)))
        y0 = max(skirting + 2, min(h - ph - 1, y0))
        img[y0 : y0 + ph, x0 : x0 + pw] = _poster(rng, ph, pw)[::-1]
    img[:, :2] *= 0.3  # the seams between panels
    img[:, -2:] *= 0.3
    if rng.random() < 0.5:  # a checker strip
        y0 = int(rng.uniform(1.3, 1.8) * PX_PER_M)
        sq = int(rng.integers(3, 8))
        yy, xx = np.mgrid[0 : min(sq * 3, h - y0), 0:w]
        img[y0 : y0 + yy.shape[0]][((yy // sq + xx // sq) % 2) == 0] *= 0.35
    return np.clip(img, 0, 1)


def sector_texture(rng: np.random.Generator, radius: float, half_deg: float, ceiling: bool) -> np.ndarray:
    """The texture of one floor (or ceiling) sector in its own frame: rows = x from 0 to the
    circumradius along the sector's bisector, cols = y from -r sin(half) to +r sin(half)."""
    h = int(radius * PX_PER_M) + 2
    half_w = radius * math.sin(math.radians(half_deg))
    w = int(2 * half_w * PX_PER_M) + 2
    yy, xx = np.mgrid[0:h, 0:w].astype(float) / PX_PER_M
    yy, xx = yy, xx - half_w  # yy: along the bisector, xx: across
    r = np.hypot(yy, xx)
    img = np.tile(_palette(rng, True) * (0.5 if ceiling else 1.0), (h, w, 1))
    if ceiling:
        beam = int(rng.integers(8, 20))
        light = (np.abs(((yy * PX_PER_M) % (beam * 3)) - beam * 1.5) < beam * 0.5) & (np.abs(xx) < 0.25 * r + 0.1)
        img[light] = rng.uniform(0.85, 1.0)
        img[(yy * PX_PER_M).astype(int) % beam == 0] *= 0.3
        return np.clip(img, 0, 1)
    ring_w = rng.uniform(0.15, 0.5)
    img[(r // ring_w) % 2 == 1] *= rng.uniform(0.6, 0.85)  # concentric rings
    sq = rng.uniform(0.12, 0.35)
    checker = ((yy // sq + xx // sq) % 2 == 0) & (r > rng.uniform(1.0, 2.0)) & (r < rng.uniform(2.2, 3.2))
    img[checker] = img[checker] * 0.5 + 0.5 * _palette(rng, False)
    for _ in range(rng.integers(1, 4)):  # inlay blocks (tape marks, logos)
        cy, cx = rng.uniform(0.8, radius * 0.8), rng.uniform(-0.3, 0.3)
        m = (np.abs(yy - cy) < rng.uniform(0.05, 0.3)) & (np.abs(xx - cx) < rng.uniform(0.05, 0.25))
        img[m] = _palette(rng, False)
    img[np.abs(xx) > (yy * math.tan(math.radians(half_deg)) - 0.02)] *= 0.4  # sector seams
    return np.clip(img, 0, 1)


def sample(tex: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Bilinear lookup of ``tex`` at fractional texel coordinates (clamped at the border)."""
    h, w = tex.shape[:2]
    r = np.clip(rows, 0, h - 1.001)
    c = np.clip(cols, 0, w - 1.001)
    r0, c0 = r.astype(int), c.astype(int)
    fr, fc = (r - r0)[:, None], (c - c0)[:, None]
    top = tex[r0, c0] * (1 - fc) + tex[r0, c0 + 1] * fc
    bot = tex[r0 + 1, c0] * (1 - fc) + tex[r0 + 1, c0 + 1] * fc
    return top * (1 - fr) + bot * fr


# ----------------------------------------------------------------------------- the figure


@dataclass
class Prim:
    """A primitive of the figure: kind 'box' (half extents), 'cyl' (radius, half length along
    local z) or 'sphere' (radius); world-from-local rotation R and centre c; a colour and a
    stripe period (0: none) in local z."""

    kind: str
    size: tuple[float, ...]
    R: np.ndarray
    c: np.ndarray
    colour: np.ndarray
    stripe: float = 0.0


@dataclass
class Figure:
    """The seated figure's fixed parameters: facing (deg), body sizes and colours."""

    facing: float
    scale: float
    colours: dict[str, np.ndarray] = field(default_factory=dict)
    stripes: dict[str, float] = field(default_factory=dict)


def make_figure(rng: np.random.Generator) -> Figure:
    """A figure of random facing, size (1.2-1.4 m seated) and clothes."""
    cols = {k: _palette(rng, k in ("chair", "skin")) for k in ("chair", "shirt", "trousers", "skin", "shoes", "hair")}
    cols["skin"] = np.array([0.8, 0.6, 0.5]) * rng.uniform(0.5, 1.1)
    cols["shoes"] = cols["shoes"] * 0.3
    stripes = {"shirt": float(rng.choice([0.0, 0.04, 0.07])), "trousers": float(rng.choice([0.0, 0.0, 0.05]))}
    return Figure(float(rng.uniform(0, 360)), float(rng.uniform(0.93, 1.07)), cols, stripes)


def _limb(a: np.ndarray, b: np.ndarray, radius: float, colour: np.ndarray, stripe: float = 0.0) -> Prim:
    """A cylinder from point a to point b."""
    d = b - a
    length = float(np.linalg.norm(d))
    z = d / length
    x = np.cross(z, [0.0, 0.0, 1.0] if abs(z[2]) < 0.9 else [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z], axis=1)
    return Prim("cyl", (radius, length / 2), R, (a + b) / 2, colour, stripe)


def figure_prims(fig: Figure, motion: tuple[float, float, float, float]) -> list[Prim]:
    """The figure's primitives in world coordinates; ``motion`` = (torso yaw, head yaw, left arm
    lift, right arm lift) in degrees."""
    s, C = fig.scale, fig.colours
    Rf = rot("z", fig.facing)  # the figure faces its local +x
    Rt = Rf @ rot("z", motion[0])
    seat_h = 0.45 * s

    def w(p, R=Rf):
        return R @ np.asarray(p, float)

    prims = [
        Prim("box", (0.22 * s, 0.22 * s, 0.025), Rf, w([0, 0, seat_h - 0.025]), C["chair"]),
        Prim("box", (0.02, 0.22 * s, 0.25 * s), Rf, w([-0.22 * s, 0, seat_h + 0.25 * s]), C["chair"]),
    ]
    for sx in (-1, 1):
        for sy in (-1, 1):
            leg = [0.19 * s * sx, 0.19 * s * sy, 0]
            prims.append(_limb(w(leg), w([leg[0], leg[1], seat_h - 0.05]), 0.018, C["chair"] * 0.6))
    for sy in (-1, 1):  # thighs (horizontal boxes), shins, feet
        y = 0.1 * s * sy
        prims.append(
            Prim("box", (0.22 * s, 0.07 * s, 0.07 * s), Rf, w([0.05 * s, y, seat_h + 0.07 * s]), C["trousers"])
        )
        knee = w([0.25 * s, y, seat_h + 0.03])
        prims.append(_limb(w([0.27 * s, y, 0.08]), knee, 0.055 * s, C["trousers"], fig.stripes["trousers"]))
        prims.append(Prim("box", (0.12 * s, 0.05 * s, 0.04), Rf, w([0.33 * s, y, 0.04]), C["shoes"]))
    hip = np.array([0, 0, seat_h + 0.12 * s])
    prims.append(Prim("box", (0.11 * s, 0.18 * s, 0.28 * s), Rt, hip + Rt @ [-0.02, 0, 0.28 * s], C["shirt"]))
    neck_top = hip + np.array([0, 0, 0.62 * s])
    prims.append(_limb(neck_top - [0, 0, 0.07], neck_top + [0, 0, 0.03], 0.05 * s, C["skin"]))
    Rh = Rt @ rot("z", motion[1])
    head = neck_top + np.array([0, 0, 0.13 * s])
    prims.append(Prim("sphere", (0.105 * s,), Rh, head, C["skin"]))
    prims.append(Prim("box", (0.07 * s, 0.1 * s, 0.04 * s), Rh, head + Rh @ [-0.03, 0, 0.07 * s], C["hair"]))
    prims.append(Prim("box", (0.03, 0.05, 0.025), Rh, head + Rh @ [0.1 * s, 0, 0.0], C["skin"] * 0.8))  # nose
    for sy, lift in ((1, motion[2]), (-1, motion[3])):
        shoulder = hip + Rt @ [0, 0.23 * s * sy, 0.5 * s]
        elbow = shoulder + Rt @ (rot("y", -lift) @ [0, 0.02 * sy, -0.28 * s])
        hand = elbow + Rt @ (rot("y", -lift * 0.5 - 60) @ [0, 0, -0.26 * s])
        prims.append(_limb(shoulder, elbow, 0.045 * s, C["shirt"], fig.stripes["shirt"]))
        prims.append(_limb(elbow, hand, 0.04 * s, C["skin"]))
        prims.append(Prim("sphere", (0.045 * s,), Rt, hand, C["skin"]))
    return prims


def figure_motion(rng: np.random.Generator, frames: int, moving: bool) -> list[tuple[float, float, float, float]]:
    """Per frame (torso yaw, head yaw, left arm lift, right arm lift), degrees: still, or a random
    walk of 5-15 deg torso turns and 10-35 deg arm moves per frame."""
    m = np.array([0.0, rng.uniform(-20, 20), rng.uniform(0, 40), rng.uniform(0, 40)])
    out = [tuple(m)]
    for _ in range(frames - 1):
        if moving:
            step = rng.uniform([5, 5, 10, 10], [15, 20, 35, 35]) * rng.choice([-1, 1], 4)
            m = np.clip(m + step, [-45, -60, -10, -10], [45, 60, 120, 120])
        out.append(tuple(m))
    return out


# ----------------------------------------------------------------------------- the room


@dataclass
class Room:
    """A regular N-gon room: ``sides``, circumradius, height, the angle of its first corner
    (deg) and the three textures that repeat with period 360/N."""

    sides: int
    radius: float
    height: float
    phase: float
    wall: np.ndarray
    floor: np.ndarray
    ceiling: np.ndarray

    @property
    def period(self) -> float:
        return 360.0 / self.sides

    @property
    def apothem(self) -> float:
        return self.radius * math.cos(math.pi / self.sides)


def make_room(rng: np.random.Generator, sides: int | None = None) -> Room:
    """A random room: 6, 8, 10 or 12 sides, circumradius 3.5-5 m, height 2.6-3.2 m."""
    n = int(sides or rng.choice([6, 8, 10, 12]))
    radius = float(rng.uniform(3.5, 5.0))
    if n == 6:
        radius = max(radius, 4.5)  # keeps the apothem >= 3.9 m: the outer ring (<= 3.5 m) fits
    height = float(rng.uniform(2.6, 3.2))
    side = 2 * radius * math.sin(math.pi / n)
    half = 180.0 / n
    return Room(n, radius, height, float(rng.uniform(0, 360)), wall_texture(rng, side, height),
                sector_texture(rng, radius, half, False), sector_texture(rng, radius, half, True))  # fmt: skip


def _room_hit(room: Room, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distance along unit rays d from o (inside the room) to the room, the unit normal facing
    the room, and the albedo there."""
    n = d.shape[0]
    t = np.full(n, np.inf)
    which = np.full(n, -1)  # 0..N-1 walls, N floor, N+1 ceiling
    for k in range(room.sides):
        a = math.radians(room.phase + (k + 0.5) * room.period)
        nk = np.array([math.cos(a), math.sin(a), 0.0])
        den = d @ nk
        tk = np.where(den > 1e-9, (room.apothem - o @ nk) / np.where(den > 1e-9, den, 1), np.inf)
        better = tk < t
        t[better], which[better] = tk[better], k
    for k, z in ((room.sides, 0.0), (room.sides + 1, room.height)):
        den = d[:, 2]
        ok = (den < -1e-9) if z == 0.0 else (den > 1e-9)
        tk = np.where(ok, (z - o[2]) / np.where(ok, den, 1), np.inf)
        better = tk < t
        t[better], which[better] = tk[better], k
    p = o + t[:, None] * d
    normal = np.zeros((n, 3))
    albedo = np.zeros((n, 3))
    ang = (np.degrees(np.arctan2(p[:, 1], p[:, 0])) - room.phase) % 360.0
    k = np.floor(ang / room.period)  # sector index; the canonical sector is k = 0
    back = np.radians(-(room.phase + (k + 0.5) * room.period))
    x_s = p[:, 0] * np.cos(back) - p[:, 1] * np.sin(back)  # along the sector's bisector
    y_s = p[:, 0] * np.sin(back) + p[:, 1] * np.cos(back)  # across it
    wall = which < room.sides
    a = np.radians(room.phase + (which[wall] + 0.5) * room.period)
    normal[wall] = -np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], 1)
    side = 2 * room.radius * math.sin(math.pi / room.sides)
    albedo[wall] = sample(room.wall, p[wall, 2] * PX_PER_M, (y_s[wall] + side / 2) * PX_PER_M)
    for k2, tex, nz in ((room.sides, room.floor, 1.0), (room.sides + 1, room.ceiling, -1.0)):
        m = which == k2
        normal[m] = [0, 0, nz]
        half_w = room.radius * math.sin(math.pi / room.sides)
        albedo[m] = sample(tex, x_s[m] * PX_PER_M, (y_s[m] + half_w) * PX_PER_M)
    return t, normal, albedo


def _prim_hit(pr: Prim, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distance to a primitive (inf: missed), its world normal and the local hit point."""
    ol = pr.R.T @ (o - pr.c)
    dl = d @ pr.R
    n = d.shape[0]
    nl = np.zeros((n, 3))
    if pr.kind == "box":
        e = np.asarray(pr.size)
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = (-e - ol) / dl, (e - ol) / dl
        tmin, tmax = np.minimum(t1, t2), np.maximum(t1, t2)
        axis = np.argmax(tmin, axis=1)
        tn, tf = tmin.max(1), tmax.min(1)
        t = np.where((tn <= tf) & (tn > 1e-6), tn, np.inf)
        nl[np.arange(n), axis] = -np.sign(dl[np.arange(n), axis])
    elif pr.kind == "sphere":
        b = dl @ ol
        disc = b * b - (ol @ ol - pr.size[0] ** 2)
        t = np.where(disc > 0, -b - np.sqrt(np.maximum(disc, 0)), np.inf)
        t = np.where(t > 1e-6, t, np.inf)
        nl = (ol + np.where(np.isfinite(t), t, 0)[:, None] * dl) / pr.size[0]
    else:
        r, hl = pr.size
        a = dl[:, 0] ** 2 + dl[:, 1] ** 2
        b = dl[:, 0] * ol[0] + dl[:, 1] * ol[1]
        disc = b * b - a * (ol[0] ** 2 + ol[1] ** 2 - r * r)
        ts = np.where((disc > 0) & (a > 1e-12), (-b - np.sqrt(np.maximum(disc, 0))) / np.maximum(a, 1e-12), np.inf)
        zs = ol[2] + ts * dl[:, 2]
        ts = np.where((ts > 1e-6) & (np.abs(zs) <= hl), ts, np.inf)
        with np.errstate(divide="ignore", invalid="ignore"):
            tc = np.where(dl[:, 2] > 0, (-hl - ol[2]) / dl[:, 2], (hl - ol[2]) / dl[:, 2])
        pc = ol[None, :2] + tc[:, None] * dl[:, :2]
        tc = np.where((tc > 1e-6) & ((pc**2).sum(1) <= r * r), tc, np.inf)
        t = np.minimum(ts, tc)
        pl = ol + np.where(np.isfinite(t), t, 0)[:, None] * dl
        zero = np.zeros(n)
        nl = np.where((tc < ts)[:, None], np.stack([zero, zero, -np.sign(dl[:, 2])], 1),
                      np.stack([pl[:, 0], pl[:, 1], zero], 1) / r)  # fmt: skip
    pl = ol + np.where(np.isfinite(t), t, 0)[:, None] * dl
    return t, nl @ pr.R.T, pl


def _shade(p: np.ndarray, normal: np.ndarray, albedo: np.ndarray, room: Room) -> np.ndarray:
    """Linear radiance: ambient + a point light under the ceiling's centre (rotationally
    symmetric, so the room's appearance keeps its period)."""
    light = np.array([0.0, 0.0, room.height - 0.2])
    to_l = light - p
    dist = np.linalg.norm(to_l, axis=1, keepdims=True)
    lam = np.clip((normal * to_l / np.maximum(dist, 1e-6)).sum(1), 0, 1)
    return albedo * (0.35 + 0.75 * lam / (1 + 0.05 * dist[:, 0] ** 2))[:, None]


# ----------------------------------------------------------------------------- cameras


@dataclass
class Cam:
    """One camera: id, K (3x3), T_cam_world (4x4, the truth), exposure gain and white balance."""

    id: str
    K: np.ndarray
    T_cam_world: np.ndarray
    gain: float
    balance: np.ndarray


def make_cameras(rng: np.random.Generator, sensor: Sensor, room: Room, count: int | None = None) -> list[Cam]:
    """5-10 cameras on one or two rings 2.5-3.5 m out (inside the walls), 1.2-2.4 m high,
    looking at the figure with yaw / pitch jitter of a few degrees."""
    n = int(count or rng.integers(5, 11))
    two = bool(rng.random() < 0.5)
    rmax = min(3.5, room.apothem - 0.35)
    radii = sorted(rng.uniform(2.5, rmax, 2)) if two else [float(rng.uniform(2.5, rmax))] * 2
    heights = sorted(rng.uniform(1.2, 2.4, 2)) if two else [float(rng.uniform(1.2, 2.4))] * 2
    start = rng.uniform(0, 360)
    cams = []
    for i in range(n):
        ring = i % 2
        az = math.radians(start + i * 360.0 / n + rng.uniform(-0.2, 0.2) * 360.0 / n)
        centre = np.array(
            [radii[ring] * math.cos(az), radii[ring] * math.sin(az), heights[ring] + rng.uniform(-0.05, 0.05)]
        )
        target = np.array([0.0, 0.0, rng.uniform(0.5, 0.9)])
        T = look_at(centre, target, rng.uniform(-2, 2))
        jitter = rot("y", rng.uniform(-4, 4)) @ rot("x", rng.uniform(-3, 3))  # yaw, pitch in camera axes
        T[:3, :3] = jitter @ T[:3, :3]
        T[:3, 3] = -T[:3, :3] @ centre
        fx = sensor.fx * rng.uniform(0.99, 1.01)
        K = np.array([[fx, 0, (sensor.width - 1) / 2 + rng.uniform(-3, 3)],
                      [0, fx * rng.uniform(0.998, 1.002), (sensor.height - 1) / 2 + rng.uniform(-3, 3)], [0, 0, 1]])  # fmt: skip
        cams.append(Cam(f"cam{i}", K, T, float(rng.uniform(0.85, 1.15)), rng.uniform(0.96, 1.04, 3)))
    return cams


def _rays(cam: Cam, sensor: Sensor) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Camera centre, unit world ray per pixel (row-major) and each ray's z in the camera."""
    v, u = np.mgrid[0 : sensor.height, 0 : sensor.width]
    pix = np.stack([u.ravel(), v.ravel(), np.ones(u.size)], 1).astype(float)
    dc = pix @ np.linalg.inv(cam.K).T
    dc /= np.linalg.norm(dc, axis=1, keepdims=True)
    R, t = cam.T_cam_world[:3, :3], cam.T_cam_world[:3, 3]
    return -R.T @ t, dc @ R, dc[:, 2]


def _stripes(pr: Prim, pl: np.ndarray) -> np.ndarray:
    """Clothes pattern: bands across the primitive's local z (1: none)."""
    if pr.stripe <= 0:
        return np.ones(len(pl))
    return np.where((pl[:, 2] // pr.stripe) % 2 == 0, 1.0, 0.55)


def _near(pr: Prim, o: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Rays passing within the bounding sphere of a primitive."""
    bound = float(np.linalg.norm(pr.size)) if pr.kind != "sphere" else pr.size[0]
    oc = pr.c - o
    along = d @ oc
    return (oc @ oc - along**2 < bound**2 * 1.01) & (along > 0)


def trace(room: Room, prims: list[Prim], cam: Cam, sensor: Sensor) -> dict[str, np.ndarray]:
    """One ray per pixel: z-depth (m), linear radiance, albedo luminance and the cosine of the
    incidence angle (H, W)."""
    o, d, dz = _rays(cam, sensor)
    t, normal, albedo = _room_hit(room, o, d)
    for pr in prims:
        near = np.flatnonzero(_near(pr, o, d))  # rays that pass the primitive's bounding sphere
        tp, npr, pl = _prim_hit(pr, o, d[near])
        m = tp < t[near]
        idx = near[m]
        t[idx], normal[idx] = tp[m], npr[m]
        albedo[idx] = pr.colour[None, :] * _stripes(pr, pl[m])[:, None]
    p = o + t[:, None] * d
    rad = _shade(p, normal, albedo, room)
    hw = (sensor.height, sensor.width)
    return {"depth": (t * dz).reshape(hw), "radiance": rad.reshape(*hw, 3),
            "lum": (albedo @ [0.3, 0.59, 0.11]).reshape(hw),
            "cos": np.abs((normal * d).sum(1)).reshape(hw)}  # fmt: skip


def _edge_range(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """3x3 neighbourhood min and max of a depth map (edge replicated)."""
    pad = np.pad(z, 1, mode="edge")
    h, w = z.shape
    stack = np.stack([pad[i : i + h, j : j + w] for i in range(3) for j in range(3)])
    return stack.min(0), stack.max(0)


def sense_depth(rng: np.random.Generator, ray: dict[str, np.ndarray], sensor: Sensor) -> np.ndarray:
    """The depth a time-of-flight camera returns: flying pixels at depth edges, noise growing with
    distance, holes on dark and grazing surfaces and beyond the range; 0 = no measurement."""
    z = ray["depth"].copy()
    lo, hi = _edge_range(z)
    edge = (hi - lo) > 0.05 + 0.01 * z
    fly = edge & (rng.random(z.shape) < 0.45)
    z[fly] = lo[fly] + rng.random(int(fly.sum())) * (hi[fly] - lo[fly])  # mixed pixels between the surfaces
    z = z + rng.normal(size=z.shape) * (sensor.sigma_a + sensor.sigma_b * z * z)
    p_miss = 0.003 + 0.85 * np.clip((0.1 - ray["lum"]) / 0.08, 0, 1)  # dark surfaces return little IR
    p_miss += np.clip((0.2 - ray["cos"]) / 0.15, 0, 1)  # grazing incidence
    p_miss += np.clip((z - sensor.nominal) / (sensor.max_range - sensor.nominal), 0, 1) * 0.3
    p_miss += edge * 0.15
    z[(rng.random(z.shape) < p_miss) | (z > sensor.max_range) | (z < 0.5)] = 0.0
    if sensor.octagon:  # the NFOV mode's valid region: the image with its corners cut
        h, w = z.shape
        v, u = np.mgrid[0:h, 0:w]
        z[(np.abs(u - w / 2) / (w / 2) + np.abs(v - h / 2) / (h / 2)) > 1.55] = 0.0
    return np.round(z * 1000.0) / 1000.0


def sense_colour(rng: np.random.Generator, ray: dict[str, np.ndarray], cam: Cam) -> np.ndarray:
    """8-bit RGB: exposure gain and white balance of this camera, vignetting, gamma, noise."""
    h, w = ray["depth"].shape
    v, u = np.mgrid[0:h, 0:w]
    r2 = ((u - w / 2) ** 2 + (v - h / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
    lin = ray["radiance"] * cam.gain * cam.balance[None, None, :] * (1 - 0.25 * r2)[..., None]
    srgb = np.clip(lin, 0, 1) ** (1 / 2.2) * 255.0 + rng.normal(0, 2.0, (h, w, 3))
    return np.clip(np.round(srgb), 0, 255).astype(np.uint8)


# ----------------------------------------------------------------------------- the recording


@dataclass
class Studio:
    """Everything one seed draws: room, figure, cameras, per-frame motion."""

    seed: int
    sensor: Sensor
    room: Room
    figure: Figure
    cams: list[Cam]
    motion: list[tuple[float, float, float, float]]

    def describe(self) -> dict:
        """The scene's parameters (JSON-able), for results and the recording's README."""
        centres = [-c.T_cam_world[:3, :3].T @ c.T_cam_world[:3, 3] for c in self.cams]
        return {"seed": self.seed, "sensor": self.sensor.name, "sides": self.room.sides,
                "room_radius": round(self.room.radius, 3), "room_height": round(self.room.height, 3),
                "cameras": len(self.cams), "frames": len(self.motion),
                "camera_radius": [round(float(np.hypot(c[0], c[1])), 3) for c in centres],
                "camera_height": [round(float(c[2]), 3) for c in centres]}  # fmt: skip


def make_studio(
    seed: int, resolution: str = "320x240", frames: int = 1, moving: bool = False,
    sides: int | None = None, cameras: int | None = None,
) -> Studio:  # fmt: skip
    """The scene of ``seed`` (deterministic): sensor by ``resolution`` (:data:`SENSORS`)."""
    if resolution not in SENSORS:
        raise ValueError(f"resolution {resolution!r}: choose from {', '.join(SENSORS)}")
    rng = np.random.default_rng([seed, 38])
    room = make_room(rng, sides)
    figure = make_figure(rng)
    cams = make_cameras(rng, SENSORS[resolution], room, cameras)
    return Studio(seed, SENSORS[resolution], room, figure, cams, figure_motion(rng, frames, moving))


def render_frame(studio: Studio, t: int) -> tuple[np.ndarray, np.ndarray]:
    """Frame t: colour (N, H, W, 3) uint8 and depth (N, H, W) float32 metres."""
    prims = figure_prims(studio.figure, studio.motion[t])
    colours, depths = [], []
    for i, cam in enumerate(studio.cams):
        rng = np.random.default_rng([studio.seed, 1, t, i])
        ray = trace(studio.room, prims, cam, studio.sensor)
        depths.append(sense_depth(rng, ray, studio.sensor).astype(np.float32))
        colours.append(sense_colour(rng, ray, cam))
    return np.stack(colours), np.stack(depths)


def studio_rig(studio: Studio, with_extrinsics: bool):
    """The rig (``fuseflow.Rig``): true intrinsics, the sensor preset, and the true extrinsics
    or none (an uncalibrated recording)."""
    from fuseflow import Camera, Rig

    s = studio.sensor
    return Rig([Camera(c.id, s.width, s.height, c.K, 1000.0, (0.5, s.max_range),
                       c.T_cam_world if with_extrinsics else None, sensor=s.preset) for c in studio.cams])  # fmt: skip


def write_studio(out, studio: Studio) -> dict:
    """Write the recording (rig.json without extrinsics, colour and depth PNGs) into ``out`` and
    the truth beside it as ``out/reference.json`` (a calib.json for ``fuseflow calibrate
    --reference``); returns :meth:`Studio.describe`."""
    import json
    from pathlib import Path

    from fuseflow import Calibration, write_calibration, write_frame, write_rig

    out = Path(out)
    rig = studio_rig(studio, False)
    write_rig(out, rig)
    for t in range(len(studio.motion)):
        colour, depth = render_frame(studio, t)
        write_frame(out, rig, t, colour, depth)
    truth = {c.id: c.T_cam_world for c in studio.cams}
    write_calibration(out / "reference.json", Calibration(truth, {"source": "independent studio truth"}), rig=rig)
    info = studio.describe()
    (out / "scene.json").write_text(json.dumps(info, indent=1))
    return info
