"""Camera sync: is a camera's stream a few frames late or early against its neighbours?

One package holds the whole algorithm above io (which reads and writes timestamps only):

* ``check``: ``check_sync`` (picks a scorer by recording length), ``check_sync_covisible``,
  ``sync_scores`` (the agreement scorer) and the ``SyncReport``;
* ``covisible``: the co-visible moving-surface scores per camera pair (the 30-fps check);
* ``offsets``: the solver: ``estimate_frame_offset`` (one camera from shifted agreement),
  ``pair_lags`` and ``solve_frame_offsets`` (every camera jointly from pair lags).

docs/formats.md ("Camera-sync check") gives the numbers and the commands behind them.
"""

from fuseflow.pipeline.sync.check import SyncReport, check_sync, check_sync_covisible, sync_scores
from fuseflow.pipeline.sync.covisible import covisible_curves
from fuseflow.pipeline.sync.offsets import (
    FrameOffsets,
    OffsetEstimate,
    PairLag,
    estimate_frame_offset,
    pair_lags,
    solve_frame_offsets,
)

__all__ = [
    "FrameOffsets",
    "OffsetEstimate",
    "PairLag",
    "SyncReport",
    "check_sync",
    "check_sync_covisible",
    "covisible_curves",
    "estimate_frame_offset",
    "pair_lags",
    "solve_frame_offsets",
    "sync_scores",
]
