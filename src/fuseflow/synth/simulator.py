"""The Simulator: a scene, a rig, and per instant t the rendered RGB-D views with ground truth.

Rendering casts one ray per pixel through Open3D's RaycastingScene (Embree, CPU). Rays go
through integer pixel coordinates (u, v) with direction R^T K^-1 [u, v, 1], so the hit distance
*is* the z-depth and ``z K^-1 [u, v, 1]`` back-projects onto the surface exactly (float32).
Colour is the part's two-layer texture at the hit (bilinear, texture.surface_albedo_ref), times its tint, Lambert-shaded by two fixed
directional lights plus ambient (view-independent, as matching between cameras needs).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import NamedTuple

import numpy as np
import torch

from fuseflow.errors import ValidationError
from fuseflow.synth.config import SimConfig
from fuseflow.synth.noise import apply_depth_noise
from fuseflow.synth.rigs import SIM_SENSOR, camera_centres, make_rig, with_sensor
from fuseflow.synth.scene import Scene, build_scene
from fuseflow.synth.studios import STUDIO_SCENES, build_studio, plain_textures
from fuseflow.synth.texture import make_textures, surface_albedo_ref
from fuseflow.types import Frame, Rig

__all__ = ["SimFrame", "Simulator"]

_LIGHTS = np.array([[0.4, -0.3, 0.866], [-0.6, 0.7, 0.4]], np.float32)
_LIGHTS /= np.linalg.norm(_LIGHTS, axis=1, keepdims=True)
_LIGHT_W = np.array([0.7, 0.3], np.float32)

# random streams drawn per frame: numpy Generator([seed, t, stream])
_STREAM_NOISE, _STREAM_COLOR = 1, 2


@dataclass(frozen=True)
class SimFrame:
    """One simulated instant.

    Attributes:
        frame: the sensor output, a Frame with noisy depth (N, H, W) float32 metres (0 = none)
            and colour (N, H, W, 3) uint8, rig order.
        depth_gt: (N, H, W) float32 noise-free z-depth in metres, 0 where the ray hits nothing.
        surface_points: (S, 3) float32 world metres, GT surface samples at this instant.
        surface_normals: (S, 3) float32 unit outward normals of those samples.
        part_id: (N, H, W) int32 index of the scene part each pixel sees (-1: none); lets tests
            and metrics tell moving from static parts.
    """

    frame: Frame
    depth_gt: torch.Tensor
    surface_points: torch.Tensor
    surface_normals: torch.Tensor
    part_id: torch.Tensor


class Simulator:
    """A simulated multi-camera RGB-D rig over a scene.

    ``sim.rig`` has the true extrinsics. ``sim.render(t)`` returns the SimFrame of frame t
    (0 <= t < cfg.frames, time t / cfg.fps seconds). Deterministic for cfg.seed.
    """

    def __init__(self, cfg: SimConfig):
        if not isinstance(cfg, SimConfig):
            raise ValidationError(f"Simulator expects a SimConfig, got {type(cfg).__name__}")
        self.cfg = cfg
        self.textures = make_textures(cfg.seed)
        if cfg.scene in STUDIO_SCENES:
            self.scene: Scene = build_studio(cfg.scene, cfg.seed, len(self.textures), cfg.dynamic, cfg.fps)
            if cfg.scene == "farroom":  # its plain walls: two textures after the normal ones
                self.textures = np.concatenate([self.textures, plain_textures(self.textures)])
        else:
            self.scene = build_scene(cfg.scene, cfg.seed, cfg.dynamic, len(self.textures))
        w, h = cfg.resolution
        self.rig: Rig = with_sensor(make_rig(
            cfg.rig, cfg.cameras, w, h, cfg.hfov_deg, cfg.depth_scale, cfg.sensor.depth_range, self.scene,
            np.random.default_rng([cfg.seed, 0x816]),
        ), SIM_SENSOR[cfg.noise])  # fmt: skip
        self._static_cache: tuple | None = None
        self._surface_local: list[tuple[np.ndarray, np.ndarray]] | None = None

    # ------------------------------------------------------------------ geometry

    @cached_property
    def _rays(self) -> np.ndarray:
        """(N, H, W, 6) float32 rays [origin, direction] with unit z in camera coordinates."""
        rays = []
        for cam in self.rig.cameras:
            Kinv = np.linalg.inv(cam.K)
            u, v = np.meshgrid(np.arange(cam.width, dtype=np.float64), np.arange(cam.height, dtype=np.float64))
            pix = np.stack([u, v, np.ones_like(u)], -1)
            d_cam = pix @ Kinv.T
            T_wc = cam.T_world_cam
            d_w = d_cam @ T_wc[:3, :3].T
            o = np.broadcast_to(T_wc[:3, 3], d_w.shape)
            rays.append(np.concatenate([o, d_w], -1).astype(np.float32))
        return np.stack(rays)

    def _geometry(self, t: float):
        """Placed triangles and their raycasting scene at time t (cached when nothing moves)."""
        moving = any(p.moving for p in self.scene.parts)
        if not moving and self._static_cache is not None:
            return self._static_cache
        import open3d as o3d

        tri_xyz, tri_uv, tex, tint, pid = self.scene.triangles_at(t)
        verts = tri_xyz.reshape(-1, 3)
        tris = np.arange(len(verts), dtype=np.uint32).reshape(-1, 3)
        rs = o3d.t.geometry.RaycastingScene()
        rs.add_triangles(o3d.core.Tensor(np.ascontiguousarray(verts)), o3d.core.Tensor(tris))
        out = (rs, tri_xyz, tri_uv, tex, tint, pid)
        if not moving:
            self._static_cache = out
        return out

    def surface_distance(self, points: np.ndarray, t: int) -> np.ndarray:
        """(P,) unsigned distance (m) of world points (P, 3) to the true surface at frame t."""
        import open3d as o3d

        rs = self._geometry(t / self.cfg.fps)[0]
        return rs.compute_distance(o3d.core.Tensor(np.asarray(points, np.float32))).numpy()

    # ------------------------------------------------------------------ rendering

    def _check_t(self, t: int) -> int:
        if isinstance(t, bool) or not isinstance(t, (int, np.integer)) or not 0 <= t < self.cfg.frames:
            raise ValidationError(f"frame index must be an integer in [0, {self.cfg.frames}), got {t!r}")
        return int(t)

    def render(self, t: int) -> SimFrame:
        """Render frame t: noisy sensor frame plus noise-free depth and GT surface."""
        import open3d as o3d

        t = self._check_t(t)
        cfg = self.cfg
        time_s = t / cfg.fps
        rs, tri_xyz, tri_uv, tex, tint, pid = self._geometry(time_s)
        rays = self._rays
        N, H, W = rays.shape[:3]
        hit = rs.cast_rays(o3d.core.Tensor(rays))
        if cfg.color_noise > 0 and cfg.noise != "none":
            crng = np.random.default_rng([cfg.seed, t, _STREAM_COLOR])
            cnoise, cstd = crng.standard_normal((N, H, W, 3), dtype=np.float32), float(cfg.color_noise)
        else:
            cnoise, cstd = np.zeros((1, 1, 1, 3), np.float32), 0.0
        args = (
            hit["t_hit"].numpy(), hit["primitive_ids"].numpy(), hit["primitive_uvs"].numpy(),
            hit["primitive_normals"].numpy(), rays, tri_uv, tex, tint, pid, self.textures, _LIGHTS, _LIGHT_W,
            float(cfg.ambient), cnoise, cstd,
        )  # fmt: skip
        depth_gt, theta, part, color = _shade(*args)
        ok = depth_gt > 0
        nrng = np.random.default_rng([cfg.seed, t, _STREAM_NOISE])
        depth = apply_depth_noise(cfg, np.where(ok, depth_gt, np.inf).astype(np.float32), theta, nrng)

        pts, nrm = self._surface(t, time_s, depth_gt)
        frame = Frame(
            index=t,
            camera_ids=self.rig.ids,
            color=torch.from_numpy(color),
            depth=torch.from_numpy(depth),
            present=torch.ones(N, dtype=torch.bool),
            timestamp=time_s,
        )
        return SimFrame(frame, torch.from_numpy(depth_gt), torch.from_numpy(pts), torch.from_numpy(nrm),
                        torch.from_numpy(part))  # fmt: skip

    # ------------------------------------------------------------------ ground-truth surface

    def _local_samples(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per part, area-uniform samples (P, 3) and normals (P, 3) in the part's local frame."""
        if self._surface_local is None:
            out = []
            for k, p in enumerate(self.scene.parts):
                rng = np.random.default_rng([self.cfg.seed, 0x5A3F, k])
                tri = p.mesh.vertices[p.mesh.triangles]
                cr = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
                area = 0.5 * np.linalg.norm(cr, axis=1)
                n_tri = cr / np.maximum(2 * area[:, None], 1e-15)
                count = rng.poisson(area * self.cfg.surface_density)
                which = np.repeat(np.arange(len(tri)), count)
                r1 = np.sqrt(rng.random(len(which)))
                r2 = rng.random(len(which))
                a, bb, c = tri[which, 0], tri[which, 1], tri[which, 2]
                pts = (1 - r1)[:, None] * a + (r1 * (1 - r2))[:, None] * bb + (r1 * r2)[:, None] * c
                out.append((pts, n_tri[which]))
            self._surface_local = out
        return self._surface_local

    def _surface(self, t: int, time_s: float, depth_gt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        moving = any(p.moving for p in self.scene.parts)
        cache = getattr(self, "_surface_cache", None)
        if not moving and cache is not None:
            return cache
        static = getattr(self, "_static_world", None)
        if static is None:
            P, Nn = [], []
            for p, (pl, nl) in zip(self.scene.parts, self._local_samples()):
                if not p.moving:
                    T = p.pose(0.0)
                    P.append(pl @ T[:3, :3].T + T[:3, 3])
                    Nn.append(nl @ T[:3, :3].T)
            static = (np.concatenate(P).astype(np.float32), np.concatenate(Nn).astype(np.float32))
            self._static_world = static
        P, Nn = [static[0]], [static[1]]
        for p, (pl, nl) in zip(self.scene.parts, self._local_samples()):
            if p.moving:
                T = p.pose(time_s)
                P.append((pl @ T[:3, :3].T + T[:3, 3]).astype(np.float32))
                Nn.append((nl @ T[:3, :3].T).astype(np.float32))
        pts = np.concatenate(P)
        nrm = np.concatenate(Nn)
        if self.cfg.surface_visible_only:
            keep = visible_mask(pts, nrm, depth_gt, self.rig)
            pts, nrm = pts[keep], nrm[keep]
        if not moving:
            self._surface_cache = (pts, nrm)
        return pts, nrm

    # ------------------------------------------------------------------ analysis helpers

    def pairwise_overlap(self, t: int = 0) -> np.ndarray:
        """(N, N) share of camera i's surface pixels (noise-free, frame t) that camera j sees
        too: the back-projected point lands inside j's image, in front of it, and agrees with j's
        noise-free depth within 1 cm + 1 %. Diagonal is 1."""
        sf = self.render(t)
        return overlap_matrix(sf.depth_gt.numpy(), self.rig)


class ShadeParams(NamedTuple):
    """Scalars of the shading kernel (``numba_kernels.shade_nb``), built by ``shade_params``."""

    texels_per_m: float
    """Texture resolution: a texture of S texels spans texture.TEXTURE_METRES."""
    l2_cos: float
    """cos, sin of the second texture layer's rotation (texture.LAYER2_ROT_DEG)."""
    l2_sin: float
    l2_inv_scale: float
    """1 / texture.LAYER2_SCALE."""
    l2_shift_u: float
    """texture.LAYER2_SHIFT (m)."""
    l2_shift_v: float
    contrast: float
    """texture.CONTRAST of the two-layer blend."""
    ambient: float
    """Ambient term of the Lambert shading (SimConfig.ambient)."""
    noise_std: float
    """Colour noise std in 8-bit levels (0 = off)."""


def shade_params(textures: np.ndarray, ambient: float, noise_std: float) -> ShadeParams:
    """The shading kernel's parameters: texture layout constants of ``texture`` plus the two
    per-config numbers. textures: (K, S, S, 3) uint8."""
    from fuseflow.synth import texture as T

    a = np.radians(T.LAYER2_ROT_DEG)
    return ShadeParams(
        float(textures.shape[1] / T.TEXTURE_METRES), float(np.cos(a)), float(np.sin(a)), float(1 / T.LAYER2_SCALE),
        float(T.LAYER2_SHIFT[0]), float(T.LAYER2_SHIFT[1]), float(T.CONTRAST), float(ambient), float(noise_std),
    )  # fmt: skip


def _shade(t_hit, prim, bary, normals, rays, tri_uv, tex, tint, pid, textures, lights, light_w, ambient,
           color_noise, noise_std):  # fmt: skip
    """Per-pixel depth_gt, incidence angle, part id and colour (numba kernel ``shade_nb``;
    ``_shade_ref`` is its numpy twin). See ``shade_nb`` for the arguments."""
    from fuseflow.synth.numba_kernels import shade_nb

    c = np.ascontiguousarray
    return shade_nb(c(t_hit, np.float32), c(prim, np.uint32), c(bary, np.float32), c(normals, np.float32),
                    c(rays, np.float32), c(tri_uv, np.float32), c(tex, np.int64), c(tint, np.float32),
                    c(pid, np.int32), textures, lights, light_w, c(color_noise, np.float32),
                    shade_params(textures, ambient, noise_std))  # fmt: skip


def _shade_ref(t_hit, prim, bary, normals, rays, tri_uv, tex, tint, pid, textures, lights, light_w, ambient,
               color_noise, noise_std):  # fmt: skip
    """Plain numpy reference of ``_shade``."""
    N, H, W = t_hit.shape
    z = t_hit
    ok = np.isfinite(z)
    prim = np.where(ok, prim.astype(np.int64), 0)
    d = rays[..., 3:]
    dn = d / np.linalg.norm(d, axis=-1, keepdims=True)
    cos_i = -(normals * dn).sum(-1)
    n_face = np.where(cos_i[..., None] < 0, -normals, normals)
    theta = np.where(ok, np.arccos(np.clip(np.abs(cos_i), 0.0, 1.0)), 0.0).astype(np.float32)
    okf = ok.reshape(-1)
    idx = prim.reshape(-1)[okf]
    b = bary.reshape(-1, 2)[okf]
    uv = tri_uv[idx]
    uvm = (1 - b[:, :1] - b[:, 1:]) * uv[:, 0] + b[:, :1] * uv[:, 1] + b[:, 1:] * uv[:, 2]
    albedo = surface_albedo_ref(textures, tex[idx], uvm) * tint[idx]
    lam = np.clip(n_face.reshape(-1, 3)[okf] @ lights.T, 0.0, None) @ light_w
    shade = ambient + (1 - ambient) * lam
    rgb = np.zeros((N * H * W, 3), np.float32)
    rgb[okf] = albedo * shade[:, None] * 255.0
    rgb = rgb.reshape(N, H, W, 3)
    if noise_std > 0:
        rgb = rgb + color_noise * noise_std
    color = np.clip(np.rint(rgb), 0, 255).astype(np.uint8)
    depth_gt = np.where(ok, z, 0.0).astype(np.float32)
    part = np.where(ok, pid[prim], -1).astype(np.int32)
    return depth_gt, theta, part, color


def visible_mask(points: np.ndarray, normals: np.ndarray, depth_gt: np.ndarray, rig: Rig,
                 tol_m: float = 0.01, tol_rel: float = 0.01) -> np.ndarray:  # fmt: skip
    """(S,) bool: the world point (S, 3) with normal (S, 3) is seen by at least one camera of
    ``rig`` whose noise-free depth (N, H, W) agrees with it within tol_m + tol_rel * z."""
    from fuseflow.synth.numba_kernels import visible_nb

    return visible_nb(
        np.ascontiguousarray(points, np.float64), np.ascontiguousarray(normals, np.float64),
        np.stack([c.T_cam_world for c in rig.cameras]), np.stack([c.K for c in rig.cameras]),
        camera_centres(rig), np.ascontiguousarray(depth_gt, np.float32), float(tol_m), float(tol_rel),
    )  # fmt: skip


def observable_mask(points: np.ndarray, normals: np.ndarray, depth_gt: np.ndarray, rig: Rig) -> np.ndarray:
    """(S,) bool: surface samples a camera can *measure*: visible (``visible_mask`` on the
    noise-free depth) and inside that camera's depth_range. ``surface_visible_only`` ignores the
    sensor range, so studio walls 5-8 m away stay in the reference surface; scoring a fused cloud
    against them makes completeness (and the Chamfer distance) meaningless."""
    d = np.array(depth_gt, dtype=np.float32, copy=True)
    for k, c in enumerate(rig.cameras):
        lo, hi = c.depth_range
        d[k][(d[k] < lo) | (d[k] > hi)] = 0
    return visible_mask(points, normals, d, rig)


def visible_mask_ref(points: np.ndarray, normals: np.ndarray, depth_gt: np.ndarray, rig: Rig,
                     tol_m: float = 0.01, tol_rel: float = 0.01) -> np.ndarray:  # fmt: skip
    """Plain numpy reference of ``visible_mask``."""
    seen = np.zeros(len(points), bool)
    centres = camera_centres(rig)
    for i, cam in enumerate(rig.cameras):
        todo = ~seen
        if not todo.any():
            break
        p = points[todo].astype(np.float64)
        facing = ((centres[i] - p) * normals[todo]).sum(1) > 0
        Xc = p @ cam.T_cam_world[:3, :3].T + cam.T_cam_world[:3, 3]
        z = Xc[:, 2]
        front = (z > 1e-6) & facing
        uvw = Xc @ cam.K.T
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.rint(uvw[:, 0] / z)
            v = np.rint(uvw[:, 1] / z)
        inside = front & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
        ui = np.where(inside, u, 0).astype(np.int64)
        vi = np.where(inside, v, 0).astype(np.int64)
        d = depth_gt[i][vi, ui]
        ok = inside & (d > 0) & (np.abs(d - z) < tol_m + tol_rel * z)
        idx = np.flatnonzero(todo)
        seen[idx[ok]] = True
    return seen


def overlap_matrix(depth_gt: np.ndarray, rig: Rig, stride: int = 4) -> np.ndarray:
    """(N, N) pairwise overlap from noise-free depth (see Simulator.pairwise_overlap)."""
    N = len(rig)
    out = np.eye(N)
    for i, ci in enumerate(rig.cameras):
        d = depth_gt[i][::stride, ::stride]
        v, u = np.nonzero(d > 0)
        if len(u) == 0:
            continue
        z = d[v, u].astype(np.float64)
        pix = np.stack([u * stride, v * stride, np.ones_like(u)], -1).astype(np.float64)
        Xc = (pix @ np.linalg.inv(ci.K).T) * z[:, None]
        Xw = Xc @ ci.T_world_cam[:3, :3].T + ci.T_world_cam[:3, 3]
        for j, cj in enumerate(rig.cameras):
            if j == i:
                continue
            Xj = Xw @ cj.T_cam_world[:3, :3].T + cj.T_cam_world[:3, 3]
            zj = Xj[:, 2]
            uvw = Xj @ cj.K.T
            with np.errstate(divide="ignore", invalid="ignore"):
                uj = np.rint(uvw[:, 0] / zj)
                vj = np.rint(uvw[:, 1] / zj)
            inside = (zj > 1e-6) & (uj >= 0) & (uj < cj.width) & (vj >= 0) & (vj < cj.height)
            dj = depth_gt[j][np.where(inside, vj, 0).astype(np.int64), np.where(inside, uj, 0).astype(np.int64)]
            ok = inside & (dj > 0) & (np.abs(dj - zj) < 0.01 + 0.01 * zj)
            out[i, j] = ok.mean()
    return out
