"""The live viewer server: page, /stats, WebSocket frames, several clients, a stalled client,
path traversal, a port in use; and the binary frame format."""

import base64
import http.client
import json
import os
import socket
import time
import urllib.request

import numpy as np
import pytest
import torch

from fuseflow.errors import FormatError, FuseFlowError
from fuseflow.live.server import LiveServer, is_loopback, parse_address
from fuseflow.live.wire import HEADER, decode_frame, encode_frame
from fuseflow.types import FusedCloud

ws_client = pytest.importorskip("websockets.sync.client")


def _cloud(m, seed=0):
    g = torch.Generator().manual_seed(seed)
    return FusedCloud(
        xyz=torch.rand(m, 3, generator=g) * torch.tensor([4.0, 2.0, 3.0]) - 1.0,
        rgb=torch.randint(0, 256, (m, 3), generator=g, dtype=torch.uint8),
        weight=torch.ones(m), camera=torch.zeros(m, dtype=torch.int16),
    )  # fmt: skip


def _get(server, path):
    conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=5)
    conn.request("GET", path)
    r = conn.getresponse()
    body = r.read()
    conn.close()
    return r.status, r.getheader("Content-Type"), body


@pytest.fixture
def server():
    s = LiveServer(
        "127.0.0.1", 0, stats=lambda: {"frames_in": 3, "frames_out": 2}, rig_message='{"type": "rig", "cameras": []}'
    )
    s.start()
    yield s
    s.close()


def test_wire_round_trip_and_size():
    cloud = _cloud(5000)
    data = encode_frame(cloud, 42, 12.5, 30.0)
    assert len(data) == HEADER + 9 * 5000 and data[:4] == b"FFLV"
    d = decode_frame(data)
    assert d.number == 42 and d.latency_ms == 12.5 and d.fuse_ms == 30.0
    step = (d.box[1] - d.box[0]) / 65535
    assert np.all(np.abs(d.xyz - cloud.xyz.numpy()) <= step * 0.51 + 1e-6)
    assert np.array_equal(d.rgb, cloud.rgb.numpy())
    empty = decode_frame(encode_frame(_cloud(0), 1, 0.0, 0.0))
    assert empty.xyz.shape == (0, 3)
    with pytest.raises(FormatError, match="expected"):
        decode_frame(data[:-1])
    with pytest.raises(FormatError, match="magic"):
        decode_frame(b"XXXX" + data[4:])


def test_page_script_and_stats(server):
    status, kind, body = _get(server, "/")
    assert status == 200 and kind.startswith("text/html") and b"viewer.js" in body
    status, kind, body = _get(server, "/viewer.js")
    assert status == 200 and b"WebSocket" in body and b"http" not in body.replace(b"https:", b"")  # no CDN
    doc = json.loads(urllib.request.urlopen(server.url + "stats", timeout=5).read())
    assert doc["frames_in"] == 3 and doc["clients"] == 0 and doc["client_stats"] == []


@pytest.mark.parametrize(
    "path",
    ["/../pyproject.toml", "/static/index.html", "/%2e%2e/%2e%2e/pyproject.toml", "/viewer.js/../server.py",
     "//etc/passwd", "/server.py", "/static/../server.py", "/..%2fwire.py", "/etc/passwd"],
)  # fmt: skip
def test_only_its_own_assets_are_served(server, path):
    status, _, body = _get(server, path)
    assert status in (400, 404)
    assert b"import" not in body and b"root:" not in body and b"[project]" not in body


def _ws(server):
    c = ws_client.connect(f"ws://127.0.0.1:{server.port}/ws", open_timeout=5, max_size=None).__enter__()
    assert json.loads(c.recv(timeout=5))["type"] == "rig"
    return c


def test_two_clients_receive_decodable_frames(server):
    a, b = _ws(server), _ws(server)
    deadline = time.time() + 5
    while server.clients < 2 and time.time() < deadline:
        time.sleep(0.01)
    for k in range(3):
        server.publish(encode_frame(_cloud(1000, k), k, 1.0, 1.0))
        assert decode_frame(a.recv(timeout=5)).number == k
        assert decode_frame(b.recv(timeout=5)).number == k
    a.close()
    server.publish(encode_frame(_cloud(10), 9, 1.0, 1.0))  # one client gone: the other goes on
    assert decode_frame(b.recv(timeout=5)).number == 9
    b.close()
    deadline = time.time() + 5
    while server.clients and time.time() < deadline:
        time.sleep(0.01)
    stats = server.client_stats()
    assert server.clients == 0 and len(stats) == 2 and all(s["frames_sent"] >= 3 for s in stats)


def _stalled_client(port):
    """A WebSocket client that completes the handshake and then never reads."""
    s = socket.socket()
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # before connecting: a small window
    s.settimeout(5)
    s.connect(("127.0.0.1", port))
    key = base64.b64encode(os.urandom(16)).decode()
    s.sendall(
        (f"GET /ws HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
         f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n").encode()
    )  # fmt: skip
    assert s.recv(12).startswith(b"HTTP/1.1 101")
    return s


def test_stalled_client_does_not_stall_the_other(server):
    stalled = _stalled_client(server.port)
    good = _ws(server)
    deadline = time.time() + 5
    while server.clients < 2 and time.time() < deadline:
        time.sleep(0.01)
    frame = encode_frame(_cloud(200_000), 0, 1.0, 1.0)  # 1.8 MB: fills the stalled socket at once
    t0 = time.perf_counter()
    for k in range(12):
        server.publish(frame[:8] + k.to_bytes(4, "little") + frame[12:])
        assert decode_frame(good.recv(timeout=5)).number == k
    assert time.perf_counter() - t0 < 10
    deadline = time.time() + 5  # the server counts a frame once its write returned
    while max(s["frames_sent"] for s in server.client_stats()) < 12 and time.time() < deadline:
        time.sleep(0.01)
    stats = sorted(server.client_stats(), key=lambda s: s["frames_sent"])
    assert stats[0]["frames_sent"] < 12 and stats[0]["dropped"] > 0  # the stalled one lost frames, alone
    assert stats[1]["frames_sent"] == 12 and stats[1]["dropped"] == 0
    good.close()
    stalled.close()


def test_port_in_use_is_one_clear_error(server):
    with pytest.raises(FuseFlowError, match=r"cannot serve on 127\.0\.0\.1:\d+: the address is in use"):
        LiveServer("127.0.0.1", server.port).start()


def test_close_is_clean_with_clients_connected():
    s = LiveServer("127.0.0.1", 0).start()
    c = _ws(s)
    t0 = time.perf_counter()
    s.close()
    assert time.perf_counter() - t0 < 5
    with pytest.raises(Exception):  # noqa: B017 - closed by the server: any websockets close error
        c.recv(timeout=5)
    assert not s.running


def test_addresses():
    assert parse_address("8080") == ("127.0.0.1", 8080)
    assert parse_address("0.0.0.0:9000") == ("0.0.0.0", 9000)
    assert parse_address("[::1]:9000") == ("::1", 9000)
    with pytest.raises(FuseFlowError, match="HOST:"):
        parse_address("host:port")
    assert is_loopback("127.0.0.1") and is_loopback("localhost") and not is_loopback("0.0.0.0")


def test_bench_live_rejects_unknown_cases_and_judges_targets():
    from fuseflow.errors import ValidationError
    from fuseflow.eval.bench.live import CASES, TARGETS, run_live_bench

    with pytest.raises(ValidationError, match="unknown cases"):
        run_live_bench(["sim9"])
    assert set(CASES) == set(TARGETS)
