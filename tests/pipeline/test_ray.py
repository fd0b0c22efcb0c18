"""`run(..., ray=RayOptions(...))`: the same outputs as the single-process run, retries, order."""

from __future__ import annotations

import json

import pytest
import torch

from fuseflow.io import open_recording, read_ply
from fuseflow.pipeline import cloud_path, run

ray = pytest.importorskip("ray", reason="Ray is the optional extra fuseflow[ray] (installed with [test])")

from fuseflow.pipeline.ray import RayOptions, ray_frame_results  # noqa: E402


@pytest.fixture(scope="module")
def local_ray():
    ray.init(address="local", num_cpus=2, include_dashboard=False, logging_level="ERROR", log_to_driver=False)
    yield
    ray.shutdown()


def _same(a, b) -> bool:
    return all(torch.equal(getattr(a, k), getattr(b, k)) for k in ("xyz", "rgb", "weight", "camera"))


def test_ray_run_matches_single_process(static_rec, tmp_path, local_ray):
    single = run(static_rec, tmp_path / "single", use_rig_extrinsics=True)
    dist = run(static_rec, tmp_path / "ray", use_rig_extrinsics=True, ray=RayOptions(max_in_flight=3))
    assert dist.frames == single.frames == dist.frames_fused_now
    for t in range(single.frames):
        assert _same(read_ply(cloud_path(tmp_path / "ray", t)), read_ply(cloud_path(tmp_path / "single", t)))
    a = [json.loads(x) for x in (tmp_path / "single" / "frames.jsonl").read_text().splitlines()]
    b = [json.loads(x) for x in (tmp_path / "ray" / "frames.jsonl").read_text().splitlines()]
    strip = lambda r: {k: v for k, v in r.items() if k != "fuse_ms"}  # noqa: E731
    assert [strip(r) for r in a] == [strip(r) for r in b]  # same records, in frame order


def test_killed_worker_is_retried_without_loss_or_duplicates(static_rec, tmp_path, local_ray):
    rec = open_recording(static_rec)
    from fuseflow.pipeline import PipelineConfig

    markers = {2: str(tmp_path / "kill2"), 4: str(tmp_path / "kill4")}
    got = list(
        ray_frame_results(
            str(static_rec),
            range(len(rec)),
            list(range(len(rec.rig))),
            rec.rig,
            PipelineConfig(),
            RayOptions(max_in_flight=2, max_retries=2),
            fail_once=markers,
        )  # fmt: skip
    )
    assert [p for p, *_ in got] == list(range(len(rec)))  # each frame once, in order
    assert all((tmp_path / f"kill{k}").exists() for k in (2, 4))  # the workers really died once
    from fuseflow.pipeline import OutputOptions

    calib_world = PipelineConfig(outputs=OutputOptions(world="calib"))  # the workers' clouds: calibration world
    ref = run(static_rec, tmp_path / "ref", use_rig_extrinsics=True, config=calib_world)
    assert ref.frames == len(got)
    for p, cloud, record, _ in got:
        assert record.index == p and _same(cloud, read_ply(cloud_path(tmp_path / "ref", p)))


def test_ray_resume_skips_done_frames(static_rec, tmp_path, local_ray):
    out = tmp_path / "o"
    run(static_rec, out, use_rig_extrinsics=True, frames=range(0, 3))
    s = run(static_rec, out, use_rig_extrinsics=True, ray=RayOptions())
    assert s.frames_resumed == 3 and s.frames_fused_now == s.frames - 3
