"""Axial depth-sensor noise: sigma(z) = a + b (z - z0)^2 (metres), the one model and its presets.

Every part that weighs or gates depth by its expected noise uses this model: FUSE (noise-aware
MCM, range-aware ranking, multi-view mean, consensus: ``FuseConfig.noise_sigma``), GMAC's joint
refinement (residual weights and gates), the simulator's Kinect-class axial term and the
calibration benchmark's synthetic noise. A new sensor is one row of ``SENSOR_NOISE``; a camera
picks its row with the optional ``"sensor"`` field of rig.json (docs/formats.md).

The formula is written once, :func:`sigma`, in operations numpy, torch and numba share: called
with numpy arrays or Python floats it is the numpy form, with float32 tensors (:func:`sigma_torch`)
the torch form, and :func:`compiled_sigma` compiles the same function with numba for the FUSE
kernels (numba is imported only there, so ``import fuseflow`` does not load it).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

from fuseflow.errors import ValidationError

if TYPE_CHECKING:
    import torch

__all__ = [
    "AxialSigma",
    "DEFAULT_SENSOR",
    "SENSOR_NOISE",
    "compiled_sigma",
    "camera_noise",
    "sensor_noise",
    "sigma",
    "sigma_torch",
]


class AxialSigma(NamedTuple):
    """Coefficients of sigma(z) = a + b (z - z0)^2: a (m), b (1/m), z0 (m). a > 0, b >= 0."""

    a: float
    b: float
    z0: float


#: Per-sensor presets. Sources:
#: - ``kinect_v1``: structured light, Kinect v1 class: Nguyen, Izadi, Lovell 2012 (3DIMPVT),
#:   fitted at normal incidence (the simulator adds their incidence-angle term on top).
#: - ``realsense_d4xx``: active stereo, RealSense D4xx class: RMS = z^2 s / (f B) with subpixel
#:   s = 0.08 px, f = 385 px, B = 0.05 m (Intel D400 datasheet and tuning guide), b = s / (f B),
#:   plus a 0.1 mm floor so sigma stays positive near z = 0.
#: - ``kinect_v2``: time of flight, Kinect v2 class: Fankhauser et al. 2015 ("Kinect v2 for mobile
#:   robot navigation"), sigma_z = 1.5 - 0.5 z + 0.3 z^2 mm = 1.29 + 0.3 (z - 0.833)^2 mm (the
#:   simulator adds an incidence-angle term on top).
#: - ``azure_kinect``: time of flight, Azure Kinect DK: the hardware specification's random error,
#:   standard deviation <= 17 mm in every depth mode (learn.microsoft.com/azure/kinect-dk/
#:   hardware-specification, "Depth camera supported operating modes"; confirmed within 3.5 m in
#:   all four modes by Tolgyessy et al. 2021, Sensors 21(2):413). The specification gives a bound,
#:   not sigma(z), so the row is that constant bound (b = 0): pessimistic at short range. The
#:   systematic error (< 11 mm + 0.1 % of distance) is a bias, not in sigma.
#: No Orbbec Femto row: no published per-mode noise figures were at hand to cite.
#: ``kinect``, ``realsense`` and ``kinect2`` are the simulator's names for the first three rows.
SENSOR_NOISE: dict[str, AxialSigma] = {
    "kinect_v1": AxialSigma(0.0012, 0.0019, 0.4),
    "realsense_d4xx": AxialSigma(0.0001, 0.08 / (385.0 * 0.05), 0.0),
    "kinect_v2": AxialSigma(0.00129, 0.0003, 0.833),
    "azure_kinect": AxialSigma(0.017, 0.0, 0.0),
}
_ALIASES = {"kinect": "kinect_v1", "realsense": "realsense_d4xx", "kinect2": "kinect_v2"}

#: The sensor assumed for a camera whose rig.json entry names none.
DEFAULT_SENSOR = "kinect_v1"


def sensor_noise(name: str) -> AxialSigma:
    """The preset of a sensor name (``SENSOR_NOISE`` keys or the simulator's 'kinect' /
    'realsense'); ValidationError listing the names otherwise."""
    key = _ALIASES.get(name, name)
    if key not in SENSOR_NOISE:
        raise ValidationError(f"unknown depth sensor {name!r}; known: {sorted(SENSOR_NOISE) + sorted(_ALIASES)}")
    return SENSOR_NOISE[key]


def camera_noise(sensor: str | None, default) -> AxialSigma:
    """The sigma(z) coefficients of a camera whose ``Camera.sensor`` is ``sensor``: its preset, or
    ``default`` (the caller's global choice, an (a, b, z0) tuple) when it names none; an unknown
    name is a ValidationError listing the known ones."""
    return AxialSigma(*default) if sensor is None else sensor_noise(sensor)


def sigma(z, a, b, z0):
    """sigma(z) = a + b (z - z0)^2 in metres, for depth z in metres (any shape).

    The numpy form with arrays / floats, the torch form with tensors (all of one dtype), and
    the body that :func:`compiled_sigma` compiles: the same operations in the same order."""
    dz = z - z0
    return a + b * (dz * dz)


def sigma_torch(z: torch.Tensor, model: tuple[float, float, float]) -> torch.Tensor:
    """:func:`sigma` for a float32 tensor z, the coefficients as float32 on z's device (the
    same float32 operations as the compiled kernels)."""
    import torch

    a, b, z0 = (torch.tensor(v, dtype=torch.float32, device=z.device) for v in model)
    return sigma(z, a, b, z0)


def compiled_sigma():
    """:func:`sigma` compiled with numba (``@njit``, inlined into the calling kernel)."""
    from numba import njit

    return njit(cache=True, inline="always", error_model="numpy")(sigma)
