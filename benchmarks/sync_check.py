"""Camera-sync check accuracy over a grid of simulated recordings: a thin wrapper around
``benchmarks.studies.sync_check`` , whose docstring says what
is measured and lists the configs. Prints one row per recording and a table per config: exact /
of seeds, false alarms, seconds per check. Recordings are kept in the folder and reused.

    PYTHONPATH=src python -m benchmarks.sync_check /tmp/sync-grid --seeds 5 [--fps 30 --num-frames 90]
        [--method auto|covisible|agreement] [--configs c4_160_late2,c4_160_sync,c3_160_early1]
"""

from __future__ import annotations

from pathlib import Path

from benchmarks import common
from benchmarks.studies.sync_check import CONFIGS, METHODS, run_sync_check


def main(argv: list[str] | None = None) -> None:
    ap = common.parser(__doc__, num_frames=20, json=False)
    ap.add_argument("root", type=Path)
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--fps", type=float, default=30.0)
    ap.add_argument("--configs", default=",".join(CONFIGS))
    ap.add_argument("--method", default="auto", choices=list(METHODS))
    ap.add_argument("--first-seed", type=int, default=0)
    a = ap.parse_args(argv)
    run_sync_check(a.root, a.seeds, a.fps, a.num_frames, common.names(a.configs), a.method, a.first_seed,
                   log=lambda line: print(line, flush=True))  # fmt: skip


if __name__ == "__main__":
    main()
