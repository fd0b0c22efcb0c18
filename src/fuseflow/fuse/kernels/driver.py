"""The compiled CPU path of FUSE, stage by stage over one frame (``fuse_numba``), and the depth
gate of api._prepare (``gate_depth``). The s0 search of target_points is fuse/density.py's
(``fit_s0``); here it counts with the hash and eq. (26) only."""

from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np

from fuseflow.fuse.config import FuseConfig
from fuseflow.fuse.density import fit_s0, with_s0
from fuseflow.fuse.kernels.ash import cells, fine_pass, scatter
from fuseflow.fuse.kernels.common import chunk_bounds
from fuseflow.fuse.kernels.params import ConsensusParams, KernelParams, PixelParams, consensus_params, kernel_params
from fuseflow.fuse.kernels.pixels import gate_rows, pixels
from fuseflow.fuse.kernels.rps import count_kept, emit, select
from fuseflow.fuse.kernels.workspace import Workspace, workspace
from fuseflow.geometry.camera import relative_transforms
from fuseflow.types import FusedCloud

__all__ = ["fuse_numba", "gate_depth"]

_F = np.float32


def gate_depth(depth: np.ndarray, lo: np.ndarray, hi: np.ndarray, present: np.ndarray):
    """(gated depth (N, H, W) float32 array, valid pixels per view): torch_driver.gate_depth
    (valid_depth, then zero for absent views) as one compiled pass. The array is a view of this
    thread's FUSE workspace: the next ``fuse_numba`` call overwrites it after reading it (api._prepare's depth is read only by that call)."""
    d = np.ascontiguousarray(depth, dtype=np.float32)
    n, h, w = d.shape
    # in this thread's workspace (fuse_numba reads it in pixels, then the buffer holds the
    # points): valid until the next fuse_numba of this thread
    out = workspace(n, h, w).depth()
    rows = np.empty(n * h, dtype=np.int64)
    gate_rows(d, np.asarray(lo, dtype=np.float32), np.asarray(hi, dtype=np.float32), np.asarray(present, dtype=np.bool_),
          out, rows)  # fmt: skip
    return out, tuple(int(x) for x in rows.reshape(n, h).sum(axis=1))


class _Cells(NamedTuple):
    """Stage 1-2 output: candidates at their pixel index, grouped by coarse cell."""

    P: np.ndarray  # (M, 3) float32 world points of the members, in members' order (scatter)
    om: np.ndarray  # (N H W,) float32 joint weight, eq. (22)
    rank: np.ndarray  # ranking value of eq. (28) (om itself without range_priority)
    start: np.ndarray  # (C + 1,) int64 slots of each coarse cell
    cell_key: np.ndarray  # (C,) int64 packed coarse key
    members: np.ndarray  # (M,) int32 pixel indices of the in-range candidates, grouped by cell
    largest: int  # points in the largest coarse cell
    candidates: int
    out_of_range: int


def _candidates(p, prm: PixelParams, ws: Workspace) -> _Cells:
    """Stages 1-2: ``pixels`` over every view, coarse cells per run, members grouped by cell."""
    depth = np.ascontiguousarray(p.depth)
    n, h, w = depth.shape
    Kf = np.asarray(p.K, dtype=np.float32)
    M_rel = relative_transforms(np.asarray(p.T_cam_world))
    T_wc = np.asarray(p.T_world_cam, dtype=np.float32)
    nbr = np.ascontiguousarray(p.graph.index, dtype=np.int64)
    present = np.asarray(p.present, dtype=np.bool_)
    rank = ws.rank(prm.range_priority)
    with numba.parallel_chunksize(8):  # rows differ in cost (and a shared core may stall)
        pixels(depth, Kf, M_rel, T_wc, nbr, present, prm, ws.P, ws.om, rank, ws.sup, ws.runs, ws.run_n,
                ws.row_info)  # fmt: skip
    run_slot = np.empty(int(ws.row_info[:, 2].sum()), dtype=ws.members.dtype)
    start, cell_key, largest, roff = cells(ws.runs, ws.run_n, ws.row_info, run_slot)
    m = int(start[-1])
    members = ws.members[:m]
    Pc = ws.Pc[:m]
    with numba.parallel_chunksize(8):
        scatter(ws.om, run_slot, roff, ws.row_info, w, ws.P, members, Pc)
    del run_slot
    cand = int(ws.row_info[:, 0].sum())
    oor = int(ws.row_info[:, 1].sum())
    return _Cells(Pc, ws.om, rank if prm.range_priority else ws.om, start, cell_key, members, int(largest), cand, oor)


class _Selection(NamedTuple):
    start: np.ndarray
    cell_nsel: np.ndarray  # (C,) representatives per coarse cell
    points: int


def _select_points(
    c: _Cells, prm: KernelParams, ws: Workspace, cons: ConsensusParams, T_wc, T_cw, hw: int, count_only: bool = False
):
    """Stages 3 and 4 on the grouped candidates: fine cells, eq. (26), FPS and (cons.on) the
    consensus; the representatives staged per coarse cell in ``ws`` (``select``). With
    ``count_only`` only how many points selection keeps (``count_kept``; density control)."""
    n_cells = c.start.shape[0] - 1
    m = c.members.shape[0]
    chunks = chunk_bounds(c.start, min(max(n_cells, 1), 16 * numba.get_num_threads()))
    members, fkey = c.members, ws.fkey[:m]
    csize = np.empty(n_cells, dtype=np.float32)
    rho_sum = np.empty(n_cells, dtype=np.float64)
    fine_n = np.empty(n_cells, dtype=np.int64)
    # slot-ordered omega, camera and rank (read by select and emit): fkey, omc and camc in
    # the buffer of the points by pixel, which nothing reads after scatter; Pc and members
    # sorted in place
    Pc, camc, omc = c.P, ws.camc[:m], ws.omc[:m]
    copy_rank = c.rank is not c.om
    rkc = ws.rkc[:m] if copy_rank else omc
    with numba.parallel_chunksize(1):  # chunks handed out as threads free up (a shared core may stall)
        fine_pass(Pc, c.start, c.cell_key, prm.cell, chunks, c.largest, not count_only, members, fkey,
                   csize, rho_sum, fine_n, c.om, c.rank, copy_rank, hw, omc, rkc, camc, ws.sup)  # fmt: skip
    sel_prm = prm.select
    if not sel_prm.fixed_k:  # eq. (26)'s rho_bar: mean density over the occupied fine cells
        total = int(fine_n.sum())
        sel_prm = sel_prm._replace(rho_bar=_F(rho_sum.sum() / max(total, 1)))
    nsel = np.empty(n_cells, dtype=np.int64)
    if count_only:
        count_kept(c.start, fkey, camc, csize, fine_n, sel_prm, nsel)
        return _Selection(c.start, nsel, int(nsel.sum()))
    with numba.parallel_chunksize(1):
        select(Pc, rkc if copy_rank else omc, omc, camc, c.start, members, fkey, csize, fine_n, sel_prm, chunks, c.largest,
                cons, T_wc, T_cw, hw, ws.stage_src, ws.stage_sup, nsel, ws.sup)  # fmt: skip
    return _Selection(c.start, nsel, int(nsel.sum()))


def fuse_numba(p, cfg: FuseConfig) -> tuple[FusedCloud, int, int, int]:
    """The compiled CPU path over api._Prepared inputs (numpy arrays); same contract as
    torch_driver.fuse_torch, with a cloud of numpy arrays."""
    prm = kernel_params(cfg)
    n, h, w = p.depth.shape
    ws = workspace(n, h, w)
    c = _candidates(p, prm.pixel, ws)
    T_wc = np.asarray(p.T_world_cam, dtype=np.float32)
    T_cw = np.asarray(p.T_cam_world, dtype=np.float32)
    hw = h * w
    if cfg.target_points is not None:  # density control: search s0 on the hash + selection only
        off = consensus_params(cfg, on=False)

        def count_at(s0: float) -> int:
            return _select_points(c, kernel_params(with_s0(cfg, s0)), ws, off, T_wc, T_cw, hw, count_only=True).points

        cfg = fit_s0(cfg, count_at)
        prm = kernel_params(cfg)
    cons = consensus_params(cfg)
    s = _select_points(c, prm, ws, cons, T_wc, T_cw, hw)
    k = s.points
    cell_out = np.zeros(s.cell_nsel.shape[0], dtype=np.int64)
    if cell_out.shape[0] > 1:
        np.cumsum(s.cell_nsel[:-1], out=cell_out[1:])
    xyz = np.empty((k, 3), dtype=np.float32)
    rgb = np.empty((k, 3), dtype=np.uint8)
    wgt = np.empty(k, dtype=np.float32)
    src = np.empty(k, dtype=np.int16)
    sup = np.empty(k if cons.on else 0, dtype=np.int16)
    color = np.ascontiguousarray(p.color).reshape(n * h * w, 3)
    rig_index = np.asarray(p.rig_index, dtype=np.int16)
    with numba.parallel_chunksize(4):  # a few hundred coarse cells of very different sizes
        emit(s.start, s.cell_nsel, cell_out, ws.stage_src, ws.stage_sup, cons.on, ws.members, ws.Pc,
              ws.omc, ws.camc, color, rig_index, xyz, rgb, wgt, src, sup)  # fmt: skip
    cloud = FusedCloud(xyz, rgb, wgt, src, sup if cons.on else None)  # numpy arrays
    return cloud, int(sum(p.valid_per_view)), c.candidates - c.out_of_range, c.out_of_range
