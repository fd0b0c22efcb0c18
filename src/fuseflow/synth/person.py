"""An articulated, clothed human figure that walks, for the simulator (person-keypoint tests).

The figure (``person_parts``) is built from the simulator's primitives: capsules (a cylinder
with a sphere at each end) for the limbs and neck, boxes for torso and pelvis, a sphere head
with hair, eyes, nose and ears, feet as boxes. Skin, shirt, trousers, shoes and hair get their
own colour (a part's texture is sampled over a small area of the texture atlas, so each reads
as a nearly uniform, lightly shaded material, as clothing does to a pose detector).

Kinematics (``Walk``): the figure walks a straight line at ``speed`` m/s, facing its direction
of travel, with legs swinging +-``swing`` rad about the hips at ``cadence`` strides per second,
knees bending in the swing phase and arms swinging opposite to the legs. ``person_joints(walk,
t)`` gives the 33 MediaPipe Pose landmarks (``fuseflow.calib.people.LANDMARKS`` order) in world
metres: joint centres (shoulders, elbows, wrists, hips, knees, ankles), heels and toes, and the
face points on the head's surface. They are the ground truth a detector's landmarks are compared
with.

``walking_person_sim`` places the figure in a plain room with cameras on a circle around its
path: the far-range small-rig case (3 cameras 120 deg apart, 3.5-4 m from a walking person).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from fuseflow.synth.config import SimConfig
from fuseflow.synth.rigs import intrinsics, look_at
from fuseflow.synth.scene import MeshData, Part, Scene, box, cylinder, quad, sphere
from fuseflow.synth.texture import make_textures
from fuseflow.types import POSE_LANDMARKS, Camera, Rig

__all__ = ["Walk", "person_parts", "person_joints", "person_scene", "walking_person_sim", "ring_rig"]

HIP_Z, SHOULDER_Z, HEAD_Z = 0.93, 1.44, 1.63
THIGH, SHIN, UPPER_ARM, FOREARM = 0.44, 0.43, 0.29, 0.26
HIP_Y, SHOULDER_Y = 0.095, 0.185

SKIN = (0.93, 0.72, 0.6)
HAIR = (0.18, 0.12, 0.08)
SHOE = (0.12, 0.12, 0.13)
EYE = (0.1, 0.08, 0.07)


@dataclass(frozen=True)
class Walk:
    """A straight walk from ``start`` to ``end`` (world xy metres, floor z = 0) at ``speed`` m/s,
    turning back at either end (the figure keeps walking for any t >= 0)."""

    start: tuple[float, float] = (-1.2, 0.0)
    end: tuple[float, float] = (1.2, 0.0)
    speed: float = 0.9
    cadence: float = 0.9
    swing: float = 0.45
    shirt: tuple[float, float, float] = (0.2, 0.35, 0.75)
    trousers: tuple[float, float, float] = (0.25, 0.25, 0.3)

    def body(self, t: float) -> np.ndarray:
        """World-from-body (4, 4) at t seconds: origin on the floor between the feet, +x forward,
        +z up."""
        a, b = np.asarray(self.start, float), np.asarray(self.end, float)
        L = float(np.linalg.norm(b - a))
        s = (self.speed * t) % (2 * L) if L > 0 else 0.0
        forward = s <= L
        p = a + (b - a) * (s / L if forward else 2 - s / L) if L > 0 else a
        d = (b - a) if forward else (a - b)
        yaw = math.atan2(d[1], d[0]) if L > 0 else 0.0
        T = np.eye(4)
        T[:3, :3] = _rz(yaw)
        T[:3, 3] = (p[0], p[1], 0.0)
        return T

    def phase(self, t: float) -> float:
        return 2 * math.pi * self.cadence * t


def _rz(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _dir(a: float) -> np.ndarray:
    """Unit vector in the body's sagittal (xz) plane, angle a from straight down towards +x."""
    return np.array([math.sin(a), 0.0, -math.cos(a)])


def _skeleton(walk: Walk, t: float) -> dict[str, np.ndarray]:
    """Body-frame joint positions (3,) at t: hips, knees, ankles, heels, toes, shoulders,
    elbows, wrists per side, plus neck and head centre."""
    ph = walk.phase(t)
    out = {"neck": np.array([0.0, 0.0, SHOULDER_Z + 0.04]), "head": np.array([0.0, 0.0, HEAD_Z])}
    for side, sgn in (("left", 1.0), ("right", -1.0)):
        th = walk.swing * sgn * math.sin(ph)  # thigh forward angle
        knee_bend = 0.7 * max(0.0, math.sin(sgn * ph + math.pi / 2)) * max(0.0, math.cos(sgn * ph))
        hip = np.array([0.0, sgn * HIP_Y, HIP_Z])
        knee = hip + THIGH * _dir(th)
        ankle = knee + SHIN * _dir(th - knee_bend - 0.05)
        shoulder = np.array([0.0, sgn * SHOULDER_Y, SHOULDER_Z])
        al = -0.8 * th
        elbow = shoulder + UPPER_ARM * _dir(al) + np.array([0.0, sgn * 0.02, 0.0])
        wrist = elbow + FOREARM * _dir(al + 0.35)
        out.update({
            f"{side}_hip": hip, f"{side}_knee": knee, f"{side}_ankle": ankle,
            f"{side}_heel": ankle + np.array([-0.05, 0.0, -0.05]),
            f"{side}_foot_index": ankle + np.array([0.15, 0.0, -0.06]),
            f"{side}_shoulder": shoulder, f"{side}_elbow": elbow, f"{side}_wrist": wrist,
        })  # fmt: skip
    return out


def _face(name: str) -> np.ndarray:
    """Body-frame offset of a face landmark from the head centre."""
    r = 0.105
    side = 1.0 if name.startswith("left") or name.endswith("left") else -1.0
    if name == "nose":
        return np.array([r + 0.015, 0.0, -0.015])
    if "eye" in name:
        dy = {"inner": 0.018, "outer": 0.052}.get(name.rsplit("_", 1)[-1], 0.035)
        return np.array([r - 0.01, side * dy, 0.02])
    if "ear" in name:
        return np.array([0.0, side * r, 0.0])
    return np.array([r - 0.005, side * 0.025, -0.05])  # mouth corners


def person_joints(walk: Walk, t: float) -> np.ndarray:
    """(33, 3) world metres: the MediaPipe Pose landmarks of the figure at t seconds."""
    sk = _skeleton(walk, t)
    pts = []
    for name in LANDMARK_NAMES:
        if name in sk:
            p = sk[name]
        elif name.endswith(("pinky", "index", "thumb")):
            side = name.split("_")[0]
            w, e = sk[f"{side}_wrist"], sk[f"{side}_elbow"]
            d = (w - e) / np.linalg.norm(w - e)
            p = w + 0.07 * d + (0.02 if name.endswith("thumb") else 0.0) * np.array([1.0, 0.0, 0.0])
        else:
            p = sk["head"] + _face(name)
        pts.append(p)
    B = walk.body(t)
    P = np.array(pts)
    return P @ B[:3, :3].T + B[:3, 3]


#: The landmark order of ``fuseflow.calib.people.LANDMARKS`` (both are ``types.POSE_LANDMARKS``).
LANDMARK_NAMES = POSE_LANDMARKS


def _flat(mesh: MeshData, scale: float = 0.08) -> MeshData:
    """The mesh with its texture coordinates shrunk: the part samples a small patch of the
    texture (a nearly uniform material with gentle shading)."""
    return MeshData(mesh.vertices, mesh.triangles, mesh.uv * scale)


def _segment_pose(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Local-from-segment (4, 4) putting a cylinder's +z axis from p to q."""
    d = q - p
    z = d / np.linalg.norm(d)
    x = np.cross([0.0, 1.0, 0.0], z)
    if np.linalg.norm(x) < 1e-6:
        x = np.cross([1.0, 0.0, 0.0], z)
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    T[:3, 3] = p
    return T


def _at(walk: Walk, fn):
    """pose(t) = world-from-body(t) @ fn(skeleton(t))."""
    return lambda t: walk.body(t) @ fn(_skeleton(walk, t))


def _translate(p: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = p
    return T


def person_parts(walk: Walk, texture: int = 0, name: str = "person") -> list[Part]:
    """The figure's parts (moving), textured from atlas entry ``texture``."""
    parts: list[Part] = []

    def add(part: str, mesh: MeshData, fn, tint) -> None:
        off = np.array([3.0 * len(parts), 1.7 * len(parts)]) % 40
        parts.append(Part(f"{name}.{part}", _flat(mesh), _at(walk, fn), True, texture, off, np.asarray(tint, float)))

    def limb(part: str, a: str, b: str, r: float, tint) -> None:
        add(part, cylinder(r, 1.0, 16, caps=False), lambda s: _segment_pose(s[a], s[b]) @ np.diag(
            [1.0, 1.0, float(np.linalg.norm(s[b] - s[a])), 1.0]), tint)  # fmt: skip
        add(part + "_end", sphere(r, 12, 8), lambda s: _translate(s[b]), tint)

    shirt, trousers = walk.shirt, walk.trousers
    add("pelvis", box(0.2, 0.33, 0.18), lambda s: _translate(np.array([0.0, 0.0, HIP_Z + 0.03])), trousers)
    add("torso", box(0.21, 0.36, 0.5), lambda s: _translate(np.array([0.0, 0.0, (HIP_Z + SHOULDER_Z) / 2 + 0.04])),
        shirt)  # fmt: skip
    add("neck", cylinder(0.05, 0.12, 12), lambda s: _translate(s["neck"] - np.array([0.0, 0.0, 0.04])), SKIN)
    add("head", sphere(0.105, 20, 14), lambda s: _translate(s["head"]), SKIN)
    add("hair", sphere(0.11, 20, 14), lambda s: _translate(s["head"] + np.array([-0.025, 0.0, 0.025])), HAIR)
    for f in ("left_eye", "right_eye"):
        add(f, sphere(0.014, 8, 6), lambda s, f=f: _translate(s["head"] + _face(f)), EYE)
    add("nose", sphere(0.018, 8, 6), lambda s: _translate(s["head"] + _face("nose") - np.array([0.01, 0, 0])), SKIN)
    add(
        "mouth",
        box(0.02, 0.05, 0.012),
        lambda s: _translate(s["head"] + np.array([0.1, 0.0, -0.05])),
        (0.6, 0.25, 0.25),
    )
    for side in ("left", "right"):
        sh = f"{side}_shoulder"
        add(sh, sphere(0.06, 12, 8), lambda s, sh=sh: _translate(s[sh]), shirt)
        limb(f"{side}_upperarm", sh, f"{side}_elbow", 0.05, shirt)
        limb(f"{side}_forearm", f"{side}_elbow", f"{side}_wrist", 0.04, SKIN)
        add(f"{side}_hand", box(0.09, 0.03, 0.08), lambda s, side=side: _translate(
            s[f"{side}_wrist"] + 0.05 * (s[f"{side}_wrist"] - s[f"{side}_elbow"]) / FOREARM), SKIN)  # fmt: skip
        hp = f"{side}_hip"
        add(hp, sphere(0.08, 12, 8), lambda s, hp=hp: _translate(s[hp]), trousers)
        limb(f"{side}_thigh", hp, f"{side}_knee", 0.075, trousers)
        limb(f"{side}_shin", f"{side}_knee", f"{side}_ankle", 0.055, trousers)
        add(f"{side}_foot", box(0.25, 0.09, 0.07), lambda s, side=side: _translate(
            s[f"{side}_ankle"] + np.array([0.05, 0.0, -0.055])), SHOE)  # fmt: skip
    return parts


def person_scene(walk: Walk, room: float = 9.0, wall_height: float = 2.8, seed: int = 0) -> Scene:
    """A plain square room (``room`` m wide, nearly uniform floor and walls: little texture to
    match) with the walking figure; cameras look at the middle of its path."""
    rng = np.random.default_rng([seed, 0x9E0])
    flat = lambda m: _flat(m, 0.01)  # noqa: E731
    parts = [Part("floor", flat(quad(room, room)), lambda t: np.eye(4), False, 1, rng.uniform(0, 40, 2),
                  np.array([0.75, 0.72, 0.68]))]  # fmt: skip
    h = room / 2
    for k in range(4):
        a = k * math.pi / 2
        R = np.stack([[-math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0], [-math.cos(a), -math.sin(a), 0.0]]).T
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = (h * math.cos(a), h * math.sin(a), wall_height / 2)
        tint = np.array([0.85, 0.85, 0.82]) * rng.uniform(0.85, 1.0)
        parts.append(Part(f"wall{k}", flat(quad(room, wall_height)), lambda t, T=T: T, False, 2,
                          rng.uniform(0, 40, 2), tint))  # fmt: skip
    parts += person_parts(walk)
    mid = (np.asarray(walk.start) + np.asarray(walk.end)) / 2
    return Scene("person", tuple(parts), np.array([mid[0], mid[1], 0.9]), 3.75, 1.6, 3.75, (10.0, 40.0))


def ring_rig(
    n: int, target: np.ndarray, radius: tuple[float, float], height: float, rng: np.random.Generator,
    resolution: tuple[int, int] = (512, 424), hfov_deg: float = 70.6, span_deg: float = 360.0,
) -> Rig:  # fmt: skip
    """n cameras on a circle around ``target`` (distance drawn in ``radius``, m), evenly spread
    over ``span_deg`` with a random start angle, each looking at the target (+-10 cm jitter);
    Kinect v2 depth-camera geometry by default."""
    w, h = resolution
    K = intrinsics(w, h, hfov_deg)
    a0 = rng.uniform(0, 2 * math.pi)
    cams = []
    for k in range(n):
        a = a0 + math.radians(span_deg) * k / n
        r = rng.uniform(*radius)
        eye = np.array([target[0] + r * math.cos(a), target[1] + r * math.sin(a), height + rng.uniform(-0.1, 0.1)])
        T = look_at(eye, np.asarray(target, float) + rng.uniform(-0.1, 0.1, 3))
        cams.append(Camera(f"cam{k:02d}", w, h, K, depth_range=(0.4, 4.5), T_cam_world=T))
    return Rig(tuple(cams))


def walking_person_sim(
    seed: int, cameras: int = 3, frames: int = 11, fps: float = 3.0, resolution: tuple[int, int] = (512, 424), **cfg_kw
):
    """A Simulator of ``cameras`` Kinect-v2-like views (``resolution``, 70.6 deg) 3.5-4 m around a
    person walking 2.4 m back and forth in a plain room; ``frames`` frames ``1 / fps`` s apart.
    The walk's direction and clothing colours are drawn from ``seed``. Further SimConfig fields
    in ``cfg_kw`` (noise, ambient, ...)."""
    from fuseflow.synth.simulator import Simulator

    rng = np.random.default_rng([seed, 0x9E1])
    a = rng.uniform(0, math.pi)
    d = 1.2 * np.array([math.cos(a), math.sin(a)])
    walk = Walk(start=tuple(-d), end=tuple(d), shirt=tuple(rng.uniform(0.15, 0.85, 3)),
                trousers=tuple(rng.uniform(0.1, 0.45, 3)))  # fmt: skip
    kw = {"surface_density": 100.0, "ambient": 0.5, **cfg_kw}  # GT surface samples unused: the fewest
    cfg = SimConfig(cameras=cameras, frames=frames, fps=fps, seed=seed, scene="room", resolution=resolution,
                    hfov_deg=70.6, **kw)  # fmt: skip
    sim = Simulator(replace(cfg, cameras=1))  # a one-camera room, then our scene and rig replace it
    sim.cfg = cfg
    sim.textures = make_textures(seed)
    sim.scene = person_scene(walk, seed=seed)
    sim.rig = ring_rig(cameras, sim.scene.target, (3.5, 4.0), 1.6, rng, resolution=resolution)
    return sim, walk
