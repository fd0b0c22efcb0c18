"""Capture nodes: the machines that read cameras and ship encoded frames to the fusing host,
as Ray actors (``fuseflow node SOURCE --ray ADDRESS``; optional extra ``fuseflow[ray]``).

A ``CaptureNode`` runs in a Ray actor on the capture machine. It opens its SOURCE there
(``open_source``: RealSense, Orbbec, or a replay of a recording, optionally of some of its
cameras, ``NodeOptions.cameras``), reads it in a thread, stamps each frame with the node's clock
(``clock.NodeClock``: when the replay released it, or when the devices delivered it) and
keeps the newest ``buffer`` frames. The fusing host (``ray_source.RaySource``) asks for
the stamp of the newest one (``newest``), then every node for its frame nearest one instant
(``frame_at``): the node encodes that frame in the wire format the host asks for
(``frame_codec``: raw arrays, raw colour with LZ4 depth, or JPEG or PNG colour with lossless LZ4 or PNG depth) and the answer
travels through Ray's object store. A node slower than its cameras thus
skips the same instants as the others, and the fused frames keep every view. The host probes
``clock`` to estimate the node's clock offset. The actor is threaded (``max_concurrency``), so
a probe is answered while a ``newest`` waits for a frame.

Nodes register by name in the Ray namespace ``NAMESPACE`` (``fuseflow-node:<name>``); the
fusing host finds them there, also when one comes back after it died. ``start_node`` pins the
actor to the machine that runs it (``fuseflow node``); ``spawn_node`` places it by Ray resources
(a custom resource per capture machine, ``ray start --resources '{"cap1": 1}'``).
"""

from __future__ import annotations

import socket
import threading
import time
import uuid
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from fuseflow.errors import FuseFlowError, ValidationError, require
from fuseflow.live.sources import ReplayOptions, open_source
from fuseflow.live.sources.clock import NodeClock
from fuseflow.live.sources.frame_codec import EncodedViews, ViewCodec, encode_views
from fuseflow.live.sources.replay import DEFAULT_RATE

__all__ = ["NAMESPACE", "CaptureNode", "NodeFrame", "NodeOptions", "actor_name", "connect_ray", "node_name", "spawn_node", "wire_codec",
           "start_node"]  # fmt: skip

NAMESPACE = "fuseflow-live"
"""The Ray namespace where capture nodes register."""

PREFIX = "fuseflow-node:"

INLINE_BYTES = 64 << 20
"""A capture node's answers up to this size travel inline in Ray's reply to the call, straight
from the node's process to the caller's, instead of through the object stores (Ray's default
puts anything over 100 kB in the node's object store, from which the fusing host's Ray node
pulls it: two raylets copy every frame on top of the two processes)."""

INLINE_ENV = {
    "RAY_max_direct_call_object_size": str(INLINE_BYTES),
    "RAY_task_rpc_inlined_bytes_limit": str(INLINE_BYTES),
}
"""Ray settings (environment of the capture node's actor process) for ``INLINE_BYTES``."""


def actor_name(name: str, token: str) -> str:
    """``fuseflow-node:<name>:<token>``: a node restarted under its old name registers anew at
    once (the actor of the one that died may still hold its registration for a while)."""
    return f"{PREFIX}{name}:{token}"


def node_name(actor: str) -> str:
    """The node name in a registered actor name (``actor_name``)."""
    return actor[len(PREFIX) :].rsplit(":", 1)[0]


@dataclass(frozen=True)
class NodeOptions:
    """What a capture node reads and how it ships it."""

    name: str | None = None
    """Its name (unique in the cluster); None = the host name."""
    cameras: tuple[str, ...] | None = None
    """The cameras of SOURCE this node ships (None = all)."""
    codec: ViewCodec = ViewCodec()
    replay: ReplayOptions = ReplayOptions(loop=True, preload=True, aligned=True)
    """A replayed recording: looped, decoded once into memory and paced by the wall clock from a
    start every node shares, so that nodes replaying other cameras of it stay in step."""
    clock_offset_s: float = 0.0
    """Added to the node's clock (tests: a node whose clock is off by a known amount)."""
    stamp_drift: float = 0.0
    """Seconds a second by which the capture stamps slide from the node's clock, from the first
    frame on (tests: a camera whose timestamps drift while the node's clock answers right)."""
    buffer: int = 8
    """Frames kept (decoded) for the fusing host to ask for: the newest ``buffer``."""
    token: str | None = None
    """Tells this start of the node from an earlier one of the same name (``spawn_node`` sets it)."""


@dataclass
class NodeFrame:
    """One frame of a node's cameras, as it travels to the fusing host."""

    number: int
    """Sequence number on this node (0, 1, ...)."""
    index: int
    """The frame's own index (a replay's frame number; a device source counts from 0)."""
    stamp: float
    """Node clock (seconds) when the frame was captured."""
    views: EncodedViews
    meta: dict[str, Any] = field(default_factory=dict)


class CaptureNode:
    """A capture machine's cameras, encoded and buffered (module docstring). Made a Ray actor by
    ``start_node`` / ``spawn_node``; usable as a plain object in one process."""

    def __init__(self, specs: Sequence[str], options: NodeOptions = NodeOptions()):
        options.codec.check()
        self.options = options
        self.name = options.name or socket.gethostname()
        self.token = options.token or uuid.uuid4().hex
        self._opened = open_source(list(specs), replace(options.replay, aligned=True))
        rig = self._opened.rig
        ids = list(options.cameras or rig.ids)
        unknown = [c for c in ids if c not in rig.ids]
        if unknown:
            self._opened.close()
            raise ValidationError(f"--cameras {unknown}: SOURCE has cameras {list(rig.ids)}")
        self._sel = [rig.ids.index(c) for c in ids]
        self.rig = rig.subset(self._sel)
        self._scales = [float(c.depth_scale) for c in self.rig.cameras]
        self._clock = NodeClock(options.clock_offset_s)
        self._frames: deque[NodeFrame] = deque(maxlen=max(1, options.buffer))
        self._cond = threading.Condition()
        self._count = 0
        self._closed = False
        self.error: str | None = None
        self._encode_ms: deque[float] = deque(maxlen=200)
        self._bytes: deque[int] = deque(maxlen=200)
        self._thread = threading.Thread(target=self._capture, name="fuseflow-node", daemon=True)
        self._thread.start()

    def _rate(self) -> float | None:
        src = self._opened.source
        config = getattr(src, "config", None)
        if config is not None:
            return float(config.fps)
        rec = getattr(src, "rec", None)
        if rec is None:
            return None
        if getattr(src, "rate", None):
            return float(src.rate)
        a, b = rec[0].timestamp, rec[len(rec) - 1].timestamp
        if len(rec) > 1 and a is not None and b is not None and b > a:
            return (len(rec) - 1) / (b - a)
        return DEFAULT_RATE  # what the replay paces a recording without timestamps at

    def info(self) -> dict[str, Any]:
        """Name, machine (``host``; ``ray_node`` and ``ip``: its Ray node id and address, None
        outside Ray), cameras (``rig``), frame rate, codec and this actor's token (new each start)."""
        return {"name": self.name, "host": socket.gethostname(), **_ray_place(), "rig": self.rig, "rate": self._rate(),
                "codec": self.options.codec, "token": self.token, "description": self._opened.description}  # fmt: skip

    def clock(self) -> float:
        """The node's clock now (seconds): the answer of a clock probe."""
        return self._clock()

    def _capture(self) -> None:
        src = self._opened.source
        first = None
        try:
            for frame in self._opened.frames():
                due = getattr(src, "due", None)  # a replay's capture time, on the wall clock
                stamp = due + self._clock.offset_s if due is not None else self._clock()
                first = stamp if first is None else first
                stamp += self.options.stamp_drift * (stamp - first)
                # the frame as delivered: its cameras are picked when it is asked for (``frame_at``),
                # so that the frames no one asks for cost no copy
                with self._cond:
                    self._frames.append((self._count, int(frame.index), stamp, frame))
                    self._count += 1
                    self._cond.notify_all()
                if self._closed:
                    break
        except Exception as exc:  # noqa: BLE001 - reported to the fusing host by next() and stats()
            self.error = f"{type(exc).__name__}: {exc}"
        finally:
            with self._cond:
                self._closed = True
                self._cond.notify_all()

    def newest(self, after: int, timeout: float = 0.5) -> tuple[int, float] | None:
        """(number, stamp) of the newest frame once one numbered above ``after`` is there,
        waiting up to ``timeout`` s; None if none came."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while not (self._frames and self._frames[-1][0] > after) and not self._closed:
                left = deadline - time.monotonic()
                if left <= 0:
                    return None
                self._cond.wait(left)
            if not self._frames or self._frames[-1][0] <= after:
                return None
            return self._frames[-1][0], self._frames[-1][2]

    def frame_at(self, stamp: float, tolerance: float, codec: str | None = None, shared: bool = False) -> Any:
        """The kept frame whose stamp is nearest ``stamp`` (node clock), if within ``tolerance``
        seconds, encoded with ``codec`` (``wire_codec``: raw, raw16, lz4, jpeg or png; None: the node's own);
        None otherwise. Every node is asked for the same instant, so that the frames a slow node
        encodes are the ones the others encode too.

        How it travels: in the call's reply (``spawn_node`` lets Ray inline replies up to
        ``INLINE_BYTES``: one copy from this process to the caller, no object store in between),
        or with ``shared`` (the caller runs on this node's Ray node) put into this Ray node's
        object store and answered as ``[ref]``, which the caller reads from shared memory."""
        wire = wire_codec(self.options.codec, codec)
        with self._cond:
            near = [f for f in self._frames if abs(f[2] - stamp) <= tolerance]
            pick = min(near, key=lambda f: abs(f[2] - stamp)) if near else None
        if pick is None:
            return None
        number, index, at, frame = pick
        color, depth, present = (self._cameras(np.asarray(x)) for x in (frame.color, frame.depth, frame.present))
        views = encode_views(color, depth, present, self._scales, wire.check())
        with self._cond:
            self._encode_ms.append(views.encode_ms)
            self._bytes.append(views.nbytes)
        out = NodeFrame(number, index, at, views)
        if shared:
            import ray

            return [ray.put(out)]
        return out

    def _cameras(self, x: np.ndarray) -> np.ndarray:
        """This node's cameras of a (N, ...) array of every camera of SOURCE: a view when they
        are consecutive, a copy otherwise."""
        sel = self._sel
        if sel == list(range(sel[0], sel[0] + len(sel))):
            return x[sel[0] : sel[0] + len(sel)]
        return x[sel]

    def stats(self) -> dict[str, Any]:
        with self._cond:
            enc = list(self._encode_ms)
            size = list(self._bytes)
            return {"frames": self._count, "skipped": int(getattr(self._opened.source, "skipped", 0)),
                    "encode_ms_median": round(float(np.median(enc)), 2) if enc else None,
                    "bytes_per_frame_median": int(np.median(size)) if size else None,
                    "ended": self._closed, "error": self.error}  # fmt: skip

    def stop(self) -> None:
        """Stop capturing and release the cameras; idempotent."""
        self._closed = True
        self._opened.close()
        self._thread.join(timeout=5.0)


def wire_codec(own: ViewCodec, wire: str | None) -> ViewCodec:
    """The codec of a frame asked for as ``wire``: None, the node's own (``NodeOptions.codec``);
    raw, the arrays; lz4, raw colour bytes and LZ4 depth (both lossless); jpeg or png, that colour
    coder with the node's depth coder."""
    if wire is None:
        return own
    if wire in ("raw", "raw16"):
        return replace(own, color="raw", depth_raw=True, depth_units=wire == "raw16")
    if wire == "lz4":
        return replace(own, color="raw", depth="lz4", depth_raw=False)
    return replace(own, color=wire, depth_raw=True)


def _ray_place() -> dict[str, str | None]:
    """``ray_node`` (node id) and ``ip`` of the Ray node this process runs on; None outside Ray."""
    try:
        import ray

        if not ray.is_initialized():
            return {"ray_node": None, "ip": None}
        return {"ray_node": ray.get_runtime_context().get_node_id(), "ip": ray.util.get_node_ip_address()}
    except ImportError:
        return {"ray_node": None, "ip": None}


def connect_ray(address: str | None, what: str) -> bool:
    """Connect this process to Ray at ``address`` (None: a local Ray) in ``NAMESPACE``; True when
    this call connected (the caller shuts it down). FuseFlowError in one line when nothing answers."""
    ray = require("ray", "ray", what)
    if ray.is_initialized():
        return False
    if address not in (None, "auto", "local"):
        _check_reachable(address, what)
    try:
        ray.init(address=address, namespace=NAMESPACE, include_dashboard=False, logging_level="ERROR",
                 log_to_driver=False, configure_logging=False)  # fmt: skip
    except (ConnectionError, RuntimeError, ValueError) as exc:
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise FuseFlowError(f"{what}: could not join the Ray cluster at {address} ({first[:200]}); "
                            "start it with ray start --head on the fusing host") from None  # fmt: skip
    return True


def _check_reachable(address: str, what: str, timeout: float = 3.0) -> None:
    hostport = address.split("://", 1)[-1]
    host, _, port = hostport.rpartition(":")
    if not host or not port.isdigit():
        raise FuseFlowError(
            f"{what}: --ray expects HOST:PORT of the head (ray start --head prints it), got {address!r}"
        )
    try:
        with socket.create_connection((host, int(port)), timeout=timeout):
            return
    except OSError as exc:
        raise FuseFlowError(f"{what}: cannot reach the Ray head at {address} ({exc.strerror or exc}); "
                            "start it there with ray start --head, or check the address and the firewall") from None  # fmt: skip


def spawn_node(specs: Sequence[str], options: NodeOptions = NodeOptions(), resources: dict[str, float] | None = None,
               node_id: str | None = None) -> Any:  # fmt: skip
    """Create the ``CaptureNode`` actor of ``options.name`` on the Ray this process joined: on the
    Ray node ``node_id``, or where ``resources`` are (placement by custom resources); returns its
    handle once it has opened SOURCE. FuseFlowError when it cannot open SOURCE there. Keep the
    handle: Ray ends an actor once no handle to it is left in the process that made it."""
    import ray

    name = options.name or socket.gethostname()
    token = uuid.uuid4().hex[:12]
    kw: dict[str, Any] = {"name": actor_name(name, token), "namespace": NAMESPACE, "max_concurrency": 4, "num_cpus": 0,
                          "resources": resources or {}, "runtime_env": {"env_vars": INLINE_ENV}}  # fmt: skip
    if node_id is not None:
        from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

        kw["scheduling_strategy"] = NodeAffinitySchedulingStrategy(node_id=node_id, soft=False)
    handle = ray.remote(CaptureNode).options(**kw).remote(list(specs), replace(options, name=name, token=token))
    try:
        ray.get(handle.info.remote())
    except ray.exceptions.RayError as exc:
        cause = getattr(exc, "cause", None) or exc
        first = (str(cause).strip().splitlines() or [type(cause).__name__])[-1]
        raise FuseFlowError(f"capture node {name!r} could not open its source: {first[:300]}") from None
    return handle


def start_node(specs: Sequence[str], options: NodeOptions, address: str | None) -> tuple[Any, bool]:
    """Join Ray at ``address`` and start this machine's capture node on it (pinned here);
    (handle, whether this call connected to Ray)."""
    import ray

    joined = connect_ray(address, "fuseflow node")
    try:
        handle = spawn_node(specs, options, node_id=ray.get_runtime_context().get_node_id())
    except BaseException:
        if joined:
            ray.shutdown()
        raise
    return handle, joined
