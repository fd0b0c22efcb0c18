"""fuseflow.geometry.noise: one sensor-noise model, its forms agree bit for bit, its users read its table."""

import numpy as np
import pytest
import torch

from fuseflow.errors import ValidationError
from fuseflow.geometry.noise import DEFAULT_SENSOR, SENSOR_NOISE, compiled_sigma, sensor_noise, sigma, sigma_torch


def test_forms_agree_bit_for_bit():
    z = np.linspace(0.0, 6.0, 1001, dtype=np.float32)
    nb = compiled_sigma()
    for model in SENSOR_NOISE.values():
        a, b, z0 = (np.float32(v) for v in model)
        ref = a + b * ((z - z0) * (z - z0))
        assert ref.dtype == np.float32
        assert np.array_equal(sigma(z, a, b, z0), ref)
        assert np.array_equal(sigma_torch(torch.from_numpy(z), model).numpy(), ref)
        assert np.array_equal(np.array([nb(v, a, b, z0) for v in z], dtype=np.float32), ref)


def test_kinect_values_and_names():
    k = sensor_noise("kinect")
    assert k == sensor_noise("kinect_v1") == SENSOR_NOISE[DEFAULT_SENSOR]
    assert sigma(2.0, *k) == pytest.approx(0.0012 + 0.0019 * 1.6**2)  # Nguyen et al. 2012 at 2 m
    r = sensor_noise("realsense")
    assert sigma(2.0, *r) == pytest.approx(0.0001 + 4.0 * 0.08 / (385 * 0.05))
    with pytest.raises(ValidationError, match="unknown depth sensor 'kinect_v9'"):
        sensor_noise("kinect_v9")


def test_users_read_the_one_table():
    from fuseflow.calib import joint_refine
    from fuseflow.fuse import NOISE_SIGMA, FuseConfig
    from fuseflow.synth.config import FANKHAUSER_2015, NGUYEN_2012

    k = SENSOR_NOISE["kinect_v1"]
    assert FuseConfig().noise_sigma == tuple(k) and type(FuseConfig().noise_sigma) is tuple
    assert NOISE_SIGMA["realsense"] == tuple(SENSOR_NOISE["realsense_d4xx"])
    assert (joint_refine.SIGMA_A, joint_refine.SIGMA_B, joint_refine.SIGMA_Z0) == k
    assert (NGUYEN_2012.a, NGUYEN_2012.b, NGUYEN_2012.z0) == k
    assert (FANKHAUSER_2015.a, FANKHAUSER_2015.b, FANKHAUSER_2015.z0) == SENSOR_NOISE["kinect_v2"]
