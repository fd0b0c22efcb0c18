"""Per-thread buffers of the compiled path, reused from frame to frame of one shape."""

from __future__ import annotations

import threading

import numpy as np

__all__ = ["Workspace", "workspace", "release_workspace"]


class Workspace:
    """Per-thread buffers of one frame shape, reused from frame to frame: a fresh 100+ MB of
    arrays per frame cost as much in page faults as some kernels (the kernel zero-fills every
    new page). Buffers hold no result; the cloud is built from new arrays.

    33 bytes per pixel (ICL, 8 x 640 x 480: 77 MiB), by reusing buffers whose
    lifetimes do not overlap (stages: 1 ``gate_rows`` / ``pixels``, 2 ``cells``, 3 ``scatter``,
    4 ``fine_pass``, 5 ``select``, 6 ``emit``):

    - ``pbuf`` (12 B): the gated depth (its first 4 B per pixel, 1; ``gate_depth``) and the
      rows' coarse runs (key, 8 B per pixel's room, 1-2); then ``Pc``, the points by coarse
      cell (3), sorted into slot order in place (4), moved by the consensus (5).
    - ``buf`` (12 B): the points by pixel (``P``, 1-3); once ``scatter`` has read them, fkey
      (4 B), omega and camera by slot (4 + 2 B) and the representatives' support (2 B).
    - ``members`` (4 B): the runs' sizes (1-2), then the pixel index per slot (3-6).
    - ``om`` (4 B): omega by pixel (1-4; NaN = no in-range candidate, sign = a run's first
      point, so no flags), then ``stage_src`` (5-6).
    - ``sup`` (1 B): the neighbours confirming each candidate within the multi-view mean's
      gate (1-5; FuseConfig.rps.lone_cell_keep).
    - with ``range_priority`` only: ``pr`` (omega / sigma by pixel) and ``rkc`` (by slot), 8 B.

    The only per-frame arrays besides the cloud are sized by cells or runs (``cells``)."""

    def __init__(self, n: int, h: int, w: int) -> None:
        npx = n * h * w
        self.shape = (n, h, w)
        idx = np.int32 if npx < 2**31 else np.int64  # pixel indices
        self.pbuf = np.empty(12 * npx + 8, dtype=np.uint8)
        self.Pc = self.pbuf[: 12 * npx].view(np.float32).reshape(npx, 3)
        o = (4 * npx + 7) // 8 * 8  # 8-aligned, after the gated depth
        self.runs = self.pbuf[o : o + 8 * npx].view(np.int64).reshape(n * h, w)
        self.buf = np.empty(12 * npx, dtype=np.uint8)
        self.P = self.buf.view(np.float32).reshape(npx, 3)
        self.fkey = self.buf[: 4 * npx].view(np.int32)
        self.omc = self.buf[4 * npx : 8 * npx].view(np.float32)
        self.camc = self.buf[8 * npx : 10 * npx].view(np.int16)  # camera of each slot
        self.stage_sup = self.buf[10 * npx :].view(np.int16)
        self.members = np.empty(npx, dtype=idx)
        self.run_n = self.members.reshape(n * h, w)
        self.om = np.empty(npx, dtype=np.float32)
        self.sup = np.empty(npx, dtype=np.uint8)  # confirming neighbours by pixel (lone_cell_keep)
        # the representatives' slots: omega by pixel is not read after fine_pass
        self.stage_src = self.om.view(np.int32) if idx is np.int32 else np.empty(npx, dtype=idx)
        self.pr = np.empty(1, dtype=np.float32)
        self.rkc = np.empty(1, dtype=np.float32)
        self.row_info = np.empty((n * h, 3), dtype=np.int64)

    def depth(self) -> np.ndarray:
        """The gated depth's buffer (N, H, W) float32: the first third of Pc, which nothing
        writes before ``scatter``, i.e. after ``pixels`` has read the depth."""
        n, h, w = self.shape
        return self.Pc.reshape(-1)[: n * h * w].reshape(n, h, w)

    def rank(self, on: bool) -> np.ndarray:
        """The buffer for the range-aware ranking value (length 1 when unused)."""
        if on and self.pr.shape[0] != self.om.shape[0]:
            self.pr = np.empty(self.om.shape[0], dtype=np.float32)
            self.rkc = np.empty(self.om.shape[0], dtype=np.float32)
        return self.pr


_LOCAL = threading.local()


def workspace(n: int, h: int, w: int) -> Workspace:
    """This thread's workspace for frames of shape (n, h, w); another shape replaces it (the
    old buffers are released first)."""
    ws = getattr(_LOCAL, "ws", None)
    if ws is None or ws.shape != (n, h, w):
        _LOCAL.ws = ws = None  # drop the old buffers before allocating new ones
        _LOCAL.ws = ws = Workspace(n, h, w)
    return ws


def release_workspace() -> None:
    """Free this thread's workspace (it is otherwise kept for the next frame of the same shape)."""
    _LOCAL.ws = None
