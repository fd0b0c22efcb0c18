"""Scale-out of per-frame fusion over a Ray cluster (optional extra ``fuseflow[ray]``).

Formerly ``fuseflow.distributed``; ``RayOptions`` is also exported by ``fuseflow.pipeline``.

FUSE keeps no state between frames, so a long recording parallelises over frames. This module
uses Ray and no scheduler of its own:

* the calibrated rig and the FUSE / pipeline configs are put into the object store once and
  shared by every task (``ray.put``);
* each task opens the recording by path (workers must see the same filesystem: a shared or
  network mount on a cluster), loads one frame, fuses it and returns the cloud as numpy arrays
  plus its per-frame record; the driver writes clouds in frame order;
* backpressure: at most ``max_in_flight`` tasks are outstanding, so memory stays bounded
  whatever the recording's length;
* failures: a task whose worker dies is retried by Ray (``max_retries``); a frame is yielded
  exactly once, in order.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from fuseflow.errors import FuseFlowError, require

if TYPE_CHECKING:
    from fuseflow.pipeline.config import PipelineConfig
    from fuseflow.pipeline.records import FrameRecord
    from fuseflow.types import FusedCloud, Rig

__all__ = ["RayOptions", "ray_frame_results", "check_ray_address"]


@dataclass(frozen=True)
class RayOptions:
    """How to reach Ray and how hard to push it."""

    address: str | None = None
    """Cluster address ("auto", "ray://host:10001", "host:6379"); None starts a local Ray."""
    num_cpus: int | None = None
    """CPUs of a local Ray (None = all); ignored when joining a cluster."""
    max_in_flight: int | None = None
    """Tasks outstanding at once; None = 2 x the cluster's CPUs. Bounds memory (backpressure)."""
    max_retries: int = 3
    """Times Ray re-runs a task whose worker died."""
    cpus_per_task: float = 1.0
    """Ray CPU resource per fusion task."""


_RECORDINGS: dict[str, Any] = {}


def _fuse_task(
    rec_path: str, position: int, sel: Sequence[int], rig: Rig, pipeline_config: PipelineConfig, fail_once: str | None,
    threads: int = 1,
):  # fmt: skip
    """One frame: load, fuse, measure agreement. Returns (position, arrays, record, load ms).

    ``threads``: the CPUs Ray reserved for the task; torch and numba use no more, so that
    tasks sharing a node do not oversubscribe its cores.
    """
    import os
    import time

    import torch

    from fuseflow.io.datasets import open_recording
    from fuseflow.pipeline.frames import process_frame

    if fail_once is not None and not os.path.exists(fail_once):
        # test hook: the first attempt of this task kills its worker process
        open(fail_once, "w").close()
        os._exit(1)
    torch.set_num_threads(threads)
    try:
        import numba

        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    except ImportError:  # pragma: no cover - numba is a core dependency
        pass
    rec = _RECORDINGS.get(rec_path)
    if rec is None:
        rec = _RECORDINGS[rec_path] = open_recording(rec_path)
    t0 = time.perf_counter()
    frame = rec[position]
    load_ms = (time.perf_counter() - t0) * 1000.0
    cloud, record = process_frame(frame, sel, rig, pipeline_config)
    c = cloud.to("cpu")
    support = None if c.support is None else c.support.numpy()
    arrays = (c.xyz.numpy(), c.rgb.numpy(), c.weight.numpy(), c.camera.numpy(), support)
    return position, arrays, record, load_ms


def check_ray_address(address: str, timeout: float = 3.0) -> None:
    """FuseFlowError at once when nothing accepts a TCP connection at a "host:port" (or
    "ray://host:port") Ray address; Ray itself retries for minutes. "auto" and "local" pass."""
    import socket

    hostport = address.split("://", 1)[-1]
    host, _, port = hostport.rpartition(":")
    if address in ("auto", "local") or not host or not port.isdigit():
        return
    try:
        with socket.create_connection((host, int(port)), timeout=timeout):
            return
    except OSError as exc:
        raise FuseFlowError(
            f"--ray-address {address}: no Ray cluster answers there ({exc.strerror or exc}); start one "
            "(ray start --head) or drop --ray-address to start a local Ray"
        ) from None


def ray_frame_results(
    rec_path: str,
    positions: Sequence[int],
    sel: Sequence[int],
    rig: Rig,
    pipeline_config: PipelineConfig,
    options: RayOptions = RayOptions(),
    fail_once: dict[int, str] | None = None,
) -> Iterator[tuple[int, FusedCloud, FrameRecord, float]]:
    """Fuse ``positions`` of the recording at ``rec_path`` on Ray; yield in order
    (position, FusedCloud, FrameRecord, load_ms).

    ``fail_once`` (tests): position -> marker file; that frame's first attempt kills its worker.
    """
    ray = require("ray", "ray", "--ray (fusing frames on Ray)")
    from fuseflow.types import FusedCloud

    started_here = False
    if options.address is not None and not ray.is_initialized():
        check_ray_address(options.address)
    if not ray.is_initialized():
        kw: dict[str, Any] = {"include_dashboard": False, "logging_level": "ERROR", "log_to_driver": False}
        if options.address is None:  # a private local Ray, also beside a cluster `ray start` left running
            kw["num_cpus"] = options.num_cpus
        try:
            ray.init(address=options.address or "local", **kw)
        except (ConnectionError, RuntimeError, ValueError) as exc:
            where = f"--ray-address {options.address}" if options.address else "a local Ray"
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise FuseFlowError(
                f"{where}: could not connect ({first[:200]}); start the cluster (ray start --head) or drop "
                "--ray-address to start a local Ray"
            ) from None
        started_here = True
    try:
        task = ray.remote(num_cpus=options.cpus_per_task, max_retries=options.max_retries)(_fuse_task)
        rig_ref = ray.put(rig)
        cfg_ref = ray.put(pipeline_config)
        sel_ref = ray.put(list(sel))
        threads = max(1, int(options.cpus_per_task))
        limit = options.max_in_flight or max(2, 2 * int(ray.cluster_resources().get("CPU", 1)))
        pending: dict[int, Any] = {}
        done: dict[int, Any] = {}
        todo = list(positions)
        nxt = 0
        for want in todo:
            while nxt < len(todo) and len(pending) + len(done) < limit:
                p = todo[nxt]
                marker = (fail_once or {}).get(p)
                pending[p] = task.remote(rec_path, p, sel_ref, rig_ref, cfg_ref, marker, threads)
                nxt += 1
            while want not in done:
                refs = list(pending.values())
                ready, _ = ray.wait(refs, num_returns=1)
                for p, r in list(pending.items()):
                    if r in ready:
                        try:
                            done[p] = ray.get(r)
                        except ray.exceptions.RayError as exc:
                            cause = getattr(exc, "cause", None)
                            if isinstance(cause, FuseFlowError):
                                raise cause from None
                            raise FuseFlowError(f"frame at position {p} failed on Ray after retries: {exc}") from None
                        del pending[p]
            position, arrays, record, load_ms = done.pop(want)
            yield position, FusedCloud.from_numpy(*arrays), record, load_ms
    finally:
        if started_here:
            ray.shutdown()
