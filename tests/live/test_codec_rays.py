"""The ray-code study (benchmarks.studies.live_codec_rays): points on their pixels' rays decode
within the bound, and the off-ray distance measures what was moved."""

from __future__ import annotations

import numpy as np
from benchmarks.studies.live_codec_rays import off_ray, ray_rows


def _plane_rig(shift_px: float = 0.0):
    """One 64x48 camera looking down z at a tilted plane, a point on every 2nd pixel of every 2nd
    row (as ``--preset live`` samples), moved ``shift_px`` pixels along u off its ray."""
    K = np.array([[[100.0, 0.0, 32.0], [0.0, 100.0, 24.0], [0.0, 0.0, 1.0]]])
    T = np.eye(4)[None].copy()
    T[0, :3, 3] = [0.1, -0.2, 0.3]  # world = camera - t
    v, u = np.mgrid[0:48:2, 0:64:2].reshape(2, -1).astype(np.float64)
    z = 1.0 + 0.002 * u + 0.001 * v
    x = (u + shift_px - 32.0) / 100.0 * z
    y = (v - 24.0) / 100.0 * z
    xyz = (np.stack([x, y, z], 1) - T[0, :3, 3]).astype(np.float32)
    rgb = np.stack([u * 3, v * 4, np.full_like(u, 90)], 1).astype(np.uint8)
    return xyz, rgb, np.zeros(len(xyz), np.int64), K, T, np.array([[64, 48]])


def test_points_on_their_rays_decode_within_the_bound():
    xyz, rgb, cam, K, T, wh = _plane_rig()
    g = off_ray(xyz, cam, K, T)
    assert np.abs(g["u"] - np.round(g["u"])).max() < 1e-3
    rows = ray_rows("plane", xyz, rgb, cam, K, T, wh, bounds=(1.5, 4.0))
    assert len(rows) == 6
    for r in rows:
        assert r["outside_image"] == 0
        assert r["off_ray_px_p50_p95_max"][2] < 1e-3
        assert r["position_error_mm_p95_max"][1] <= r["bound_mm"] + 1e-3, r
        assert r["share_over_bound"] == 0.0
        assert r["mask"] < 0.5  # every lattice cell holds a point
        parts = r["mask"] + r["extra_flags"] + r["depth"] + r["offsets"] + r["luma"] + r["chroma"]
        assert abs(parts - r["bits_per_point"]) < 0.01


def test_a_point_moved_off_its_ray_is_measured_and_costs_offset_bits():
    xyz, rgb, cam, K, T, wh = _plane_rig(shift_px=0.4)
    rows = {(r["bound_mm"], r["mode"]): r for r in ray_rows("shifted", xyz, rgb, cam, K, T, wh, bounds=(1.5,))}
    assert abs(rows[(1.5, "a = b = B")]["off_ray_px_p50_p95_max"][0] - 0.4) < 1e-3
    # 0.4 px at 1 m is 4 mm sideways: on centre rays the error passes the bound, with offsets it does not
    assert rows[(1.5, "centre rays, b = B")]["position_error_mm_p95_max"][1] > 3.5
    assert rows[(1.5, "a = b = B / sqrt 3")]["position_error_mm_p95_max"][1] <= 1.5 + 1e-3
    assert rows[(1.5, "a = b = B / sqrt 3")]["offsets"] > 0.0
