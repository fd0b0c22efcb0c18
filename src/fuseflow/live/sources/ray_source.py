"""The fusing host's side of capture nodes: ``RaySource`` gathers the frames of every
``node.CaptureNode`` registered on a Ray cluster into one ``Source`` for the live loop.

- **Discovery**: nodes are found by name in ``node.NAMESPACE``. The source waits until
  ``RayLiveOptions.nodes`` nodes registered (or, without a count, until one did and no other
  joined for a second); its cameras are theirs, ordered by camera id. A node that registers
  later (one restarted after it died) joins the stream when its cameras are among these.
- **Transport**: the source asks every node for the stamp of its newest frame (``newest``),
  chooses the instant T (below) and asks every node for its frame nearest T (``frame_at``); the
  answers (``node.NodeFrame``) travel inline in Ray's replies (``node.INLINE_BYTES``: one copy
  from the node's process to this one), or, from a node on this process's own Ray node, through
  that node's object store (shared memory), and are decoded here (``frame_codec.decode_views``). Up to ``RayLiveOptions.in_flight`` instants are in transfer at
  once, and the next ``newest`` round trip overlaps them. In the live loop (``paced_by``) frames
  are asked for only while fusion is ready for them: a node encodes and ships the frames that
  are fused, not every frame it captures.
- **Wire format** (``RayLiveOptions.frame_codec``): ``auto`` ships a node's frames raw (the
  arrays, bit for bit) when the node runs on this machine: through shared memory from this
  process's own Ray node, inline in the reply from another Ray node (smaller formats, ``raw16``
  with depth as uint16 depth units or ``lz4``, cost the node more to encode than the smaller
  copy saves); and in the node's own codec (JPEG or PNG colour, lossless LZ4 or PNG depth) when
  they cross a network; ``raw``, ``raw16``, ``lz4``, ``jpeg`` or ``png`` force one for every
  node.
- **Clocks**: a thread probes every node's ``clock`` every ``probe_every_s`` and keeps a
  min-RTT estimate of its offset (``clock.OffsetEstimator``); each frame's stamp is moved onto
  this host's clock by it before pairing.
- **Pairing**: T is the oldest of the nodes' newest corrected stamps, once every node has a
  frame past the last T; each node answers with its frame within half a frame interval of T.
  A node that delivered no new frame for ``stall_s`` is stalled: it is not waited for and its
  cameras are missing from the fused frames (counted by the live loop, warned through ``warn``)
  until it delivers again.
- **Skew report** (``status``): per node the offset, its uncertainty and round trip, the link and
  wire format; per camera how far its paired stamps were from T (median and max over the last
  frames) and its drift from the other cameras (``clock.StampDrift``), warned once per camera
  when it exceeds half a frame interval.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from fuseflow.errors import FuseFlowError, ValidationError
from fuseflow.live.sources.clock import OffsetEstimator, StampDrift, probe
from fuseflow.live.sources.frame_codec import decode_views
from fuseflow.live.sources.node import NAMESPACE, PREFIX, connect_ray, node_name, wire_codec
from fuseflow.types import Frame, Rig

__all__ = ["FRAME_CODECS", "RayLiveOptions", "RaySource"]

FRAME_CODECS = ("auto", "raw", "raw16", "lz4", "jpeg", "png")


@dataclass(frozen=True)
class RayLiveOptions:
    """Where the capture nodes are and how their frames are paired."""

    address: str | None = "auto"
    """Ray address of the cluster (``ray start --head`` prints it); "auto" = the local one."""
    nodes: int | None = None
    """Wait for this many capture nodes (None: one, plus any that joins within a second)."""
    wait_s: float = 30.0
    """Give up when the nodes have not registered after this many seconds."""
    stall_s: float = 0.5
    """A node that delivered nothing for this long is stalled: its cameras go missing."""
    probe_every_s: float = 0.1
    """Clock probes per node: one every this many seconds."""
    window: int = 32
    """Clock probes the min-RTT estimate chooses from."""
    correct_clocks: bool = True
    """Move node stamps onto this host's clock by the estimated offsets (False: pair the raw stamps)."""
    rate: float | None = None
    """Frames per second of the cameras (None: the nodes' own rate; 15 when they do not know it)."""
    in_flight: int = 2
    """Instants whose frames may be in transfer at once (1: fetch one frame after the other)."""
    frame_codec: str = "auto"
    """How frames travel (``FRAME_CODECS``): auto (raw from a node on this machine, the node's
    codec from another machine), raw, raw16 (depth as 16-bit depth units), lz4, jpeg or png."""


@dataclass
class _Arrived:
    t: float  # this host's clock
    index: int
    stamp: float  # the node's clock
    color: np.ndarray
    depth: np.ndarray
    present: np.ndarray


@dataclass
class _Node:
    name: str
    handle: Any
    token: str
    cameras: tuple[str, ...]
    slots: list[int]
    scales: list[float]
    estimator: OffsetEstimator
    wire: str | None = None  # the codec asked of it (None: the node's own)
    link: str = "network"
    codec: str = ""  # the wire format its frames come in
    buffer: deque = field(default_factory=lambda: deque(maxlen=8))
    pending: Any = None
    after: int = -1
    last_arrival: float = field(default_factory=time.time)
    newest: float = -np.inf
    alive: bool = True
    stalled: bool = False
    frames: int = 0
    bytes: deque = field(default_factory=lambda: deque(maxlen=100))
    encode_ms: deque = field(default_factory=lambda: deque(maxlen=100))
    decode_ms: deque = field(default_factory=lambda: deque(maxlen=100))


class RaySource:
    """The frames of every capture node on a Ray cluster, paired, as one live ``Source``
    (module docstring). ``warn(message)`` is called (from a background thread) when a node
    stalls, dies, joins or comes back."""

    def __init__(self, options: RayLiveOptions = RayLiveOptions(), warn: Callable[[str], None] | None = None):
        if not int(options.in_flight) >= 1:
            raise ValidationError(f"in_flight must be at least 1, got {options.in_flight}")
        if options.frame_codec not in FRAME_CODECS:
            raise ValidationError(f"frame codec must be one of {', '.join(FRAME_CODECS)}, got {options.frame_codec!r}")
        self.options = options
        self._warn = warn or (lambda m: None)
        self._lock = threading.Lock()
        self._nodes: dict[str, _Node] = {}
        self._seen: set[str] = set()
        self.scan_error: str | None = None
        """The last error looking for nodes that joined (None: none)."""
        self._closed = threading.Event()
        self._started_ray = connect_ray(options.address, "fuseflow live --ray")
        self._here = self._place()
        self.events: list[tuple[float, str]] = []
        """(time.time, message) of every warning given, in order."""
        try:
            infos = self._wait_for_nodes()
            self.rig = self._rig(infos)
            self.resolution = self.rig.resolution
            rates = [i["rate"] for _, i in infos if i.get("rate")]
            self.rate = options.rate or (float(np.median(rates)) if rates else 15.0)
            for handle, info in infos:
                self._add(handle, info)
            for node in list(self._nodes.values()):
                for _ in range(8):
                    self._probe(node)
        except BaseException:
            self.close()
            raise
        self.description = (
            f"{len(self._nodes)} capture nodes on Ray ({len(self.rig)} cameras: {', '.join(self.rig.ids)})"
        )
        self.released: float | None = None
        self.skipped = 0
        self._last_t = -np.inf
        self._skew: dict[str, deque] = {c: deque(maxlen=100) for c in self.rig.ids}
        self._drift = StampDrift(1.0 / self.rate)
        self._paired = {"frames": 0, "mixed_index": 0}
        self._backlog: Callable[[], int] = lambda: 0
        self._thread = threading.Thread(target=self._watch, name="fuseflow-ray-clock", daemon=True)
        self._thread.start()

    # -- discovery ---------------------------------------------------------------------------
    def _registered(self) -> list[str]:
        import ray

        names = ray.util.list_named_actors(all_namespaces=True)
        return sorted(d["name"] for d in names if d.get("namespace") == NAMESPACE and d["name"].startswith(PREFIX))

    def _info(self, name: str, timeout: float = 5.0) -> tuple[Any, dict] | None:
        import ray

        try:
            handle = ray.get_actor(name, namespace=NAMESPACE)
            return handle, ray.get(handle.info.remote(), timeout=timeout)
        except Exception as exc:  # noqa: BLE001 - ValueError, RayError: gone or not ready
            self.scan_error = f"{name}: {type(exc).__name__}: {exc}"[:300]
            return None

    def _wait_for_nodes(self) -> list[tuple[Any, dict]]:
        want = self.options.nodes
        deadline = time.monotonic() + self.options.wait_s
        seen: list[str] = []
        settled = None
        while time.monotonic() < deadline:
            names = self._registered()
            if names != seen:
                seen, settled = names, time.monotonic()
            if want is not None and len(seen) >= want:
                break
            if want is None and seen and time.monotonic() - settled >= 1.0:
                break
            time.sleep(0.1)
        self._seen.update(seen)
        infos = [x for x in (self._info(n) for n in seen) if x is not None]
        if not infos or (want is not None and len(infos) < want):
            raise FuseFlowError(
                f"fuseflow live --ray: {len(infos)} capture node(s) registered on the Ray cluster within "
                f"{self.options.wait_s:g} s, {want or 1} wanted: start them with fuseflow node SOURCE --ray ADDRESS"
            )
        return infos

    def _rig(self, infos: list[tuple[Any, dict]]) -> Rig:
        cams: dict[str, Any] = {}
        for _, info in infos:
            for cam in info["rig"].cameras:
                if cam.id in cams:
                    raise FuseFlowError(f"camera {cam.id} is on two capture nodes: give each node its own --cameras")
                cams[cam.id] = cam
        rig = Rig(tuple(cams[c] for c in sorted(cams)))
        if len({(c.width, c.height) for c in rig.cameras}) > 1:
            raise FuseFlowError(
                "the capture nodes' cameras have different resolutions: give them one (--width/--height)"
            )
        return rig

    @staticmethod
    def _place() -> tuple[str, str]:
        import ray

        return ray.get_runtime_context().get_node_id(), ray.util.get_node_ip_address()

    def _link(self, info: dict) -> tuple[str, str | None]:
        """(link, wire format asked of the node) for a node's ``info``."""
        node_id, ip = self._here
        link = ("same Ray node" if info.get("ray_node") == node_id
                else "same machine" if info.get("ip") == ip else "network")  # fmt: skip
        codec = self.options.frame_codec
        if codec == "auto":
            return link, None if link == "network" else "raw"  # None: the node's own codec
        return link, codec

    def _add(self, handle: Any, info: dict) -> _Node:
        ids = tuple(info["rig"].ids)
        link, wire = self._link(info)
        node = _Node(info["name"], handle, info["token"], ids, [self.rig.ids.index(c) for c in ids],
                     [float(c.depth_scale) for c in info["rig"].cameras], OffsetEstimator(self.options.window),
                     wire, link)  # fmt: skip
        node.codec = wire_codec(info["codec"], wire).name
        with self._lock:
            self._nodes[node.name] = node
        return node

    def _say(self, message: str) -> None:
        self.events.append((time.time(), message))
        self._warn(message)

    def _rejoin(self) -> None:
        """Nodes that registered since (new ones, or one restarted after it died or stalled)."""
        for name in self._registered():
            if name in self._seen:
                continue
            short = node_name(name)
            known = self._nodes.get(short)
            got = self._info(name, timeout=2.0)
            if got is None:
                continue  # not answering yet: asked again at the next scan
            self._seen.add(name)
            handle, info = got
            if known is not None and known.alive and not known.stalled:
                self._say(f"another capture node named {short} registered while {short} delivers; ignored")
                continue
            if not set(info["rig"].ids) <= set(self.rig.ids):
                self._say(f"capture node {short} has cameras outside this stream ({list(info['rig'].ids)}); ignored")
                continue
            node = self._add(handle, info)
            for _ in range(4):
                self._probe(node)
            self._say(f"capture node {short} joined: cameras {', '.join(node.cameras)}")

    # -- clocks and health -------------------------------------------------------------------
    def _probe(self, node: _Node) -> None:
        import ray

        try:
            t0, t1, t2 = probe(lambda: ray.get(node.handle.clock.remote(), timeout=self.options.stall_s))
        except ray.exceptions.GetTimeoutError:
            return
        except Exception as exc:  # noqa: BLE001 - RayError, or Ray's plain Exception for an actor it cannot find
            self._lost(node, exc)
            return
        node.estimator.add(t0, t1, t2)

    def _lost(self, node: _Node, exc: BaseException) -> None:
        """``exc`` from a call to the node: gone for good (its actor died; Ray cannot find it), or
        a transient failure (unavailable for a moment: the stall check covers it)."""
        import ray

        if isinstance(exc, ray.exceptions.ActorUnavailableError):
            return
        why = f"its actor is gone ({type(exc).__name__}: {(str(exc).splitlines() or [''])[0][:160]})"
        if node.alive:
            node.alive = False
            self._say(f"capture node {node.name} lost: {why}; cameras {', '.join(node.cameras)} are missing")

    def _watch(self) -> None:
        last_scan = 0.0
        while not self._closed.wait(self.options.probe_every_s):
            now = time.time()
            for node in list(self._nodes.values()):
                if node.alive and not node.stalled:
                    self._probe(node)
            if now - last_scan > 0.5:
                last_scan = now
                try:
                    self._rejoin()
                except Exception as exc:  # noqa: BLE001 - Ray shutting down under us; the next scan retries
                    self.scan_error = f"{type(exc).__name__}: {exc}"

    def _check_stalls(self, now: float) -> None:
        for node in list(self._nodes.values()):
            if node.alive and node.slots and not node.stalled and now - node.last_arrival > self.options.stall_s:
                node.stalled = True
                self._say(f"capture node {node.name} delivered nothing for {now - node.last_arrival:.1f} s: "
                          f"cameras {', '.join(node.cameras)} are missing until it delivers again")  # fmt: skip

    def offset(self, node: _Node) -> float:
        est = node.estimator.estimate()
        return est.offset_s if est is not None and self.options.correct_clocks else 0.0

    # -- frames ------------------------------------------------------------------------------
    def _issue(self, nodes: list[_Node], call) -> dict[Any, _Node]:
        """``call(node)`` (a remote call) on every node at once; its object ref -> node. A node
        whose actor is gone is marked lost."""
        refs = {}
        for n in nodes:
            try:
                refs[call(n)] = n
            except Exception as exc:  # noqa: BLE001 - Ray cannot find the actor any more
                self._lost(n, exc)
        return refs

    def _collect(self, refs: dict[Any, _Node], timeout: float) -> dict[str, Any]:
        """Node name -> answer of the calls ``refs`` that answered within ``timeout``."""
        import ray

        ready, _ = ray.wait(list(refs), num_returns=len(refs), timeout=timeout) if refs else ([], [])
        try:
            return {refs[ref].name: got for ref, got in zip(ready, ray.get(ready))}
        except Exception:  # noqa: BLE001 - one failed: get them one by one to know which
            pass
        out = {}
        for ref in ready:
            try:
                out[refs[ref].name] = ray.get(ref)
            except Exception as exc:  # noqa: BLE001 - RayError, or Ray's plain Exception for a lost actor
                self._lost(refs[ref], exc)
        return out

    def _ask_newest(self, nodes: list[_Node]) -> dict[Any, _Node]:
        return self._issue(nodes, lambda n: n.handle.newest.remote(n.after, 0.05))

    def _instant(self, nodes: list[_Node], asked: dict[Any, _Node]) -> float | None:
        """The instant to fuse next: the oldest of the nodes' newest stamps (host clock), once
        every node that is not stalled has a frame past the last one fused; ``asked``: the
        nodes' ``newest`` calls (``_ask_newest``)."""
        half = 0.5 / self.rate
        news = self._collect(asked, self.options.stall_s)
        now = time.time()
        for n in nodes:
            got = news.get(n.name)
            if got is not None and got[0] > n.after:
                n.after, n.newest, n.last_arrival = got[0], got[1] - self.offset(n), now
                if n.stalled:
                    n.stalled = False
                    self._say(f"capture node {n.name} delivers again: cameras {', '.join(n.cameras)}")
        self._check_stalls(now)
        active = [n for n in nodes if n.alive and not n.stalled]
        if not active or any(n.newest <= self._last_t + half for n in active):
            return None
        return min(n.newest for n in active)

    def _ask_frames(self, T: float, nodes: list[_Node]) -> dict[Any, _Node]:
        half = 0.5 / self.rate
        return self._issue(
            nodes, lambda n: n.handle.frame_at.remote(T + self.offset(n), half, n.wire, n.link == "same Ray node")
        )

    def _picks(self, asked: dict[Any, _Node]) -> dict[str, _Arrived]:
        """The frames of the ``frame_at`` calls ``asked`` (``_ask_frames``), decoded."""
        got = self._collect(asked, self.options.stall_s)
        picks = {}
        for n in asked.values():
            f = self._shared(n, got.get(n.name))
            if f is None:
                continue
            t0 = time.perf_counter()
            color, depth, present = decode_views(f.views, n.scales, (self.resolution[1], self.resolution[0]))
            n.decode_ms.append((time.perf_counter() - t0) * 1e3)
            n.encode_ms.append(f.views.encode_ms)
            n.bytes.append(f.views.nbytes)
            n.frames += 1
            picks[n.name] = _Arrived(f.stamp - self.offset(n), f.index, f.stamp, color, depth, present)
        return picks

    def _shared(self, node: _Node, answer: Any) -> Any:
        """A ``frame_at`` answer: the frame itself (it came in the reply), or ``[ref]`` of one the
        node put into this Ray node's object store (read from shared memory)."""
        import ray

        if not isinstance(answer, list):
            return answer
        try:
            return ray.get(answer[0], timeout=self.options.stall_s)
        except ray.exceptions.GetTimeoutError:
            return None  # late: the frame is fused without this node's views
        except Exception as exc:  # noqa: BLE001 - RayError: the node's object is gone with it
            self._lost(node, exc)
            return None

    def _assemble(self, T: float, nodes: list[_Node], picks: dict[str, _Arrived]) -> Frame:
        n, (w, h) = len(self.rig), self.resolution
        color = np.zeros((n, h, w, 3), np.uint8)
        depth = np.zeros((n, h, w), np.float32)
        present = np.zeros(n, bool)
        indices = set()
        residuals: dict[str, float | None] = {c: None for c in self.rig.ids}
        for node in nodes:
            a = picks.get(node.name)
            if a is None:
                continue
            color[node.slots], depth[node.slots], present[node.slots] = a.color, a.depth, a.present
            indices.add(a.index)
            for c, p in zip(node.cameras, a.present):
                if p:
                    self._skew[c].append((a.t - T) * 1e3)
                    residuals[c] = a.t - T
        self._check_drift(residuals)
        self._paired["frames"] += 1
        self._paired["mixed_index"] += len(indices) > 1
        index = min(indices) if indices else -1
        self.released = T - (time.time() - time.perf_counter())
        self.last_indices = {node.name: picks[node.name].index for node in nodes if node.name in picks}
        frame = Frame(index=index, camera_ids=self.rig.ids, color=torch.from_numpy(color), depth=torch.from_numpy(depth),
                      present=torch.from_numpy(present), timestamp=T)  # fmt: skip
        return frame

    def _check_drift(self, residuals: dict[str, float | None]) -> None:
        half = 500.0 / self.rate
        for cam, drift in self._drift.add(residuals):
            node = next((n.name for n in self._nodes.values() if cam in n.cameras), "?")
            self._say(f"camera {cam} (capture node {node}): its capture stamps drifted {drift * 1e3:+.1f} ms from the "
                      f"other cameras' (median over the last {self._drift.window} frames), more than half a frame "
                      f"interval ({half:.1f} ms): its frames are paired by stamps that are off, or it does not run "
                      "in step with the others; check its sync")  # fmt: skip

    def frames(self) -> Iterator[Frame]:
        """Paired frames as the nodes deliver them, until ``close``. Pipelined: up to
        ``RayLiveOptions.in_flight`` instants are in transfer at once, and the nodes are asked for
        their next newest stamps while they are, so that one frame's round trips and transfer
        overlap the next one's; a frame is handed on as soon as all its views arrived."""
        fetching: deque[tuple[float, list[_Node], dict[Any, _Node]]] = deque()
        while not self._closed.is_set():
            if len(fetching) + self._backlog() >= self.options.in_flight:  # pull: the consumer is busy
                if fetching and self._arrived(fetching[0][2], 0.02):  # waits for it, no busy loop
                    yield self._finish(fetching.popleft())
                elif not fetching:
                    self._closed.wait(0.002)
                continue
            nodes = [n for n in self._nodes.values() if n.alive and n.slots]
            asked = self._ask_newest(nodes)
            while fetching and (len(fetching) >= self.options.in_flight or self._arrived(fetching[0][2])):
                yield self._finish(fetching.popleft())
            T = self._instant(nodes, asked) if nodes else None
            if T is None:
                if fetching:
                    yield self._finish(fetching.popleft())
                else:
                    self._closed.wait(0.005)
                continue
            fetching.append((T, nodes, self._ask_frames(T, [n for n in nodes if n.alive and not n.stalled])))
            self._last_t = T
            self.last_t = T

    def paced_by(self, backlog: Callable[[], int]) -> None:
        """Fetch frames only as fast as they are consumed: ``backlog()`` is the number of frames
        handed on and not yet taken (the live loop's mailbox); with it, frames are asked of the
        nodes only while that plus those in transfer is below ``in_flight``, so that no frame is
        encoded, copied and decoded only to be replaced before fusion takes it."""
        self._backlog = backlog

    @staticmethod
    def _arrived(asked: dict[Any, _Node], timeout: float = 0.0) -> bool:
        """Whether every answer of ``asked`` is here, waiting up to ``timeout`` s for them."""
        import ray

        ready, _ = ray.wait(list(asked), num_returns=len(asked), timeout=timeout) if asked else ([], [])
        return len(ready) == len(asked)

    def _finish(self, fetching: tuple[float, list[_Node], dict[Any, _Node]]) -> Frame:
        T, nodes, asked = fetching
        return self._assemble(T, nodes, self._picks(asked))

    # -- report ------------------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        """For ``/stats`` and the summary: per node its state, clock offset (``offset_ms``,
        ``uncertainty_ms``, ``rtt_ms``), frames, bytes per frame, encode / decode ms; per camera
        the skew of its paired stamps (ms, median and max of |skew| over the last frames); the
        pairing counts (``mixed_index``: fused frames whose views came from different frame
        indices of a replay)."""
        nodes = {}
        for node in list(self._nodes.values()):
            if not node.slots:
                continue
            est = node.estimator.estimate()
            nodes[node.name] = {
                "state": "lost" if not node.alive else "stalled" if node.stalled else "ok",
                "cameras": list(node.cameras), **(est.to_json() if est else {}), "frames": node.frames,
                "link": node.link, "wire": node.codec,
                "bytes_per_frame": int(np.median(node.bytes)) if node.bytes else None,
                "encode_ms": round(float(np.median(node.encode_ms)), 2) if node.encode_ms else None,
                "decode_ms": round(float(np.median(node.decode_ms)), 2) if node.decode_ms else None,
            }  # fmt: skip
        skew = {}
        for c, d in self._skew.items():
            v = np.abs(np.array(d)) if d else None
            drift = self._drift.drift(c)
            skew[c] = (
                {"median_ms": round(float(np.median(v)), 2), "max_ms": round(float(v.max()), 2),
                 "drift_ms": round(drift * 1e3, 2) if drift is not None else None}
                if v is not None
                else None
            )  # fmt: skip
        return {
            "nodes": nodes,
            "skew": skew,
            "frame_interval_ms": round(1e3 / self.rate, 2),
            "paired": dict(self._paired),
        }

    def close(self) -> None:
        """Stop gathering (``frames()`` returns); the capture nodes keep running. Idempotent."""
        if self._closed.is_set():
            return
        self._closed.set()
        thread = getattr(self, "_thread", None)
        if thread is not None:
            thread.join(timeout=3.0)
        if self._started_ray:
            import ray

            ray.shutdown()
            self._started_ray = False
