"""Who may watch, and how far behind a viewer may be: Origin and Host checks, the token of a
bind that is not loopback, the viewer cap; acknowledging clients are sent the newest frame only
once they showed the previous one; the end of the stream reaches current and late clients."""

import http.client
import json
import time

import pytest

from fuseflow.errors import FuseFlowError
from fuseflow.live.server import Access, LiveServer, lan_address

ws_client = pytest.importorskip("websockets.sync.client")


def _get(port, path, headers=None):
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
    conn.request("GET", path, headers=headers or {})
    r = conn.getresponse()
    body = r.read()
    conn.close()
    return r.status, body


def _wait(cond, seconds=5.0):
    deadline = time.time() + seconds
    while not cond() and time.time() < deadline:
        time.sleep(0.01)
    return cond()


@pytest.fixture
def server():
    s = LiveServer("127.0.0.1", 0, stats=lambda: {"frames_out": 1}).start()
    yield s
    s.close()


def test_other_origins_and_hosts_get_nothing(server):
    p = server.port
    assert _get(p, "/stats", {"Origin": f"http://127.0.0.1:{p}"})[0] == 200  # the page's own
    status, body = _get(p, "/stats", {"Origin": "http://evil.example"})
    assert status == 403 and b"frames_out" not in body and b"--allow-origin" in body
    status, body = _get(p, "/stats", {"Host": f"attacker.example:{p}"})  # DNS rebinding
    assert status == 403 and b"frames_out" not in body
    assert _get(p, "/", {"Host": f"attacker.example:{p}"})[0] == 403
    assert _get(p, "/stats", {"Host": f"localhost:{p}"})[0] == 200
    with pytest.raises(Exception, match="403"):
        ws_client.connect(f"ws://127.0.0.1:{p}/ws", origin="http://evil.example", open_timeout=5)
    assert server.refused == {"origin": 2, "host": 2} and server.clients == 0


def test_allowed_origin_may_watch():
    with LiveServer("127.0.0.1", 0, access=Access(allow_origins=("http://studio.example:8000",))) as s:
        with ws_client.connect(f"ws://127.0.0.1:{s.port}/ws", origin="http://studio.example:8000") as c:
            assert json.loads(c.recv(timeout=5))["type"] == "rig"
    with pytest.raises(FuseFlowError, match="--allow-origin expects"):
        Access(allow_origins=("studio.example",)).check()


def test_non_loopback_bind_needs_the_token():
    with LiveServer("0.0.0.0", 0) as s:
        assert s.token and len(s.token) >= 16
        url = s.url
        assert "0.0.0.0" not in url and url.endswith(f"/?token={s.token}") and lan_address() in url
        status, body = _get(s.port, "/")
        assert status == 403 and b"token" in body
        assert _get(s.port, "/stats?token=wrong")[0] == 403
        assert _get(s.port, f"/?token={s.token}")[0] == 200
        assert _get(s.port, f"/stats?token={s.token}")[0] == 200
        assert _get(s.port, "/viewer.js")[0] == 200  # public code, no secret in it
        with pytest.raises(Exception, match="403"):
            ws_client.connect(f"ws://127.0.0.1:{s.port}/ws", open_timeout=5)
        with ws_client.connect(f"ws://127.0.0.1:{s.port}/ws?token={s.token}", open_timeout=5) as c:
            assert json.loads(c.recv(timeout=5))["type"] == "rig"
    with LiveServer("127.0.0.1", 0) as s:
        assert s.token is None and "token" not in s.url


def test_viewer_cap():
    with LiveServer("127.0.0.1", 0, access=Access(max_viewers=1)) as s:
        with ws_client.connect(f"ws://127.0.0.1:{s.port}/ws", open_timeout=5) as c:
            c.recv(timeout=5)
            with pytest.raises(Exception, match="503"):
                ws_client.connect(f"ws://127.0.0.1:{s.port}/ws", open_timeout=5)
        assert s.refused == {"viewers": 1}


def _frame(k):
    return b"FFLV" + k.to_bytes(4, "little") + bytes(1000)


def test_acknowledging_client_gets_the_newest_frame_only(server):
    c = ws_client.connect(f"ws://127.0.0.1:{server.port}/ws?ack=1", open_timeout=5, max_size=None).__enter__()
    rig = json.loads(c.recv(timeout=5))
    assert rig["type"] == "rig" and rig["run"] == server.run_id
    assert _wait(lambda: server.clients == 1)
    server.publish(_frame(0), {"number": 0, "captured": time.time()})
    head = json.loads(c.recv(timeout=5))
    assert head["type"] == "frame" and head["number"] == 0 and head["age_ms"] >= 0
    assert c.recv(timeout=5)[4:8] == (0).to_bytes(4, "little")
    for k in range(1, 30):  # the client has not acknowledged frame 0: these replace each other
        server.publish(_frame(k), {"number": k, "captured": time.time()})
    assert _wait(lambda: server.client_stats()[0]["dropped"] == 28)  # all 29 handed over
    with pytest.raises(TimeoutError):
        c.recv(timeout=0.2)  # nothing more is queued for it
    c.send(json.dumps({"type": "ack", "number": 0, "age_ms": 12.5, "decode_ms": 3.0, "dropped": 0}))
    head = json.loads(c.recv(timeout=5))
    assert head["number"] == 29 and head["dropped"] == 28  # the newest one, next
    assert c.recv(timeout=5)[4:8] == (29).to_bytes(4, "little")
    assert _wait(lambda: server.client_stats()[0]["frames_sent"] == 2)  # counted once written
    stats = server.client_stats()[0]
    assert stats["ack"] and stats["frames_sent"] == 2 and stats["dropped"] == 28
    assert stats["age_ms"] == 12.5 and stats["age_ms_max"] == 12.5 and stats["rtt_ms"] is not None
    c.close()


def test_end_reaches_current_and_late_clients(server):
    a = ws_client.connect(f"ws://127.0.0.1:{server.port}/ws", open_timeout=5).__enter__()
    a.recv(timeout=5)
    assert _wait(lambda: server.clients == 1)
    server.publish(_frame(7))
    assert a.recv(timeout=5)[4:8] == (7).to_bytes(4, "little")
    server.end("end of source")
    assert json.loads(a.recv(timeout=5)) == {"type": "end", "reason": "end of source"}
    b = ws_client.connect(f"ws://127.0.0.1:{server.port}/ws", open_timeout=5).__enter__()
    b.recv(timeout=5)
    assert b.recv(timeout=5)[4:8] == (7).to_bytes(4, "little")  # the last frame, then the end
    assert json.loads(b.recv(timeout=5))["type"] == "end"
    assert json.loads(_get(server.port, "/stats")[1])["ended"] == "end of source"
    server.end("boom", error=True)
    a.close()
    b.close()
