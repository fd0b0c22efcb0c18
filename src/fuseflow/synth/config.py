"""Configuration of the simulator: one frozen dataclass, plus the two sensor noise presets.

Every number has its source next to it. Effects are switched on and off one by one with the
``SimConfig`` booleans; the sensor preset (``noise``) says which numbers they use.

A new depth-noise model is one edit here: its axial-noise coefficients (an ``AxialNoise``) and
a ``SensorModel`` preset in ``SENSORS``. ``synth.noise.sigma_z`` is the one formula that the
numpy reference and the compiled kernel both evaluate with those coefficients.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import NamedTuple

import numpy as np

from fuseflow.errors import ValidationError
from fuseflow.geometry.noise import SENSOR_NOISE

__all__ = [
    "SimConfig", "SensorModel", "AxialNoise", "NGUYEN_2012", "D400_STEREO", "KINECT_V1", "REALSENSE_D435",
    "FANKHAUSER_2015", "KINECT_V2", "AZURE_KINECT",
    "SENSORS", "SCENES", "RIG_LAYOUTS",
]  # fmt: skip

SCENES = ("studio", "room", "wall", "symstudio", "farroom", "polyroom")
RIG_LAYOUTS = ("auto", "ring", "dome")


class AxialNoise(NamedTuple):
    """Coefficients of the axial (along-ray) depth noise std, ``synth.noise.sigma_z``:

        sigma_z(z, theta) = a + b (z - z0)^2 + c / sqrt(z) * theta^2 / (pi/2 - theta)^2 + z^2 s / (f B)

    metres, z in metres, theta the incidence angle in radians (clipped at 89 deg), f B the
    sensor's focal_px * baseline_m. Each published model sets its terms and leaves the others 0.
    A NamedTuple of floats, so the compiled kernel takes it as one argument.
    """

    a: float = 0.0
    """Constant term (m)."""
    b: float = 0.0
    """Quadratic range term (1/m), about z0."""
    z0: float = 0.0
    """Centre of the quadratic term (m)."""
    c: float = 0.0
    """Incidence-angle term (m^1.5): c / sqrt(z) * theta^2 / (pi/2 - theta)^2."""
    stereo_rms: float = 0.0
    """s, the stereo matching RMS subpixel error (px) of the disparity term z^2 s / (f B)."""


#: Structured light, Kinect v1 class: Nguyen, Izadi, Lovell 2012: the ``kinect_v1`` row of
#: fuseflow.geometry.noise.SENSOR_NOISE plus the incidence term 0.0001 / sqrt(z) theta^2 / (pi/2 - theta)^2 m.
NGUYEN_2012 = AxialNoise(*SENSOR_NOISE["kinect_v1"], c=0.0001)
#: Active stereo, RealSense D400 class: RMS = z^2 s / (f B) with s = 0.08 px (Intel 'Tuning depth
#: cameras for best performance', Grunnet-Jepsen et al. 2018: 0.08 px typical on a well-textured target).
D400_STEREO = AxialNoise(stereo_rms=0.08)


@dataclass(frozen=True)
class SensorModel:
    """Numbers of one depth-sensor noise model (see docs/simulator.md for the sources)."""

    name: str
    """Preset name ('kinect', 'realsense', 'none')."""
    kind: str
    """'structured-light', 'stereo' (descriptive), or 'none' (no sensor effects at all)."""
    depth_range: tuple[float, float]
    """(min, max) metres of the sensor; depth outside is missing. Kinect v1: 0.4-4.5 m, an
    assumption between the 0.5-5 m of raw data Khoshelham & Elberink 2012 measured and the
    0.8-4 m (default) / 0.4-3 m (near) modes of the Kinect for Windows SDK; D435: 0.3-6 m
    (Intel D400 datasheet: minimum ~0.3 m at 848x480, 'ideal range' 0.3-3 m, max ~10 m)."""
    baseline_m: float
    """Projector/emitter-to-camera (Kinect: 0.075 m, Khoshelham & Elberink 2012) or stereo
    baseline (D435: 0.050 m, Intel D400 datasheet)."""
    disparity_subpixel: float
    """Disparity quantization step in pixels: Kinect v1 1/8 px (Khoshelham & Elberink 2012,
    11-bit disparity in 1/8 px units); D435 1/32 px (D400 datasheet, 5-bit subpixel)."""
    focal_px: float = 580.0
    """Native focal length of the sensor's depth camera in pixels, used by the axial-noise and
    quantization formulas whatever the simulated resolution: Kinect v1 IR camera ~580 px at
    640x480 (Khoshelham & Elberink 2012); D435 ~385 px at 640x480 (librealsense intrinsics of
    a D435 at 640x480, typical)."""
    axial: AxialNoise = AxialNoise()
    """Coefficients of the axial noise std sigma_z(z, theta) (``AxialNoise``; all 0 = none)."""
    lateral_sigma_px: float = 0.8
    """Lateral (in-image) noise in pixels at normal incidence: 0.8 px (Nguyen et al. 2012,
    sigma_L = 0.8 + 0.035 theta / (pi/2 - theta) px). For D435 the same form is used
    (no published model; stated as an assumption)."""
    grazing_max_deg: float = 75.0
    """Incidence angle (between ray and surface normal) beyond which a pixel has no depth.
    Nguyen et al. 2012 report reliable data up to 60-70 deg; above ~75 deg the Kinect returns
    mostly nothing. Pixels between grazing_max_deg - 10 and grazing_max_deg drop with a linearly
    rising probability."""
    dropout_rate: float = 0.005
    """Probability that a pixel independently has no depth (speckle/IR failures), 0.5 %."""
    flying_pixel_rate: float = 0.5
    """Probability that a pixel on a depth discontinuity becomes a mixed pixel (depth between
    the two sides), Kinect-class behaviour (Sabov & Krueger 2008; Reynolds et al. 2011)."""

    def __post_init__(self) -> None:
        if not isinstance(self.axial, AxialNoise):
            raise ValidationError(f"SensorModel.axial: expected an AxialNoise, got {self.axial!r}")
        if self.axial.stereo_rms > 0 and not self.focal_px * self.baseline_m > 0:
            raise ValidationError(
                f"SensorModel {self.name!r}: a stereo term (axial.stereo_rms > 0) needs focal_px * baseline_m > 0"
            )

    @property
    def stereo_subpixel_rms(self) -> float:
        """``axial.stereo_rms`` (the name before AxialNoise; kept for one release)."""
        return self.axial.stereo_rms


KINECT_V1 = SensorModel(
    name="kinect",
    kind="structured-light",
    depth_range=(0.4, 4.5),
    baseline_m=0.075,
    disparity_subpixel=1.0 / 8.0,
    axial=NGUYEN_2012,
)
REALSENSE_D435 = SensorModel(
    name="realsense",
    kind="stereo",
    depth_range=(0.3, 6.0),
    baseline_m=0.050,
    disparity_subpixel=1.0 / 32.0,
    focal_px=385.0,
    axial=D400_STEREO,
    grazing_max_deg=80.0,
    dropout_rate=0.01,
    flying_pixel_rate=0.3,
)
#: Time of flight, Kinect v2 class: the axial term of ``geometry.noise.SENSOR_NOISE["kinect_v2"]``
#: (Fankhauser et al. 2015); their angular term (0.1 z^1.5 theta^2 / (pi/2 - theta)^2 mm) is
#: approximated by this model's c / sqrt(z) form with the value it has at 4 m (c = 0.8 mm: an
#: assumption).
FANKHAUSER_2015 = AxialNoise(*SENSOR_NOISE["kinect_v2"], c=0.0008)
KINECT_V2 = SensorModel(
    name="kinect2",
    kind="time-of-flight",
    depth_range=(0.5, 4.5),  # Kinect for Windows v2 SDK: 0.5-4.5 m
    baseline_m=0.05,  # emitter beside the sensor; no disparity (no stereo term, no quantization)
    disparity_subpixel=0.0,
    focal_px=365.0,  # 512x424 depth camera, ~70.6 deg horizontal field of view
    axial=FANKHAUSER_2015,
    grazing_max_deg=80.0,
    dropout_rate=0.005,
    flying_pixel_rate=0.5,  # ToF mixes foreground and background on edges (Fankhauser et al. 2015)
)
#: Time of flight, Azure Kinect class (NFOV binned mode: 0.5-5.46 m, Azure Kinect DK hardware
#: specification). The specification bounds the random error at 17 mm std; the 1 mm + 0.8 mm/m z used
#: here (an assumption) is closer to what a unit shows at 1-4 m on a matte target. Depth edges are
#: invalidated by the device rather than mixed (flying_pixel_rate 0.1).
AZURE_KINECT = SensorModel(
    name="azure",
    kind="time-of-flight",
    depth_range=(0.5, 5.46),
    baseline_m=0.05,
    disparity_subpixel=0.0,
    focal_px=252.0,  # 320x288 binned depth, 75 deg horizontal field of view
    axial=AxialNoise(a=0.001, c=0.0008),
    grazing_max_deg=78.0,
    dropout_rate=0.005,
    flying_pixel_rate=0.1,
)
NO_NOISE = SensorModel(name="none", kind="none", depth_range=(0.1, 10.0), baseline_m=0.0, disparity_subpixel=0.0)
SENSORS = {
    "kinect": KINECT_V1,
    "realsense": REALSENSE_D435,
    "none": NO_NOISE,
    "kinect2": KINECT_V2,
    "azure": AZURE_KINECT,
}


@dataclass(frozen=True)
class SimConfig:
    """Everything that defines a simulated recording. Same config + seed = same bytes.

    Effects (``axial_noise`` ... ``color_noise``) apply only when ``noise`` is not 'none'.
    """

    cameras: int = 8
    """Number of cameras, 1..64."""
    frames: int = 10
    """Number of frames (instants) in a recording, >= 1."""
    scene: str = "studio"
    """'studio' (people-sized objects inside a camera ring, backdrop walls) or 'room'
    (floor, walls, furniture-like boxes, cylinders, thin parts); 'wall' is a test scene: one
    flat textured wall 2 m in front of the cameras (noise statistics). Scenes that break
    target-free calibration (``synth.studios``): 'symstudio' (a regular 8-12-sided room that
    repeats exactly, a small figure at the centre; rig 'ring': one ring, else two) and
    'farroom' (low-texture room, a person walking across, cameras 3.6 m out); 'polyroom'
    (``synth.studio_b``: a separately written 6-12-sided repeating room with a static figure of
    boxes and cylinders, its own textures and time-of-flight noise)."""
    dynamic: bool = False
    """Add moving objects (an articulated human-sized figure walking a circle, a bouncing box
    and a rolling sphere) so that every frame differs."""
    resolution: tuple[int, int] = (640, 480)
    """(width, height) pixels of every camera, 16..4096 each."""
    noise: str = "kinect"
    """Depth sensor preset: 'kinect' (Kinect v1 class), 'realsense' (D435 class), 'kinect2'
    (Kinect v2 class, time of flight), 'azure' (Azure Kinect class, time of flight) or 'none'."""
    seed: int = 0
    """Seed of every random draw (scene layout, texture, noise); frame t draws from
    numpy Generator([seed, t, stream])."""
    rig: str = "auto"
    """Camera layout: 'ring' (one ring, all looking at the volume centre), 'dome' (rings at
    several elevations), 'auto' (ring up to 16 cameras, dome above), or a path to a rig.json
    (fuseflow-rig/1 with extrinsics; its resolution and intrinsics are used)."""
    hfov_deg: float = 62.0
    """Horizontal field of view, degrees (Kinect v1 colour camera 62 deg, depth 58.5 deg;
    valid 20..120). fx = fy = (W / 2) / tan(hfov / 2), principal point at the image centre."""
    fps: float = 30.0
    """Frame rate (timestamps t / fps and the motion speed of dynamic objects), > 0."""
    depth_scale: float = 1000.0
    """uint16 units per metre written to the recording (1000 = millimetres, as Kinect/RealSense)."""
    calib_error_deg: float = 0.0
    """Injected calibration error: each camera's rotation written to rig.json is perturbed by
    this many degrees about a random axis (0 = exact). The Simulator's ``rig`` stays true."""
    calib_error_mm: float = 0.0
    """Injected calibration error: each camera's translation is moved by this many millimetres
    in a random direction (0 = exact)."""
    surface_density: float = 10000.0
    """Ground-truth surface samples per square metre (10000 = 1 cm spacing), 100..1e6."""
    surface_visible_only: bool = True
    """Keep only the GT surface samples that at least one camera sees at that instant (depth test
    against the noise-free depth), so that accuracy metrics compare like with like."""
    axial_noise: bool = True
    """Gaussian depth noise along the ray: Nguyen et al. 2012 (kinect), z^2 s/(f b) (realsense)."""
    lateral_noise: bool = True
    """Each pixel reads the depth of a pixel displaced by N(0, sigma_L) (Nguyen et al. 2012)."""
    quantization: bool = True
    """Disparity quantization (1/8 px kinect, 1/32 px realsense) before the depth_scale units."""
    flying_pixels: bool = True
    """Mixed depths at depth discontinuities (between foreground and background)."""
    grazing_dropout: bool = True
    """No depth where the incidence angle exceeds the sensor's grazing_max_deg."""
    range_dropout: bool = True
    """No depth outside the sensor's depth_range."""
    random_dropout: bool = True
    """Pixels dropped independently with the sensor's dropout_rate."""
    color_noise: float = 2.0
    """Std of Gaussian colour noise in 8-bit levels (0 = off); a typical value for a
    well-lit VGA sensor."""
    ambient: float = 0.35
    """Ambient term of the Lambert shading, 0..1 (the rest is diffuse from two fixed lights)."""

    def __post_init__(self) -> None:
        def bad(name: str, want: str) -> None:
            raise ValidationError(f"SimConfig.{name}: expected {want}, got {getattr(self, name)!r}")

        def is_int(v: object) -> bool:
            return isinstance(v, int) and not isinstance(v, bool)

        if not is_int(self.cameras) or not 1 <= self.cameras <= 64:
            bad("cameras", "an integer from 1 to 64")
        if not is_int(self.frames) or self.frames < 1:
            bad("frames", "an integer >= 1")
        if self.scene not in SCENES:
            bad("scene", f"one of {list(SCENES)}")
        res = self.resolution
        if not isinstance(res, (tuple, list)) or len(res) != 2 or not all(is_int(v) and 16 <= v <= 4096 for v in res):
            bad("resolution", "(width, height) integers in 16..4096")
        object.__setattr__(self, "resolution", (int(res[0]), int(res[1])))
        if self.noise not in SENSORS:
            bad("noise", f"one of {list(SENSORS)}")
        if not is_int(self.seed) or self.seed < 0:
            bad("seed", "a non-negative integer")
        if not isinstance(self.rig, str) or not self.rig:
            bad("rig", f"one of {list(RIG_LAYOUTS)} or a path to a rig.json")
        for name, lo, hi in (
            ("hfov_deg", 20.0, 120.0),
            ("fps", 1e-3, 1e4),
            ("depth_scale", 1.0, 1e5),
            ("calib_error_deg", 0.0, 90.0),
            ("calib_error_mm", 0.0, 1e4),
            ("surface_density", 100.0, 1e6),
            ("color_noise", 0.0, 64.0),
            ("ambient", 0.0, 1.0),
        ):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
                bad(name, f"a number in [{lo:g}, {hi:g}]")
        for f in fields(self):
            if f.type in ("bool",) and not isinstance(getattr(self, f.name), bool):
                bad(f.name, "True or False")

    @property
    def sensor(self) -> SensorModel:
        """The SensorModel of ``noise``."""
        return SENSORS[self.noise]

    def to_json(self) -> dict:
        """JSON-serialisable dict of the fields (written to gt.json)."""
        return {f.name: (list(v) if isinstance(v := getattr(self, f.name), tuple) else v) for f in fields(self)}

    @staticmethod
    def from_json(doc: dict) -> SimConfig:
        known = {f.name for f in fields(SimConfig)}
        kw = {k: v for k, v in doc.items() if k in known}
        if "resolution" in kw:
            kw["resolution"] = tuple(kw["resolution"])
        return SimConfig(**kw)


#: Incidence angle at which the angular term of sigma_z stops growing (89 deg, float32 as the angle maps).
THETA_CLIP = np.float32(np.radians(89.0))


def sigma_terms(a, b, z0, c, stereo_rms, fb, z, theta):
    """The one definition of the ``AxialNoise`` formula (its fields spelled out): ``axial_sigma``
    evaluates it on numpy arrays and ``synth.numba_kernels`` compiles this same function for the
    per-pixel kernel, so it uses only operations that numba and numpy share."""
    tc = np.minimum(theta, THETA_CLIP)
    return (
        a
        + b * (z - z0) ** 2
        + c / np.sqrt(np.maximum(z, 1e-3)) * tc**2 / (np.pi / 2 - tc) ** 2
        + z * z * stereo_rms / fb
    )
