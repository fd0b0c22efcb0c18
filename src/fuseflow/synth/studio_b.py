"""``polyroom``: a second, separately written symmetric studio, for testing calibration on scenes
it was not developed on.

A regular N-sided room (N = 6..12 from the seed; apothem 4.0-4.8 m, height 2.8-3.4 m) whose wall
panels, skirting boards, floor sectors and ceiling sectors repeat exactly every 360/N deg: every
repeated piece carries the same solid texture evaluated in its own sector's coordinates, and the
shading depends on the surface normal's height component only (no directional light), so the
room looks the same after a turn of 360/N deg. At the centre a static seated figure built from
boxes and cylinders (a stool, legs, torso, arms, head) with none, one or two of three props (a
side table, a bag, a short post) beside it: the only thing that tells the N turns of the room
apart. ``SimConfig.dynamic``: the figure turns
and moves (12 deg and 6 cm per frame, the arms swing), otherwise it is still.

Cameras: ``SimConfig.cameras`` on one ring (``rig='ring'``), two rings (``rig='dome'``) or one or
two from the seed (``'auto'``), 2.5-4 m from the centre, looking at the figure; evenly spaced
from a random phase with +-4 deg of jitter, and in half the seeds moved to the nearest whole
period of the room (as when mounted on its pillars) where no two cameras of a ring then share one.

Textures are a different function family from ``synth.texture`` (tiled value noise and shapes):
a solid texture made of eight oriented cosine gratings (wavelengths 10-80 cm), a hashed cell
mosaic (cells 12-40 cm) on a rotated lattice, and one square-wave band, evaluated at the hit point.

Depth noise, own models (``SimConfig.noise``): 'kinect2' is a Kinect v2 class time-of-flight
sensor (70.6 deg, 0.5-8 m, sigma = 1.2 mm + 0.6 mm/m^2 (z - 0.8)^2 plus a grazing-angle term,
mixed pixels on depth edges, holes at grazing angles, on dark surfaces and in small random
clusters); 'azure' an Azure Kinect class one (NFOV binned: 75 deg, 0.5-5.46 m, sigma = 1 mm +
0.8 mm/m z plus the grazing term, depth edges invalidated instead of mixed, holes as above);
'kinect' (the default) picks one of the two from the seed (even: Kinect v2, odd: Azure); 'none'
is exact depth. Colour: per-camera channel gains within +-4 % and Gaussian noise of
``SimConfig.color_noise`` levels.

Only the ray casting (Open3D's RaycastingScene) is shared with ``synth.simulator``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from fuseflow.errors import ValidationError
from fuseflow.synth.config import SimConfig
from fuseflow.types import Camera, Frame, Rig

__all__ = ["POLYROOM", "SUBJECTS", "PolyroomSimulator", "polyroom_sides", "polyroom_sensor"]

#: The scene name of this module in ``synth.config.SCENES``.
POLYROOM = "polyroom"
#: What stands in the middle: the seated figure (the scene), or, as controls that cannot tell the
#: room's turns apart, a column on the room's axis or nothing (``PolyroomSimulator(subject=...)``).
SUBJECTS = ("figure", "column", "none")

_SENSORS = {
    # name: (hfov deg, range (m), sigma a (m), sigma quadratic (1/m), z0, sigma linear, edge mode, rig sensor)
    "kinect2": (70.6, (0.5, 8.0), 0.0012, 0.0006, 0.8, 0.0, "mix", "kinect_v2"),
    "azure": (75.0, (0.5, 5.46), 0.0010, 0.0, 0.0, 0.0008, "invalid", "azure_kinect"),
    "none": (70.6, (0.1, 12.0), 0.0, 0.0, 0.0, 0.0, "none", None),
}


def polyroom_sides(seed: int) -> int:
    """Number of sides (6..12) of the polyroom of ``seed``."""
    return 6 + int(np.random.default_rng([seed, 0xB0B, 1]).integers(7))


def polyroom_sensor(cfg: SimConfig) -> str:
    """The sensor model of ``cfg`` in the polyroom: 'kinect2', 'azure' or 'none'."""
    if cfg.noise == "none":
        return "none"
    if cfg.noise in ("kinect2", "azure"):
        return cfg.noise
    if cfg.noise == "kinect":
        return "kinect2" if cfg.seed % 2 == 0 else "azure"
    raise ValidationError(f"scene 'polyroom': noise must be 'kinect', 'kinect2', 'azure' or 'none', got {cfg.noise!r}")


# --------------------------------------------------------------------------- solid textures


@dataclass(frozen=True)
class _Material:
    base: np.ndarray  # (3,) albedo
    waves: np.ndarray  # (8, 3) wave vectors, cycles per metre
    phase: np.ndarray  # (8,)
    amp: np.ndarray  # (8, 3) per-channel amplitude
    cell_rot: np.ndarray  # (3, 3)
    cell_size: float
    palette: np.ndarray  # (64, 3)
    band: np.ndarray  # (3,) wave vector of the square-wave band


def _material(rng: np.random.Generator, base_lo: float = 0.35, base_hi: float = 0.7) -> _Material:
    dirs = rng.standard_normal((8, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    lam = np.exp(rng.uniform(math.log(0.1), math.log(0.8), 8))
    q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    band = rng.standard_normal(3)
    band *= 1.0 / (np.linalg.norm(band) * rng.uniform(0.4, 1.2))
    return _Material(
        base=rng.uniform(base_lo, base_hi, 3), waves=dirs / lam[:, None], phase=rng.uniform(0, 2 * math.pi, 8),
        amp=rng.uniform(0.03, 0.09, (8, 3)), cell_rot=q, cell_size=float(np.exp(rng.uniform(math.log(0.12), math.log(0.4)))),
        palette=rng.uniform(-0.25, 0.25, (64, 3)), band=band,
    )  # fmt: skip


def solid_albedo(m: _Material, p: np.ndarray) -> np.ndarray:
    """(M, 3) albedo in [0.03, 0.97] of material ``m`` at local points ``p`` (M, 3) metres."""
    out = np.broadcast_to(m.base, p.shape).copy()
    arg = 2 * math.pi * (p @ m.waves.T) + m.phase  # (M, 8)
    out += np.cos(arg) @ m.amp
    cells = np.floor((p @ m.cell_rot.T) / m.cell_size).astype(np.int64)
    h = (cells[:, 0] * 73856093) ^ (cells[:, 1] * 19349663) ^ (cells[:, 2] * 83492791)
    h = (h ^ (h >> 13)) * 1274126177
    out += m.palette[(h ^ (h >> 16)) & 63]
    out += 0.12 * np.sign(np.cos(2 * math.pi * (p @ m.band)))[:, None]
    return np.clip(out, 0.03, 0.97)


# --------------------------------------------------------------------------- meshes


def _box(sx: float, sy: float, sz: float) -> tuple[np.ndarray, np.ndarray]:
    """Box centred at the origin: (8, 3) corners and (12, 3) triangles (orientation free)."""
    c = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * np.array([sx, sy, sz]) / 2
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    return c, np.array([t for a, b, cc, d in faces for t in ((a, b, cc), (a, cc, d))])


def _cylinder(r: float, h: float, seg: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """Cylinder along local z from 0 to h with caps."""
    a = np.linspace(0, 2 * math.pi, seg, endpoint=False)
    ring = np.stack([r * np.cos(a), r * np.sin(a)], 1)
    v = np.concatenate([np.c_[ring, np.zeros(seg)], np.c_[ring, np.full(seg, h)], [[0, 0, 0], [0, 0, h]]])
    tris = []
    for i in range(seg):
        j = (i + 1) % seg
        tris += [(i, j, seg + j), (i, seg + j, seg + i), (2 * seg, j, i), (2 * seg + 1, seg + i, seg + j)]
    return v, np.array(tris)


def _rz(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def _ry(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


@dataclass
class _Mesh:
    """Triangles (T, 3, 3) world metres, per triangle: material index and sector (-1: the figure)."""

    tri: list
    mat: list
    sector: list

    def add(self, v: np.ndarray, f: np.ndarray, mat: int, sector: int = -1) -> None:
        self.tri.append(v[f])
        self.mat.append(np.full(len(f), mat))
        self.sector.append(np.full(len(f), sector))

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return np.concatenate(self.tri), np.concatenate(self.mat), np.concatenate(self.sector)


@dataclass(frozen=True)
class _Layout:
    sides: int
    apothem: float
    height: float
    yaw: float  # the figure's heading
    offset: np.ndarray  # the figure's position (2,)
    materials: tuple
    props: tuple  # which of the three props stand beside the figure
    snap: bool  # cameras at whole periods of the room (the rig shares its symmetry)


def _layout(seed: int) -> _Layout:
    rng = np.random.default_rng([seed, 0xB0B, 2])
    mats = (_material(rng), _material(rng, 0.3, 0.55), _material(rng, 0.5, 0.8), _material(rng, 0.15, 0.3)) + tuple(
        _material(rng, 0.2, 0.8) for _ in range(8)
    )
    props = tuple(sorted(int(k) for k in rng.permutation(3)[: int(rng.integers(3))]))
    return _Layout(polyroom_sides(seed), float(rng.uniform(4.0, 4.8)), float(rng.uniform(2.8, 3.4)),
                   float(rng.uniform(0, 2 * math.pi)), rng.uniform(-0.15, 0.15, 2), mats, props,
                   bool(rng.random() < 0.5))  # fmt: skip


def _room(mesh: _Mesh, lay: _Layout) -> None:
    """Walls (material 0), floor (1), ceiling (2), skirting (3), every piece once per sector."""
    n, a, H = lay.sides, lay.apothem, lay.height
    half = a * math.tan(math.pi / n)
    wall = np.array([[a, -half, 0], [a, half, 0], [a, half, H], [a, -half, H]])
    r = a / math.cos(math.pi / n)
    c0 = np.array([r * math.cos(-math.pi / n), r * math.sin(-math.pi / n)])
    c1 = np.array([r * math.cos(math.pi / n), r * math.sin(math.pi / n)])
    floor = np.array([[0, 0, 0], [c0[0], c0[1], 0], [c1[0], c1[1], 0]])
    skirt_v, skirt_f = _box(0.04, 2 * half, 0.12)
    skirt_v = skirt_v + np.array([a - 0.02, 0, 0.06])
    quad = np.array([[0, 1, 2], [0, 2, 3]])
    for k in range(n):
        R = _rz(2 * math.pi * k / n)
        mesh.add(wall @ R.T, quad, 0, k)
        mesh.add(floor @ R.T, np.array([[0, 1, 2]]), 1, k)
        mesh.add((floor + np.array([0, 0, H])) @ R.T, np.array([[0, 1, 2]]), 2, k)
        mesh.add(skirt_v @ R.T, skirt_f, 3, k)


def _figure(mesh: _Mesh, lay: _Layout, t: int, moving: bool) -> None:
    """The seated figure (materials 4..11), at frame ``t`` (moves only when ``moving``)."""
    yaw = lay.yaw + (math.radians(12.0) * t if moving else 0.0)
    pos = lay.offset + (np.array([0.06, 0.03]) * t if moving else 0.0)
    swing = 0.5 * math.sin(1.1 * t) if moving else 0.0
    R = _rz(yaw)
    parts = [  # (vertices, faces, material) in the figure's frame: +x forward, z up, origin on the floor
        (*_cylinder(0.22, 0.45), 4),  # stool
        (*_box(0.45, 0.16, 0.14), 5, (0.2, 0.1, 0.52)),  # thighs
        (*_box(0.45, 0.16, 0.14), 5, (0.2, -0.1, 0.52)),
        (*_box(0.12, 0.12, 0.46), 6, (0.42, 0.1, 0.23)),  # shins
        (*_box(0.12, 0.12, 0.46), 6, (0.42, -0.1, 0.23)),
        (*_box(0.24, 0.4, 0.58), 7, (0.0, 0.0, 0.88)),  # torso
        (*_cylinder(0.1, 0.24), 8, (0.0, 0.0, 1.2)),  # head
    ]
    props = [
        (*_box(0.3, 0.26, 0.62), 9, (-0.55, 0.45, 0.31)),  # side table, a box
        (*_box(0.35, 0.2, 0.28), 10, (0.1, -0.5, 0.14)),  # bag on the floor
        (*_cylinder(0.05, 0.5), 11, (0.45, 0.55, 0.0)),  # a short post in front, to one side
    ]
    parts += [props[k] for k in lay.props]
    for part in parts:
        v, f, mat = part[0], part[1], part[2]
        off = np.array(part[3]) if len(part) > 3 else np.zeros(3)
        w = (v + off) @ R.T + np.r_[pos, 0.0]
        mesh.add(w, f, mat)
    for side in (1.0, -1.0):  # arms: cylinders hanging from the shoulders, swinging when moving
        v, f = _cylinder(0.045, 0.55)
        v = v @ _ry(math.pi - 0.6 + side * swing).T + np.array([0.0, 0.24 * side, 1.12])
        mesh.add(v @ R.T + np.r_[pos, 0.0], f, 7)


# --------------------------------------------------------------------------- rig


def _look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, -R @ eye
    return T


def _rig(cfg: SimConfig, lay: _Layout, sensor: str) -> Rig:
    rng = np.random.default_rng([cfg.seed, 0xB0B, 3])
    rings = 1 if cfg.rig == "ring" else 2 if cfg.rig == "dome" else 1 + int(rng.integers(2))
    rings = min(rings, cfg.cameras)
    counts = [cfg.cameras] if rings == 1 else [math.ceil(cfg.cameras / 2), cfg.cameras // 2]
    hfov, rng_m, *_, rig_sensor = _SENSORS[sensor]
    w, h = cfg.resolution
    f = (w / 2) / math.tan(math.radians(hfov) / 2)
    K = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]])
    cams = []
    phase = rng.uniform(0, 2 * math.pi)
    for ring, count in enumerate(counts):
        radius = float(rng.uniform(2.5, min(4.0, lay.apothem - 0.4)))
        height = float(rng.uniform(0.9, 1.5) if ring == 0 else rng.uniform(1.9, 2.5))
        angles = [phase + (2 * math.pi * (k + 0.5 * ring)) / count + math.radians(rng.uniform(-4, 4))
                  for k in range(count)]  # fmt: skip
        period = 2 * math.pi / lay.sides
        snapped = [round(a / period) % lay.sides for a in angles]
        if lay.snap and len(set(snapped)) == count:  # mounted at whole periods (the room's pillars)
            angles = [k * period for k in snapped]
        for ang in angles:
            eye = np.array([radius * math.cos(ang), radius * math.sin(ang), height])
            target = np.array([*(lay.offset + rng.uniform(-0.15, 0.15, 2)), rng.uniform(0.7, 1.0)])
            cams.append(Camera(f"cam{len(cams):02d}", w, h, K, depth_scale=cfg.depth_scale, depth_range=rng_m,
                               T_cam_world=_look_at(eye, target), sensor=rig_sensor))  # fmt: skip
    return Rig(tuple(cams))


# --------------------------------------------------------------------------- rendering and noise


def _rays(rig: Rig) -> np.ndarray:
    out = []
    for cam in rig.cameras:
        u, v = np.meshgrid(np.arange(cam.width, dtype=float), np.arange(cam.height, dtype=float))
        d = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(cam.K).T  # unit z: hit distance = z-depth
        T = cam.T_world_cam
        out.append(np.concatenate([np.broadcast_to(T[:3, 3], d.shape), d @ T[:3, :3].T], -1))
    return np.stack(out).astype(np.float32)


def _edges(z: np.ndarray, jump: float = 0.05) -> np.ndarray:
    """(N, H, W) bool: a 4-neighbour differs by more than ``jump`` m (relative to z) or is empty."""
    e = np.zeros(z.shape, bool)
    for ax in (1, 2):
        d = np.abs(np.diff(z, axis=ax)) > jump * np.maximum(z, 1.0).take(range(z.shape[ax] - 1), axis=ax)
        sl0 = [slice(None)] * 3
        sl1 = [slice(None)] * 3
        sl0[ax], sl1[ax] = slice(0, -1), slice(1, None)
        e[tuple(sl0)] |= d
        e[tuple(sl1)] |= d
    return e


def _noisy_depth(z: np.ndarray, cos_i: np.ndarray, lum: np.ndarray, sensor: str, rng: np.random.Generator):
    """Sensor depth from exact depth ``z`` (N, H, W; 0 = nothing), incidence cosine and luminance."""
    _, (lo, hi), a, b, z0, lin, edge_mode, _ = _SENSORS[sensor]
    if sensor == "none":
        return z.copy()
    theta = np.arccos(np.clip(cos_i, 0.0, 1.0))
    graze = 0.0001 * z**1.5 * theta**2 / np.maximum(math.pi / 2 - theta, 0.05) ** 2
    sigma = a + b * (z - z0) ** 2 + lin * z + graze
    out = z + sigma * rng.standard_normal(z.shape)
    hit = z > 0
    edge = _edges(np.where(hit, z, 0.0)) & hit
    if edge_mode == "mix":  # ToF mixed pixels: between this depth and the far side of the edge
        pad = np.pad(np.where(hit, z, 0.0), ((0, 0), (1, 1), (1, 1)), mode="edge")
        far = np.max([pad[:, 1 + dy : pad.shape[1] - 1 + dy, 1 + dx : pad.shape[2] - 1 + dx]
                      for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0))], axis=0)  # fmt: skip
        mix = edge & (rng.random(z.shape) < 0.6) & (far > 0)
        alpha = rng.random(z.shape)
        out = np.where(mix, alpha * z + (1 - alpha) * far, out)
    elif edge_mode == "invalid":
        out[edge] = 0.0
    drop = theta > math.radians(78.0)
    drop |= (lum < 0.1) & (rng.random(z.shape) < 0.5)
    seeds = rng.random(z.shape) < 0.002  # small clusters of holes (3x3 blobs)
    blob = seeds.copy()
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            blob |= np.roll(np.roll(seeds, dy, 1), dx, 2)
    drop |= blob
    out[drop | ~hit | (out < lo) | (out > hi)] = 0.0
    return out.astype(np.float32)


class PolyroomSimulator:
    """The ``polyroom`` scene (module docstring) with the interface the recording writer uses:
    ``rig`` (true extrinsics), ``moving``, ``render(t)`` -> ``simulator.SimFrame``. ``subject``:
    one of ``SUBJECTS``."""

    def __init__(self, cfg: SimConfig, subject: str = "figure"):
        if cfg.scene != POLYROOM:
            raise ValidationError(f"PolyroomSimulator needs scene {POLYROOM!r}, got {cfg.scene!r}")
        if subject not in SUBJECTS:
            raise ValidationError(f"PolyroomSimulator: subject must be one of {SUBJECTS}, got {subject!r}")
        self.subject = subject
        self.cfg = cfg
        self.sensor = polyroom_sensor(cfg)
        self.layout = _layout(cfg.seed)
        self.rig = _rig(cfg, self.layout, self.sensor)
        self.moving = bool(cfg.dynamic)
        self.symmetry = self.layout.sides

    def mesh(self, t: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(T, 3, 3) triangles, (T,) material, (T,) sector (-1: the figure) at frame ``t``."""
        m = _Mesh([], [], [])
        _room(m, self.layout)
        if self.subject == "figure":
            _figure(m, self.layout, t, self.moving)
        elif self.subject == "column":  # turns into itself: a control that cannot tell the room's turns
            v, f = _cylinder(0.3, 1.6, 48)
            m.add(v, f, 7)
        return m.arrays()

    def _albedo(self, p: np.ndarray, mat: np.ndarray, sector: np.ndarray) -> np.ndarray:
        """Albedo of world points ``p`` (M, 3): room pieces in their sector's coordinates."""
        ang = -2 * math.pi * np.maximum(sector, 0) / self.layout.sides
        c, s = np.cos(ang), np.sin(ang)
        local = np.where((sector >= 0)[:, None], np.stack([c * p[:, 0] - s * p[:, 1], s * p[:, 0] + c * p[:, 1],
                                                            p[:, 2]], 1), p)  # fmt: skip
        out = np.empty_like(p)
        for k, m in enumerate(self.layout.materials):
            sel = mat == k
            if sel.any():
                out[sel] = solid_albedo(m, local[sel])
        return out

    def render(self, t: int):
        """The SimFrame of frame ``t``."""
        import open3d as o3d

        from fuseflow.synth.simulator import SimFrame

        if isinstance(t, bool) or not isinstance(t, (int, np.integer)) or not 0 <= t < self.cfg.frames:
            raise ValidationError(f"frame index must be an integer in [0, {self.cfg.frames}), got {t!r}")
        tri, mat, sector = self.mesh(int(t))
        rs = o3d.t.geometry.RaycastingScene()
        verts = tri.reshape(-1, 3).astype(np.float32)
        rs.add_triangles(o3d.core.Tensor(verts), o3d.core.Tensor(np.arange(len(verts), dtype=np.uint32).reshape(-1, 3)))
        rays = _rays(self.rig)
        hit = rs.cast_rays(o3d.core.Tensor(rays))
        zt = hit["t_hit"].numpy()
        ok = np.isfinite(zt)
        prim = np.where(ok, hit["primitive_ids"].numpy().astype(np.int64), 0)
        normal = hit["primitive_normals"].numpy()
        d = rays[..., 3:]
        dn = d / np.linalg.norm(d, axis=-1, keepdims=True)
        dot = (normal * dn).sum(-1)
        n_face = np.where(dot[..., None] > 0, -normal, normal)
        p = rays[..., :3] + zt[..., None] * d
        albedo = np.zeros(zt.shape + (3,), np.float64)
        albedo[ok] = self._albedo(p[ok].astype(np.float64), mat[prim[ok]], sector[prim[ok]])
        shade = 0.7 + 0.3 * (0.5 + 0.5 * n_face[..., 2])  # depends on the normal's height only: turn-invariant
        rng = np.random.default_rng([self.cfg.seed, int(t), 0xB0B])
        gains = 1.0 + np.random.default_rng([self.cfg.seed, 0xB0B, 4]).uniform(-0.04, 0.04, (len(self.rig), 1, 1, 3))
        rgb = albedo * shade[..., None] * gains * 255.0 + self.cfg.color_noise * rng.standard_normal(albedo.shape)
        color = np.clip(np.rint(np.where(ok[..., None], rgb, 0.0)), 0, 255).astype(np.uint8)
        z = np.where(ok, zt, 0.0).astype(np.float32)
        lum = albedo.mean(-1)
        depth = _noisy_depth(z, np.abs(dot), lum, self.sensor, rng)
        pts, nrm = self._surface(tri)
        if self.cfg.surface_visible_only:
            from fuseflow.synth.simulator import visible_mask

            keep = visible_mask(pts, nrm, z, self.rig)
            pts, nrm = pts[keep], nrm[keep]
        frame = Frame(index=int(t), camera_ids=self.rig.ids, color=torch.from_numpy(color),
                      depth=torch.from_numpy(depth), present=torch.ones(len(self.rig), dtype=torch.bool),
                      timestamp=int(t) / self.cfg.fps)  # fmt: skip
        part = np.where(ok, np.where(sector[prim] >= 0, 0, 1 + mat[prim]), -1).astype(np.int32)
        return SimFrame(frame, torch.from_numpy(z), torch.from_numpy(pts), torch.from_numpy(nrm),
                        torch.from_numpy(part))  # fmt: skip

    def _surface(self, tri: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Area-uniform samples (``SimConfig.surface_density`` per m^2) of every triangle, with normals."""
        rng = np.random.default_rng([self.cfg.seed, 0xB0B, 5])
        cr = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        area = 0.5 * np.linalg.norm(cr, axis=1)
        nrm = cr / np.maximum(2 * area[:, None], 1e-15)
        which = np.repeat(np.arange(len(tri)), rng.poisson(area * self.cfg.surface_density))
        r1, r2 = np.sqrt(rng.random(len(which))), rng.random(len(which))
        a, b, c = tri[which, 0], tri[which, 1], tri[which, 2]
        pts = (1 - r1)[:, None] * a + (r1 * (1 - r2))[:, None] * b + (r1 * r2)[:, None] * c
        return pts.astype(np.float32), nrm[which].astype(np.float32)
