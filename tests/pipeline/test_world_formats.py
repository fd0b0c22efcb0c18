"""The output frame (--world), the seen crop (--crop auto), several formats in one call, Gaussian
splats: on the real HO-Cap frame and on small simulated rigs."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from fuseflow.cli import app
from fuseflow.io import read_calibration, read_ply
from fuseflow.pipeline import fuse_recording
from fuseflow.pipeline.config import OutputOptions

HOCAP = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "hocap-8rs"
SPLAT_LAYOUT = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity",
                "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]  # fmt: skip


def _invoke(*args):
    return CliRunner(env={"COLUMNS": "250"}).invoke(app, [str(a) for a in args])


def _largest_plane(xyz: np.ndarray) -> tuple[np.ndarray, float]:
    """Unit normal and inlier share of the largest plane (Open3D RANSAC, 1 cm)."""
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(xyz, np.float64)))
    model, inliers = pcd.segment_plane(0.01, 3, 2000, seed=0) if _has_seed() else pcd.segment_plane(0.01, 3, 2000)
    n = np.asarray(model[:3])
    return n / np.linalg.norm(n), len(inliers) / len(xyz)


def _has_seed() -> bool:
    import inspect

    import open3d as o3d

    try:
        return "seed" in inspect.signature(o3d.geometry.PointCloud.segment_plane).parameters
    except (TypeError, ValueError):
        return False


def _angle(n: np.ndarray, axis: int) -> float:
    return float(np.degrees(np.arccos(min(1.0, abs(float(n[axis]))))))


@pytest.fixture(scope="module")
def hocap(tmp_path_factory):
    if not HOCAP.is_dir():
        pytest.skip("../shared/data/hocap-8rs is not here")
    rec = tmp_path_factory.mktemp("hocap") / "rec"
    r = _invoke("convert", HOCAP, rec, "--with-extrinsics")
    assert r.exit_code == 0, r.output
    out = rec.parent / "out"
    r = _invoke("fuse", rec, "--out", out, "--format", "ply,glb,drc,splat", "--crop", "auto", "--points", "100000")
    assert r.exit_code == 0, r.output
    return rec, out, r.output


def test_hocap_glb_stands_upright_and_ply_has_z_up(hocap):
    trimesh = pytest.importorskip("trimesh")
    _, out, text = hocap
    assert "floor seen by" in text and "% of the fused points" in text  # the frame and what the crop kept
    seq = json.loads((out / "manifest.json").read_text())["sequence"]
    assert seq["world"]["name"] == "floor" and seq["up"] == [0.0, 0.0, 1.0]
    assert read_calibration(out / "calib.json").report["world"]["name"] == "floor"
    scene = trimesh.load(out / "clouds" / "000000.glb")
    geom = scene.to_geometry() if hasattr(scene, "to_geometry") else scene.dump(concatenate=True)
    n, share = _largest_plane(np.asarray(geom.vertices))
    assert share > 0.2 and _angle(n, 1) < 2.0  # the table top (the floor plane HO-Cap sees): +y up in glTF
    xyz = read_ply(out / "clouds" / "000000.ply").xyz.numpy()
    n, share = _largest_plane(xyz)
    assert share > 0.2 and _angle(n, 2) < 2.0
    assert np.median(xyz[:, 2]) > -0.02  # the subject stands on the plane, not under it


def test_hocap_splats_read_back_in_the_3dgs_layout(hocap):
    plyfile = pytest.importorskip("plyfile")
    _, out, _ = hocap
    seq = json.loads((out / "manifest.json").read_text())["sequence"]
    assert seq["splat"]["layout"] == "3dgs-ply" and seq["frames"][0]["files"]["splat"] == "splats/000000.ply"
    v = plyfile.PlyData.read(out / "splats" / "000000.ply")["vertex"]
    assert [p.name for p in v.properties] == SPLAT_LAYOUT
    cloud = read_ply(out / "clouds" / "000000.ply")
    assert v.count == len(cloud)
    assert np.allclose(np.stack([v["x"], v["y"], v["z"]], 1), cloud.xyz.numpy())
    alpha = 1 / (1 + np.exp(-v["opacity"]))
    assert np.allclose(alpha, np.clip(cloud.weight.numpy(), 0.05, 0.99), atol=1e-4)
    rgb = (np.stack([v[f"f_dc_{a}"] for a in range(3)], 1) * 0.28209479177387814 + 0.5) * 255
    assert np.abs(rgb - cloud.rgb.numpy()).max() < 0.01
    sigma = np.exp(v["scale_0"])
    assert np.array_equal(v["scale_0"], v["scale_1"]) and 0.000499 <= sigma.min() and sigma.max() <= 0.0501
    from scipy.spatial import cKDTree

    xyz = cloud.xyz.numpy().astype(np.float64)
    spacing = cKDTree(xyz).query(xyz, k=4)[0][:, 1:].mean(axis=1)
    assert np.allclose(sigma, np.clip(0.5 * spacing, 0.0005, 0.05), rtol=1e-3)  # half the local spacing
    q = np.stack([v[f"rot_{a}"] for a in range(4)], 1)
    assert np.allclose(q, [1, 0, 0, 0])


def test_hocap_crop_keeps_what_two_cameras_see_above_the_table(hocap):
    from fuseflow.geometry.volume import CaptureVolume, seen_count
    from fuseflow.geometry.world import World
    from fuseflow.io import open_recording

    rec_dir, out, _ = hocap
    rec = open_recording(rec_dir)
    cal = read_calibration(out / "calib.json")
    world = World.from_json(cal.report["world"])
    volume = CaptureVolume.from_json(cal.report["capture_volume"])
    from fuseflow.fuse import fuse
    from fuseflow.fuse.presets import preset_config

    xyz = fuse(rec[0], rec.rig, preset_config("auto", 100000)).numpy().xyz.astype(np.float64)  # uncropped
    frame = rec.frame(0, numpy=True)
    n = seen_count(xyz, list(frame.depth), rec.rig)
    seen = (n >= 2) & (world.apply(xyz)[:, 2] > 0.02)
    assert seen.sum() > 10000
    assert volume.contains(xyz)[seen].mean() >= 0.99


@pytest.fixture(scope="module")
def studio(tmp_path_factory):
    from fuseflow.synth import SimConfig, simulate_recording

    out = tmp_path_factory.mktemp("world") / "rec"
    simulate_recording(out, SimConfig(cameras=6, frames=2, resolution=(160, 120), seed=3, noise="realsense"))
    return out


def test_floor_frame_levels_the_simulated_floor_and_other_worlds(studio, tmp_path):
    from fuseflow.fuse import fuse
    from fuseflow.fuse.presets import preset_config
    from fuseflow.io import open_recording

    rec = open_recording(studio)
    raw = fuse(rec[1], rec.rig, preset_config("auto")).numpy()
    fuse_recording(studio, tmp_path / "calib", frames=range(1, 2), outputs=OutputOptions(world="calib"))
    assert np.allclose(read_ply(tmp_path / "calib" / "clouds" / "000001.ply").xyz.numpy(), raw.xyz, atol=1e-6)
    cam = rec.rig.cameras[2]
    fuse_recording(studio, tmp_path / "cam", frames=range(1, 2), outputs=OutputOptions(world=f"camera:{cam.id}"))
    T = cam.T_cam_world
    got = read_ply(tmp_path / "cam" / "clouds" / "000001.ply").xyz.numpy()
    assert np.allclose(got, raw.xyz @ T[:3, :3].T + T[:3, 3], atol=1e-4)
    fuse_recording(studio, tmp_path / "floor", frames=range(1, 2))  # default: the floor frame
    w = read_calibration(tmp_path / "floor" / "calib.json").report["world"]
    R = np.asarray(w["T_out_world"])[:3, :3]
    assert w["name"] == "floor" and _angle(R @ [0.0, 0.0, 1.0], 2) < 1.0  # the simulator's floor is z = 0, z up
    assert abs(np.asarray(w["T_out_world"])[2, 3]) < 0.02  # the origin lies on that floor
    r = _invoke("fuse", studio, "--out", tmp_path / "bad", "--world", "camera:nope")
    assert r.exit_code == 2 and "camera:nope" in r.output and not (tmp_path / "bad").exists()


def test_added_format_resumes_and_bad_formats_are_refused_before_fusing(studio, tmp_path, monkeypatch):
    out = tmp_path / "o"
    r = _invoke("fuse", studio, "--out", out, "--crop", "auto")
    assert r.exit_code == 0, r.output
    before = (out / "clouds" / "000000.ply").read_bytes()
    r = _invoke("fuse", studio, "--out", out, "--crop", "auto", "--format", "ply,drc,glb,splat")
    assert r.exit_code == 0, r.output
    for f in ("clouds/000000.drc", "clouds/000001.glb", "splats/000001.ply"):
        assert (out / f).exists(), f
    assert (out / "clouds" / "000000.ply").read_bytes() == before  # fused again: the same cloud
    r = _invoke("fuse", studio, "--out", out, "--crop", "auto", "--format", "ply,drc")
    assert r.exit_code == 0 and "2 kept from an earlier call" in r.output
    r = _invoke("fuse", studio, "--out", tmp_path / "x", "--format", "ply,obj")
    assert r.exit_code == 2 and "--format" in r.output and not (tmp_path / "x").exists()
    import fuseflow.io.exchange as exchange

    def missing():
        raise exchange.FormatError("Draco output needs DracoPy (a dependency of fuseflow): pip install DracoPy")

    monkeypatch.setattr(exchange, "_need_draco", missing)
    r = _invoke("fuse", studio, "--out", tmp_path / "y", "--format", "ply,drc")
    assert r.exit_code != 0 and "DracoPy" in r.output and not (tmp_path / "y").exists()


def test_voxel_thins_each_cloud_to_one_point_a_cube(studio, tmp_path):
    fuse_recording(studio, tmp_path / "all", frames=range(1))
    fuse_recording(studio, tmp_path / "v", frames=range(1), outputs=OutputOptions(voxel_mm=50))
    whole = read_ply(tmp_path / "all" / "clouds" / "000000.ply")
    thin = read_ply(tmp_path / "v" / "clouds" / "000000.ply")
    cells = np.floor(thin.xyz.numpy().astype(np.float64) / 0.05)
    assert len(np.unique(cells, axis=0)) == len(thin) < 0.7 * len(whole)


def test_view_refuses_weight_colours_from_draco_clouds(studio, tmp_path):
    out = tmp_path / "o"
    fuse_recording(studio, out, frames=range(1), outputs=OutputOptions(cloud_format="drc"))
    r = _invoke("view", out, "--save-png", tmp_path / "png", "--color-by", "weight")
    assert r.exit_code != 0 and "weight" in r.output and ".drc" in r.output and not list(tmp_path.glob("png/*.png"))
    fuse_recording(studio, out, frames=range(1), outputs=OutputOptions(cloud_format="drc,ply"))
    r = _invoke("view", out, "--save-png", tmp_path / "png", "--color-by", "weight")
    assert r.exit_code == 0, r.output  # the PLY of the same frame keeps the weights
    assert [p.name for p in (tmp_path / "png").glob("*.png")] == ["000000.png"]


def test_rerun_log_subsamples_unless_asked_for_every_point(tmp_path):
    pytest.importorskip("rerun")
    from fuseflow.types import FusedCloud
    from fuseflow.viz.rerun_log import RerunLogger

    n = 250_000
    rng = np.random.default_rng(0)
    cloud = FusedCloud.from_numpy(rng.random((n, 3)), np.zeros((n, 3)), np.ones(n), np.zeros(n))
    small, full = RerunLogger(save_to=tmp_path / "s.rrd"), RerunLogger(save_to=tmp_path / "f.rrd")
    assert small.log_cloud(0, cloud) == 100_000 and full.log_cloud(0, cloud, max_points=None) == n
    small.close()
    full.close()
    assert (tmp_path / "s.rrd").stat().st_size < 0.6 * (tmp_path / "f.rrd").stat().st_size


def test_splat_renderer_draws_an_opaque_splat_where_it_projects():
    from fuseflow.viz.splat_render import render_splats

    K = np.array([[100.0, 0, 49.5], [0, 100.0, 49.5], [0, 0, 1]])
    xyz = np.array([[0.0, 0.0, 2.0], [0.0, 0.0, 3.0], [0.5, 0.5, 2.0]])
    rgb = np.array([[255, 0, 0], [0, 0, 255], [0, 255, 0]])
    img = render_splats(xyz, rgb, np.full(3, 0.1), np.array([0.99, 0.99, 0.5]), K, np.eye(4), 100, 100)
    assert img[50, 50, 0] > 240 and img[50, 50, 2] < 10  # the red splat hides the blue one behind it
    g = img[75, 75].astype(int)  # the half-transparent green splat over the white background
    assert g[1] > 240 and 100 < g[0] < 160
    assert tuple(img[5, 5]) == (255, 255, 255)


def test_range_mesh_joins_each_cameras_points_and_skips_depth_edges(studio):
    from fuseflow.fuse import fuse
    from fuseflow.io import open_recording
    from fuseflow.pipeline.mesh import mesh_range

    rec = open_recording(studio)
    cloud = fuse(rec[0], rec.rig).numpy()
    mesh = mesh_range(cloud, rec.rig)
    xyz = np.asarray(cloud.xyz)
    assert len(mesh.faces) > len(cloud) // 4
    # the vertices are fused points, with their colours
    from scipy.spatial import cKDTree

    d, i = cKDTree(xyz).query(mesh.vertices)
    assert d.max() < 1e-6 and np.array_equal(mesh.colors, np.asarray(cloud.rgb)[i])
    v = mesh.vertices[mesh.faces]
    edge = np.linalg.norm(v - np.roll(v, 1, axis=1), axis=2).max(axis=1)
    assert edge.max() < 0.5  # no triangle bridges a depth edge (without the edge limit: 0.88 m)
    n = np.linalg.norm(mesh.normals, axis=1)
    assert np.allclose(n[n > 0], 1, atol=1e-4)
