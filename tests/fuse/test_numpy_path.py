"""The compiled CPU path on numpy frames: no torch import, the same cloud as torch tensors give."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from fuseflow import Frame
from fuseflow.fuse import FuseConfig, fuse_with_report


@pytest.fixture(scope="module")
def numpy_frame():
    from fuseflow.synth import SimConfig, Simulator

    sim = Simulator(SimConfig(cameras=4, resolution=(96, 72), frames=1, seed=5))
    f = sim.render(0).frame
    arrays = {k: getattr(f, k).numpy().copy() for k in ("color", "depth", "present", "invalid_depth")}
    return Frame(f.index, f.camera_ids, **arrays, timestamp=f.timestamp), f, sim.rig


@pytest.mark.parametrize("cfg", [FuseConfig(), FuseConfig(pixel_stride=2), FuseConfig(target_points=2000)])
def test_numpy_frame_gives_the_torch_frames_cloud_bit_for_bit(numpy_frame, cfg):
    nf, tf, rig = numpy_frame
    a = fuse_with_report(nf, rig, cfg)
    b = fuse_with_report(tf, rig, cfg)
    assert a.report.backend == b.report.backend == "numba"
    assert a.cloud.is_numpy and not b.cloud.is_numpy
    assert len(a.cloud) > 200
    for x, y in zip(
        (a.cloud.xyz, a.cloud.rgb, a.cloud.weight, a.cloud.camera, a.cloud.support),
        (b.cloud.xyz, b.cloud.rgb, b.cloud.weight, b.cloud.camera, b.cloud.support),
    ):
        assert (x is None) == (y is None)
        if x is not None:
            assert np.array_equal(x, y.numpy())


def test_numpy_frame_on_the_torch_backend_gives_a_numpy_cloud(numpy_frame):
    nf, tf, rig = numpy_frame
    a = fuse_with_report(nf, rig, FuseConfig(backend="torch")).cloud
    b = fuse_with_report(tf, rig, FuseConfig(backend="torch")).cloud
    assert a.is_numpy and np.array_equal(a.xyz, b.xyz.numpy())


def test_frame_rejects_mixed_numpy_and_torch(numpy_frame):
    from fuseflow import ValidationError

    nf, tf, _ = numpy_frame
    with pytest.raises(ValidationError, match="mix numpy arrays and torch tensors"):
        Frame(nf.index, nf.camera_ids, nf.color, tf.depth, nf.present)


def test_fuse_recording_on_cpu_fuses_with_numba_and_torch_only_checks(static_rec, tmp_path):
    """``fuseflow fuse``'s path (read, fuse with numba, write PLY) fuses on numpy; torch is loaded
    only by the input checks' depth agreement (``pipeline.checks``: exchanged cameras)."""
    code = (
        "import sys\n"
        "import fuseflow.pipeline.checks as checks\n"
        "checks.check_swaps = lambda *a, **k: []\n"
        "from fuseflow.pipeline import fuse_recording\n"
        f"s = fuse_recording({str(static_rec)!r}, {str(tmp_path / 'out')!r}, frames=range(2))\n"
        "print(s.backend, s.frames, 'torch' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["numba", "2", "False"]
