"""Pinned simulator output: values recorded with the code before the noise model became one
``AxialNoise`` definition, so a refactor of the noise or shading kernels that changes
a single bit of the sensor output fails here.

The noise-stage pins are exact (a numpy Generator and IEEE float32/float64 arithmetic without
fast-math are platform-stable); the render pins go through Open3D's ray caster and are
compared to 1e-6 relative (any real change of the noise moves depth by a millimetre or more).
"""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from fuseflow.synth import SimConfig, Simulator
from fuseflow.synth.noise import apply_depth_noise


def _analytic() -> tuple[np.ndarray, np.ndarray]:
    """(z, theta) (2, 24, 32) float32: a slanted plane 1-3.5 m with a box at 0.8 m in front (depth
    edges), a second view 4-6.5 m (range dropout), no surface in four pixels, and an incidence
    angle rising from 0 to 87 degrees down the image (grazing dropout)."""
    n, h, w = 2, 24, 32
    u = np.arange(w, dtype=np.float32)[None, None, :]
    v = np.arange(h, dtype=np.float32)[None, :, None]
    z = np.broadcast_to(np.float32(1.0) + np.float32(2.5 / (w - 1)) * u, (n, h, w)).copy()
    z[1] += np.float32(3.0)
    z[0, 8:16, 10:20] = np.float32(0.8)
    z[0, 0, :4] = np.inf
    theta = np.broadcast_to(np.radians(np.float32(87.0)) * v / np.float32(h - 1), (n, h, w)).astype(np.float32)
    return z, theta


# (noise, effects off) -> (sha256 prefix of the output bytes, valid pixels, d[0,4,6], d[0,12,24], d[1,3,3])
NOISE_PINS = {
    ("kinect", ()): ("bb53593e489ef816", 736, 1.6109999418258667, 3.0260000228881836, 4.296000003814697),
    ("kinect", ("quantization",)): ("8aab9452529b9117", 738, 1.6080000400543213, 3.0230000019073486, 4.284999847412109),
    ("kinect", ("lateral_noise",)): ("bc7dd831be35e8be", 735, 1.5399999618530273, 2.9489998817443848, 4.192999839782715),
    ("realsense", ()): ("b25f893dece97319", 1157, 1.5670000314712524, 3.0339999198913574, 4.218999862670898),
    ("realsense", ("quantization",)): ("0664ebb9c5ce2104", 1149, 1.565999984741211, 3.0350000858306885, 4.22599983215332),
    ("realsense", ("lateral_noise",)): ("477010f34bbceb8a", 1165, 1.4839999675750732, 2.947000026702881, 4.1620001792907715),
}  # fmt: skip


@pytest.mark.parametrize("key", list(NOISE_PINS), ids=lambda k: f"{k[0]}-{'-'.join(k[1]) or 'all'}")
def test_depth_noise_output_is_pinned(key):
    noise, off = key
    digest, valid, *values = NOISE_PINS[key]
    z, th = _analytic()
    cfg = SimConfig(cameras=2, resolution=(32, 24), noise=noise, **{k: False for k in off})
    d = apply_depth_noise(cfg, z, th, np.random.default_rng(11))
    assert d.dtype == np.float32 and d.shape == z.shape
    assert [float(d[0, 4, 6]), float(d[0, 12, 24]), float(d[1, 3, 3])] == values
    assert int((d > 0).sum()) == valid
    assert hashlib.sha256(d.tobytes()).hexdigest()[:16] == digest


def test_seeded_render_is_pinned():
    sim = Simulator(SimConfig(cameras=2, frames=1, resolution=(64, 48), noise="kinect", seed=3))
    f = sim.render(0).frame
    d = f.depth.numpy()
    pins = {(0, 6, 21): 3.4800000190734863, (0, 34, 1): 3.7019999027252197, (0, 45, 6): 2.4679999351501465,
            (1, 29, 47): 3.742000102996826, (1, 40, 59): 2.9739999771118164}  # fmt: skip
    for idx, want in pins.items():
        assert float(d[idx]) == pytest.approx(want, rel=1e-6), idx
    assert abs(int((d > 0).sum()) - 3247) <= 3
    rgb = f.color.numpy()
    assert np.abs(rgb[0, 30, 20].astype(int) - [56, 20, 0]).max() <= 1
    assert np.abs(rgb[1, 5, 60].astype(int) - [31, 57, 66]).max() <= 1
