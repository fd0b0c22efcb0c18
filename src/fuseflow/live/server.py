"""The live viewer server: the page at ``/``, fused frames over a WebSocket at ``/ws``, ``/stats``.

One asyncio event loop in a thread of its own (``websockets``). ``publish(data)`` is called from
the fusion loop and only hands the frame over: every client has a one-frame slot of its own that
its sender task empties, so a slow client has frames replaced (dropped for it alone, counted)
while the others, and the capture, go on. A frame is written to a client only once the previous
one has left: either the client acknowledged it (``/ws?ack=1``, what the page does: one text
``{"type": "ack", ...}`` per frame shown), or, for a client that does not acknowledge, the
server's buffer and the kernel's send queue of its socket are empty. A viewer is therefore at
most one frame behind the newest one.

Access (``Access``): ``/ws`` and ``/stats`` refuse a request whose ``Origin`` is neither the
page's own nor in ``allow_origins``; every request's ``Host`` must name the bound address, a
loopback name or (for a wildcard bind) this machine; a bind that is not loopback needs the random
``token`` in the address (``?token=``) of ``/``, ``/ws`` and ``/stats`` (403 otherwise); at most
``max_viewers`` WebSocket clients at once (503 beyond).

The server answers only these paths; its page and scripts are files of this package, looked up
in a fixed table (no file system path is ever built from a request).

A client picks its frame codec in the address, ``/ws?codec=raw`` or ``/ws?codec=compact``
(default: the server's ``codec``; ``fuseflow.live.wire.CODECS``). On connect it gets one text
message, the rig (``{"type": "rig", "codec": ..., "run": ..., "cameras": [...]}``: id, width,
height, K and ``T_world_cam`` row-major, for the cameras with extrinsics; ``run`` is random per
server, so a page can tell a restarted server), then one binary message per fused frame in its
codec (``fuseflow.live.wire``). With ``ack=1`` each binary frame is preceded by a text message
``{"type": "frame", "number", "captured", "sent", "age_ms", "rtt_ms", "dropped"}`` (capture and
send times in the server's clock, the frame's age when sent, the last measured round trip, the
frames dropped for this client so far, whether an attributes message follows). A raw client
that also asks ``attrs=1`` gets, after each frame, a binary message with each point's camera and
weight (``fuseflow.live.wire.encode_attributes``). A compact client that asks ``inter=1`` decodes
the stream in order (``codec.CompactDecoder``, decode.js ``createDecoder``) and is sent a frame as
a delta against the previous one (version 6, or 4 unsplit) whenever it was sent that one, else as a key frame;
its acknowledgement may say which frame its decoder holds (``"held"``: a number, or null after a
frame it could not decode: a key frame follows). ``{"type": "end", "reason": ...}`` says the stream
ended (a replay's last frame), ``{"type": "error", "message": ...}`` that it failed.
``codecs()`` tells the publisher which codecs the connected clients want, so that a frame is
encoded only in those.
"""

from __future__ import annotations

import asyncio
import errno
import hmac
import json
import secrets
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib import resources
from typing import Any
from urllib.parse import parse_qs, urlsplit

from fuseflow.errors import FuseFlowError, require

__all__ = ["LiveServer", "Access", "ASSETS", "parse_address", "is_loopback", "lan_address"]

_JS = "text/javascript; charset=utf-8"
ASSETS = {
    "/": ("index.html", "text/html; charset=utf-8"),
    "/index.html": ("index.html", "text/html; charset=utf-8"),
    "/viewer.js": ("viewer.js", _JS),
    "/decode.js": ("decode.js", _JS),
    "/decode-worker.js": ("decode-worker.js", _JS),
    "/three/three.module.js": ("three/three.module.js", _JS),
    "/three/three.core.js": ("three/three.core.js", _JS),
    "/three/addons/controls/OrbitControls.js": ("three/addons/controls/OrbitControls.js", _JS),
    "/three/addons/webxr/VRButton.js": ("three/addons/webxr/VRButton.js", _JS),
    "/three/addons/webxr/ARButton.js": ("three/addons/webxr/ARButton.js", _JS),
    "/three/LICENSE": ("three/LICENSE", "text/plain; charset=utf-8"),
}
"""Request path -> (file in fuseflow/live/static, content type): everything the server serves
besides ``/ws`` and ``/stats``."""
_PAGES = ("/", "/index.html")
"""Paths that need the token (when one is required); the scripts are public code."""
LOOPBACK_NAMES = ("localhost", "127.0.0.1", "::1")


def parse_address(spec: str, default_host: str = "127.0.0.1") -> tuple[str, int]:
    """``PORT``, ``HOST:PORT`` or ``[IPv6]:PORT`` -> (host, port); FuseFlowError otherwise."""
    if not spec.strip():
        raise FuseFlowError("--serve expects [HOST:]PORT (e.g. 8080 or 0.0.0.0:8080), got an empty value")
    host, sep, port = spec.rpartition(":")
    if not sep:
        host, port = "", spec
    host = host.strip("[]") or default_host
    try:
        number = int(port)
    except ValueError:
        raise FuseFlowError(f"--serve expects [HOST:]PORT (e.g. 8080 or 0.0.0.0:8080), got {spec!r}") from None
    if not 0 <= number <= 65535:
        raise FuseFlowError(f"--serve: port {number} is not between 0 and 65535")
    return host, number


def is_loopback(host: str) -> bool:
    return host in ("localhost", "::1") or host.startswith("127.")


def _is_wildcard(host: str) -> bool:
    return host in ("0.0.0.0", "::", "")


def lan_address() -> str:
    """This machine's address on the network a default route leads to (no packet is sent); its
    host name when there is none."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect(("192.0.2.1", 9))  # TEST-NET-1: only picks the outgoing interface
            return s.getsockname()[0]
        except OSError:
            return socket.gethostname()


@dataclass(frozen=True)
class Access:
    """Who may watch. ``token``: None = none needed; ``"auto"`` = a random one when the bind
    address is not loopback (the default), none on loopback; any other string = that token."""

    allow_origins: tuple[str, ...] = ()
    """Origins (``scheme://host[:port]``) besides the page's own that may use /ws and /stats."""
    token: str | None = "auto"
    max_viewers: int = 16
    """WebSocket clients at once; more get 503."""

    def check(self) -> Access:
        if self.max_viewers < 1:
            raise FuseFlowError(f"--max-viewers must be at least 1, got {self.max_viewers}")
        for o in self.allow_origins:
            parts = urlsplit(o)
            if parts.scheme not in ("http", "https") or not parts.hostname or parts.path not in ("", "/"):
                raise FuseFlowError(
                    f"--allow-origin expects scheme://host[:port] (e.g. http://example.org:8000), got {o!r}"
                )
        return self


def _host_name(value: str) -> str:
    """The host of a Host header or an origin's netloc, lower case, without port or brackets."""
    return (urlsplit("//" + value).hostname or "").lower()


@dataclass(eq=False)
class _Client:
    ws: Any
    event: asyncio.Event
    codec: str = "compact"
    ack: bool = False
    attrs: bool = False
    pending: tuple[bytes, dict, bytes | None] | None = None
    sent: int = 0
    dropped: int = 0
    bytes_sent: int = 0
    connected: float = 0.0
    waiting_ack: bool = False
    sent_at: float = 0.0
    rtt_ms: float | None = None
    shown: dict[str, Any] = field(default_factory=dict)
    """What the client reported in its last acknowledgement (age_ms, decode_ms, dropped, ...)."""
    age_max_ms: float = 0.0
    inter: bool = False
    """Takes deltas (``/ws?inter=1``, compact): its decoder holds the last frame sent to it."""
    held: int | None = None
    """The number of the last compact frame sent to it (what a delta may refer to)."""


class LiveServer:
    """Serve the viewer and stream frames; ``start()`` binds (FuseFlowError when the port is taken),
    ``publish(data)`` sends a frame to every client, ``end(reason)`` tells them the stream ended,
    ``close()`` stops and disconnects everyone.

    Args:
        host, port: where to listen (port 0: any free port; ``port`` holds the bound one after
            ``start``).
        stats: returns the loop's counters for ``/stats`` (the server adds ``clients`` and per
            client ``client_stats``).
        rig_message: the text message every client gets first (the rig as JSON; the server adds
            the client's ``codec`` and the server's ``run``).
        codec: the frame codec of a client that does not name one (``?codec=``).
        access: origins, token and viewer cap (``Access``).
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 8080, stats: Callable[[], dict] | None = None,
                 rig_message: str = '{"type": "rig", "cameras": []}', codec: str = "compact",
                 access: Access = Access()):  # fmt: skip
        from fuseflow.live.wire import CODECS

        if codec not in CODECS:
            raise FuseFlowError(f"--codec must be one of {', '.join(CODECS)}, got {codec!r}")
        self.codec = codec
        self.host, self.port = host, port
        self.access = access.check()
        self.token = access.token
        if self.token == "auto":
            self.token = None if is_loopback(host) else secrets.token_urlsafe(12)
        self.run_id = secrets.token_hex(4)
        self._stats = stats or dict
        self._rig = rig_message
        self._clients: set[_Client] = set()
        self._done: list[dict[str, Any]] = []
        self._last: tuple[Any, dict] | None = None
        self._end: dict | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._stopped: asyncio.Event | None = None
        self._hosts: set[str] | None = None
        self.refused: dict[str, int] = {}
        """Requests refused, by reason (origin, host, token, viewers)."""
        self._files = {name: (resources.files("fuseflow.live") / "static" / name).read_bytes()
                       for name, _ in ASSETS.values()}  # fmt: skip

    # ------------------------------------------------------------------ lifecycle (caller's thread)

    def start(self) -> LiveServer:
        require("websockets", "live", "the live viewer server")
        ready = threading.Event()
        failure: list[BaseException] = []
        self._thread = threading.Thread(target=self._run, args=(ready, failure), name="fuseflow-server", daemon=True)
        self._thread.start()
        ready.wait()
        if failure:
            self._thread.join()
            exc = failure[0]
            if isinstance(exc, OSError) and exc.errno in (errno.EADDRINUSE, errno.EACCES, errno.EADDRNOTAVAIL):
                why = {errno.EADDRINUSE: "is in use", errno.EACCES: "is not permitted"}.get(
                    exc.errno, "is not available"
                )
                raise FuseFlowError(f"cannot serve on {self.host}:{self.port}: the address {why}; "
                                    "choose another with --serve [HOST:]PORT") from None  # fmt: skip
            raise FuseFlowError(f"cannot serve on {self.host}:{self.port}: {exc}") from None
        return self

    def close(self) -> None:
        if self._loop is not None and self._stopped is not None and self._thread is not None:
            self._loop.call_soon_threadsafe(self._stopped.set)
            self._thread.join(timeout=10.0)
        self._loop = None

    def __enter__(self) -> LiveServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def url(self) -> str:
        """The page's address: a LAN address for a wildcard bind, with the token when one is needed."""
        host = lan_address() if _is_wildcard(self.host) else self.host
        host = f"[{host}]" if ":" in host else host
        return f"http://{host}:{self.port}/" + (f"?token={self.token}" if self.token else "")

    def publish(self, data: bytes | dict[str, bytes], meta: dict | None = None) -> None:
        """Hand one frame to every client (returns at once; from any thread): the same bytes to
        all, or {codec: bytes} (a client gets its codec's; one whose codec is missing gets nothing).
        ``meta``: ``number`` and ``captured`` (seconds, ``time.time`` clock) of the frame, for the
        clients that acknowledge."""
        if self._loop is not None:
            self._loop.call_soon_threadsafe(self._offer, data, dict(meta or {}))

    def end(self, reason: str, error: bool = False) -> None:
        """Tell every client (and every later one) that the stream ended (``{"type": "end"}``) or
        failed (``{"type": "error"}``); the last frame stays, for late joiners."""
        msg = {"type": "error", "message": reason} if error else {"type": "end", "reason": reason}
        if self._loop is not None:
            self._loop.call_soon_threadsafe(self._set_end, msg)

    def codecs(self) -> set[str]:
        """The codecs the connected clients want (empty: nobody to encode for); "raw.attrs" when a
        raw client also wants each point's camera and weight (``wire.encode_attributes``)."""
        clients = list(self._clients)
        return {c.codec for c in clients} | {"raw.attrs" for c in clients if c.attrs and c.codec == "raw"}

    def compact_needs(self, reference: int | None) -> tuple[bool, bool]:
        """(key frame, delta) of the next compact frame: whether a compact client needs a key
        frame, and whether an ``inter`` client holds frame ``reference`` with nothing waiting in
        its slot, so that a delta against it reaches it. From any thread."""
        key = delta = False
        for c in list(self._clients):
            if c.codec != "compact":
                continue
            if c.inter and reference is not None and c.held == reference and c.pending is None:
                delta = True
            else:
                key = True
        return key, delta

    def client_stats(self) -> list[dict[str, Any]]:
        """Per client (connected ones, then those gone): frames sent and dropped, bytes, seconds,
        and for clients that acknowledge the age of the frame they show (``age_ms``, its maximum)."""
        now = time.perf_counter()
        return [self._client_json(c, now) for c in list(self._clients)] + list(self._done)

    @property
    def running(self) -> bool:
        """True while the server thread runs."""
        return self._thread is not None and self._thread.is_alive()

    @property
    def clients(self) -> int:
        return len(self._clients)

    # ------------------------------------------------------------------ event loop (server thread)

    def _run(self, ready: threading.Event, failure: list[BaseException]) -> None:
        loop = asyncio.new_event_loop()
        try:
            loop.run_until_complete(self._serve(ready))
        except BaseException as exc:  # noqa: BLE001 - handed to start() in the caller's thread
            failure.append(exc)
            ready.set()
        finally:
            loop.close()

    async def _serve(self, ready: threading.Event) -> None:
        from websockets.asyncio.server import serve

        self._stopped = asyncio.Event()
        async with serve(self._handler, self.host, self.port, process_request=self._http, close_timeout=1.0,
                         max_size=2**16, write_limit=2**16, compression=None) as server:  # fmt: skip
            self.port = server.sockets[0].getsockname()[1]
            self._allowed_hosts()
            self._loop = asyncio.get_running_loop()
            ready.set()
            await self._stopped.wait()
            server.close(close_connections=True)
            for c in list(self._clients):
                c.event.set()
            await asyncio.wait_for(server.wait_closed(), timeout=3.0)

    def _offer(self, data: bytes | dict[str, bytes], meta: dict) -> None:
        last = self._last
        if (
            last is not None
            and isinstance(data, dict)
            and isinstance(last[0], dict)
            and last[1].get("number") == meta.get("number")
        ):
            data = {**last[0], **data}  # the same frame again (a key frame after a delta): keep both
        self._last = (data, meta)
        for c in self._clients:
            self._give(c, data, meta)

    def _give(self, c: _Client, data: bytes | dict[str, bytes], meta: dict) -> None:
        mine = data.get(c.codec) if isinstance(data, dict) else data
        if c.inter and c.codec == "compact" and c.held is not None and isinstance(data, dict):
            if c.pending is None and meta.get("number") == c.held:
                return  # it has this frame already
            if "compact.delta" in data and meta.get("ref") == c.held:
                mine = data["compact.delta"]
        if mine is None:
            return
        extra = data.get(c.codec + ".attrs") if c.attrs and isinstance(data, dict) else None
        if c.pending is not None:
            c.dropped += 1
        c.pending = (mine, meta, extra)
        c.event.set()

    def _set_end(self, msg: dict) -> None:
        self._end = msg
        for c in self._clients:
            c.event.set()

    def _client_json(self, c: _Client, now: float) -> dict[str, Any]:
        seconds = max(now - c.connected, 1e-9)
        doc = {"codec": c.codec, "ack": c.ack, "frames_sent": c.sent, "dropped": c.dropped,
               "bytes_sent": c.bytes_sent, "seconds": round(seconds, 2),
               "mbit_per_s": round(c.bytes_sent * 8 / seconds / 1e6, 3)}  # fmt: skip
        if c.ack:
            doc.update(age_ms=c.shown.get("age_ms"), age_ms_max=round(c.age_max_ms, 1),
                       viewer_dropped=c.shown.get("dropped"), decode_ms=c.shown.get("decode_ms"),
                       rtt_ms=None if c.rtt_ms is None else round(c.rtt_ms, 1))  # fmt: skip
        return doc

    async def _handler(self, ws: Any) -> None:
        query = parse_qs(urlsplit(ws.request.path).query)
        client = _Client(ws, asyncio.Event(), self._client_codec(ws.request.path),
                         ack=query.get("ack", ["0"])[-1] == "1", attrs=query.get("attrs", ["0"])[-1] == "1",
                         inter=query.get("inter", ["0"])[-1] == "1",
                         connected=time.perf_counter())  # fmt: skip
        self._clients.add(client)
        if self._last is not None:
            self._give(client, *self._last)
            client.dropped = 0
        sender = asyncio.ensure_future(self._send_frames(client))
        reader = asyncio.ensure_future(self._read_acks(client))
        try:
            await asyncio.wait([sender, reader], return_when=asyncio.FIRST_COMPLETED)
        finally:
            for task in (sender, reader):
                task.cancel()
            self._clients.discard(client)
            self._done.append(self._client_json(client, time.perf_counter()))
            del self._done[:-100]

    async def _read_acks(self, client: _Client) -> None:
        """Every text message of an acknowledging client: ``{"type": "ack", "number", ...}``
        after it showed a frame (anything else is ignored); ends when the connection does."""
        from websockets.exceptions import ConnectionClosed

        try:
            async for msg in client.ws:
                if not client.ack or not isinstance(msg, str):
                    continue
                try:
                    doc = json.loads(msg)
                except ValueError:
                    continue
                if isinstance(doc, dict) and doc.get("type") == "ack" and client.waiting_ack:
                    held = float(doc.get("held_ms") or 0.0)
                    client.rtt_ms = max((time.perf_counter() - client.sent_at) * 1000.0 - held, 0.0)
                    client.shown = {k: doc.get(k) for k in ("number", "age_ms", "decode_ms", "dropped")}
                    if isinstance(doc.get("age_ms"), (int, float)):
                        client.age_max_ms = max(client.age_max_ms, float(doc["age_ms"]))
                    if "held" in doc and client.inter:
                        client.held = doc["held"] if isinstance(doc["held"], int) else None
                    client.waiting_ack = False
                    client.event.set()
        except ConnectionClosed:
            pass

    async def _send_frames(self, client: _Client) -> None:
        """The rig, then each frame put in the client's slot once the previous one left (module
        docstring); ends when the client goes away (mid-frame or not: the others go on) or the
        server stops."""
        from websockets.exceptions import ConnectionClosed

        try:
            rig = json.loads(self._rig)
            await client.ws.send(json.dumps({"type": rig.pop("type", "rig"), "codec": client.codec,
                                             "run": self.run_id, **rig}))  # fmt: skip
            ended = False
            while not self._stopped.is_set():
                await client.event.wait()
                client.event.clear()
                if client.waiting_ack:
                    continue
                if client.pending is not None:
                    await self._send_one(client)
                    continue
                if self._end is not None and not ended:
                    await client.ws.send(json.dumps(self._end))
                    ended = True
        except ConnectionClosed:
            pass

    async def _send_one(self, client: _Client) -> None:
        (data, meta, extra), client.pending = client.pending, None
        if client.ack:
            now = time.time()
            captured = meta.get("captured")
            head = {"type": "frame", "number": meta.get("number"), "captured": captured, "sent": now,
                    "age_ms": None if captured is None else round((now - captured) * 1000.0, 1),
                    "rtt_ms": None if client.rtt_ms is None else round(client.rtt_ms, 1),
                    "dropped": client.dropped, "attrs": extra is not None}  # fmt: skip
            await client.ws.send(json.dumps(head))
            client.waiting_ack = True
            client.sent_at = time.perf_counter()
        await client.ws.send(data)
        if client.codec == "compact":
            client.held = meta.get("number")
        if extra is not None:
            await client.ws.send(extra)
        client.sent += 1
        client.bytes_sent += len(data) + (len(extra) if extra is not None else 0)
        if not client.ack:
            await self._drained(client)
        client.event.set()  # a frame (or the end) that came meanwhile goes next

    async def _drained(self, client: _Client) -> None:
        """Wait until the frame left this process and the kernel's send queue of the socket (a
        client that does not read keeps it there; frames meanwhile replace each other)."""
        transport = client.ws.transport
        sock = transport.get_extra_info("socket")
        while not transport.is_closing():
            if transport.get_write_buffer_size() == 0 and _unsent(sock) == 0:
                return
            await asyncio.sleep(0.002)

    def _client_codec(self, path: str) -> str:
        """The codec named in ``/ws?codec=NAME`` (the server's default when none is)."""
        from fuseflow.live.wire import CODECS

        asked = parse_qs(urlsplit(path).query).get("codec", [self.codec])[-1]
        if asked not in CODECS:
            raise FuseFlowError(f"unknown codec {asked!r}: /ws?codec= takes {', '.join(CODECS)}")
        return asked

    # ------------------------------------------------------------------ HTTP (server thread)

    def _allowed_hosts(self) -> set[str]:
        """Host names a request may carry (computed once: the machine's names need a lookup)."""
        if self._hosts is None:
            names = {"localhost", "127.0.0.1", "::1", self.host.lower()}
            if _is_wildcard(self.host):
                names |= {lan_address(), socket.gethostname().lower(), socket.getfqdn().lower()}
            self._hosts = names
        return self._hosts

    def _refusal(self, request: Any, path: str) -> tuple[int, str, str] | None:
        """(status, kind, why) when the request may not be answered; None when it may."""
        headers = request.headers
        host = _host_name(headers.get("Host", ""))
        allowed = self._allowed_hosts()
        wildcard_name = _is_wildcard(self.host) and host.split(".")[0] == socket.gethostname().lower().split(".")[0]
        if host not in allowed and not host.startswith("127.") and not wildcard_name:
            return 403, "host", f"Host {host or '(none)'!r} is not this server's address; open {self.url}"
        origin = headers.get("Origin")
        if origin is not None and path in ("/ws", "/stats"):
            own = {f"http://{headers.get('Host', '')}".lower(), f"https://{headers.get('Host', '')}".lower()}
            if origin.lower() not in own and origin.rstrip("/") not in self.access.allow_origins:
                return (
                    403,
                    "origin",
                    f"Origin {origin!r} may not watch this stream (fuseflow live --allow-origin ORIGIN)",
                )
        if self.token and path in (*_PAGES, "/ws", "/stats"):
            given = parse_qs(urlsplit(request.path).query).get("token", [""])[-1]
            if not hmac.compare_digest(given.encode(), self.token.encode()):
                return 403, "token", "this stream needs its token: open the address fuseflow live printed (…/?token=…)"
        if path == "/ws" and len(self._clients) >= self.access.max_viewers:
            return (
                503,
                "viewers",
                f"{self.access.max_viewers} viewers are watching already (fuseflow live --max-viewers N)",
            )
        return None

    def _http(self, connection: Any, request: Any) -> Any:
        from websockets.datastructures import Headers
        from websockets.http11 import Response

        def text(status: int, reason: str, msg: str) -> Any:
            body = f"{msg}\n".encode()
            return Response(status, reason, Headers([("Content-Type", "text/plain; charset=utf-8"),
                                                     ("Content-Length", str(len(body)))]), body)  # fmt: skip

        path = request.path.split("?", 1)[0]
        refused = self._refusal(request, path)
        if refused is not None:
            status, key, why = refused
            self.refused[key] = self.refused.get(key, 0) + 1
            return text(status, "Forbidden" if status == 403 else "Service Unavailable", why)
        if path == "/ws":
            try:
                self._client_codec(request.path)
            except FuseFlowError as exc:
                return text(400, "Bad Request", str(exc))
            return None  # the WebSocket handshake
        if path == "/stats":
            doc = {**self._stats(), "clients": len(self._clients), "client_stats": self.client_stats(),
                   "refused": dict(self.refused),
                   "ended": None if self._end is None else self._end.get("reason", self._end.get("message"))}  # fmt: skip
            body, kind = json.dumps(doc).encode(), "application/json"
        elif path in ASSETS:
            name, kind = ASSETS[path]
            body = self._files[name]
        else:
            return text(404, "Not Found", "not found")
        headers = Headers([("Content-Type", kind), ("Content-Length", str(len(body))), ("Cache-Control", "no-store")])
        return Response(200, "OK", headers, body)


def _unsent(sock: Any) -> int:
    """Bytes in the kernel's send queue of ``sock`` (Linux TIOCOUTQ); 0 where that is not known."""
    try:
        import fcntl
        import struct
        import termios

        return struct.unpack("i", fcntl.ioctl(sock.fileno(), termios.TIOCOUTQ, b"\0\0\0\0"))[0]
    except (OSError, ImportError, AttributeError, ValueError):
        return 0
