"""The live viewer server: the page at ``/``, fused frames over a WebSocket at ``/ws``, ``/stats``.

One asyncio event loop in a thread of its own (``websockets``). ``publish(data)`` is called from
the fusion loop and only hands the frame over: every client has a one-frame slot of its own that
its sender task empties, so a slow client has frames replaced (dropped for it alone, counted)
while the others, and the capture, go on. The server answers only these paths; its page and
script are files of this package, looked up in a fixed table (no file system path is ever built
from a request).

A client picks its frame codec in the address, ``/ws?codec=raw`` or ``/ws?codec=compact``
(default: the server's ``codec``; ``fuseflow.live.wire.CODECS``). On connect it gets one text
message, the rig (``{"type": "rig", "codec": ..., "cameras": [...]}``: id, width, height, K and
``T_world_cam`` row-major, for the cameras with extrinsics), then one binary message per fused
frame in its codec (``fuseflow.live.wire``). ``codecs()`` tells the publisher which codecs the
connected clients want, so that a frame is encoded only in those.
"""

from __future__ import annotations

import asyncio
import errno
import json
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from importlib import resources
from typing import Any

from fuseflow.errors import FuseFlowError, require

__all__ = ["LiveServer", "ASSETS", "parse_address", "is_loopback"]

ASSETS = {
    "/": ("index.html", "text/html; charset=utf-8"),
    "/index.html": ("index.html", "text/html; charset=utf-8"),
    "/viewer.js": ("viewer.js", "text/javascript; charset=utf-8"),
    "/decode.js": ("decode.js", "text/javascript; charset=utf-8"),
}
"""Request path -> (file in fuseflow/live/static, content type): everything the server serves
besides ``/ws`` and ``/stats``."""


def parse_address(spec: str, default_host: str = "127.0.0.1") -> tuple[str, int]:
    """``PORT``, ``HOST:PORT`` or ``[IPv6]:PORT`` -> (host, port); ValidationError-like
    FuseFlowError otherwise."""
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


@dataclass(eq=False)
class _Client:
    ws: Any
    event: asyncio.Event
    codec: str = "compact"
    pending: bytes | None = None
    sent: int = 0
    dropped: int = 0
    bytes_sent: int = 0
    connected: float = 0.0


class LiveServer:
    """Serve the viewer and stream frames; ``start()`` binds (FuseFlowError when the port is taken),
    ``publish(data)`` sends a frame to every client, ``close()`` stops and disconnects everyone.

    Args:
        host, port: where to listen (port 0: any free port; ``port`` holds the bound one after
            ``start``).
        stats: returns the loop's counters for ``/stats`` (the server adds ``clients`` and per
            client ``client_stats``).
        rig_message: the text message every client gets first (the rig as JSON; the server adds
            the client's ``codec``).
        codec: the frame codec of a client that does not name one (``?codec=``).
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 8080, stats: Callable[[], dict] | None = None,
                 rig_message: str = '{"type": "rig", "cameras": []}', codec: str = "compact"):  # fmt: skip
        from fuseflow.live.wire import CODECS

        if codec not in CODECS:
            raise FuseFlowError(f"--codec must be one of {', '.join(CODECS)}, got {codec!r}")
        self.codec = codec
        self.host, self.port = host, port
        self._stats = stats or dict
        self._rig = rig_message
        self._clients: set[_Client] = set()
        self._done: list[dict[str, Any]] = []
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._stopped: asyncio.Event | None = None
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
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/"

    def publish(self, data: bytes | dict[str, bytes]) -> None:
        """Hand one frame to every client (returns at once; from any thread): the same bytes to
        all, or {codec: bytes} (a client gets its codec's; one whose codec is missing gets nothing)."""
        if self._loop is not None:
            self._loop.call_soon_threadsafe(self._offer, data)

    def codecs(self) -> set[str]:
        """The codecs the connected clients want (empty: nobody to encode for)."""
        return {c.codec for c in list(self._clients)}

    def client_stats(self) -> list[dict[str, Any]]:
        """Per client (connected ones, then those gone): frames sent and dropped, bytes, seconds."""
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
                         max_size=2**16, write_limit=2**18, compression=None) as server:  # fmt: skip
            self.port = server.sockets[0].getsockname()[1]
            self._loop = asyncio.get_running_loop()
            ready.set()
            await self._stopped.wait()
            server.close(close_connections=True)
            for c in list(self._clients):
                c.event.set()
            await asyncio.wait_for(server.wait_closed(), timeout=3.0)

    def _offer(self, data: bytes | dict[str, bytes]) -> None:
        for c in self._clients:
            mine = data.get(c.codec) if isinstance(data, dict) else data
            if mine is None:
                continue
            if c.pending is not None:
                c.dropped += 1
            c.pending = mine
            c.event.set()

    def _client_json(self, c: _Client, now: float) -> dict[str, Any]:
        seconds = max(now - c.connected, 1e-9)
        return {"codec": c.codec, "frames_sent": c.sent, "dropped": c.dropped, "bytes_sent": c.bytes_sent,
                "seconds": round(seconds, 2), "mbit_per_s": round(c.bytes_sent * 8 / seconds / 1e6, 3)}  # fmt: skip

    async def _handler(self, ws: Any) -> None:
        client = _Client(ws, asyncio.Event(), self._client_codec(ws.request.path), connected=time.perf_counter())
        self._clients.add(client)
        sender = asyncio.ensure_future(self._send_frames(client))
        closed = asyncio.ensure_future(ws.wait_closed())
        try:
            await asyncio.wait([sender, closed], return_when=asyncio.FIRST_COMPLETED)
        finally:
            for task in (sender, closed):
                task.cancel()
            self._clients.discard(client)
            self._done.append(self._client_json(client, time.perf_counter()))
            del self._done[:-100]

    async def _send_frames(self, client: _Client) -> None:
        """The rig, then each frame put in the client's slot; ends when the client goes away
        (mid-frame or not: the others go on) or the server stops."""
        from websockets.exceptions import ConnectionClosed

        try:
            rig = json.loads(self._rig)
            await client.ws.send(json.dumps({"type": rig.pop("type", "rig"), "codec": client.codec, **rig}))
            while not self._stopped.is_set():
                await client.event.wait()
                client.event.clear()
                data, client.pending = client.pending, None
                if data is None:
                    continue
                await client.ws.send(data)
                client.sent += 1
                client.bytes_sent += len(data)
        except ConnectionClosed:
            pass

    def _client_codec(self, path: str) -> str:
        """The codec named in ``/ws?codec=NAME`` (the server's default when none is)."""
        from urllib.parse import parse_qs, urlsplit

        from fuseflow.live.wire import CODECS

        asked = parse_qs(urlsplit(path).query).get("codec", [self.codec])[-1]
        if asked not in CODECS:
            raise FuseFlowError(f"unknown codec {asked!r}: /ws?codec= takes {', '.join(CODECS)}")
        return asked

    def _http(self, connection: Any, request: Any) -> Any:
        from websockets.datastructures import Headers
        from websockets.http11 import Response

        path = request.path.split("?", 1)[0]
        if path == "/ws":
            try:
                self._client_codec(request.path)
            except FuseFlowError as exc:
                body = f"{exc}\n".encode()
                return Response(400, "Bad Request", Headers([("Content-Type", "text/plain; charset=utf-8"),
                                                             ("Content-Length", str(len(body)))]), body)  # fmt: skip
            return None  # the WebSocket handshake
        if path == "/stats":
            doc = {**self._stats(), "clients": len(self._clients), "client_stats": self.client_stats()}
            body, kind = json.dumps(doc).encode(), "application/json"
        elif path in ASSETS:
            name, kind = ASSETS[path]
            body = self._files[name]
        else:
            body, kind = b"not found\n", "text/plain; charset=utf-8"
            return Response(
                404, "Not Found", Headers([("Content-Type", kind), ("Content-Length", str(len(body)))]), body
            )
        headers = Headers([("Content-Type", kind), ("Content-Length", str(len(body))), ("Cache-Control", "no-store")])
        return Response(200, "OK", headers, body)
