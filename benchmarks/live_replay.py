"""Live replay benchmark: recordings replayed as cameras through `fuseflow live --serve` with one
WebSocket viewer (fuseflow.eval.bench.live, also ``fuseflow bench live``).

    python -m benchmarks.live_replay [--cases sim4,hocap8,hocap8-200k] [--duration 20]
        [--data-dir ../shared/data] [--json benchmarks/results/live_replay.json] [--stand-in-ms 56]
    python -m benchmarks.live_replay --nodes 3 [--duration 20] [--runs 3] [--wires auto,jpeg,auto@head] [--save]

--nodes N: N capture nodes on a local Ray cluster, each replaying some cameras of a simulated
8-camera 640x480 dynamic recording, against the one-host rate measured in the same run
(fuseflow.eval.bench.live_nodes, also ``fuseflow bench live --nodes 3``), per wire format (auto: raw on this machine; jpeg: what crosses
a network); saved as live_nodes.json.

Prints per case: sustained fused frames/s, drop rate, latency (capture to sent) p50/p95, FUSE ms,
points per frame and the viewer's Mbit/s, with the target (docs/live.md) and whether it was met.
"""

from __future__ import annotations

from benchmarks import common
from fuseflow.eval.bench.live import run_live_bench


def main(argv: list[str] | None = None) -> None:
    ap = common.parser(__doc__, data=True)
    ap.add_argument("--cases", default="sim4,hocap8,hocap8-200k")
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--stand-in-ms", type=float, default=None, help="replace FUSE by a sleep (all but FUSE)")
    ap.add_argument("--nodes", type=int, default=None, help="capture nodes on a local Ray cluster vs one host")
    ap.add_argument("--runs", type=int, default=1, help="--nodes: repeat the whole comparison")
    ap.add_argument("--wires", default="auto,jpeg,auto@head",
                    help="--nodes: wire formats (fuseflow live --frame-codec); @head: the capture actors on the "
                         "fusing process's Ray node instead of one Ray node each")  # fmt: skip
    a = ap.parse_args(argv)
    command = common.command("live_replay", argv)
    if a.nodes is not None:
        from fuseflow.eval.bench.live_nodes import run_nodes_bench

        wires = tuple(common.names(a.wires))
        rows = run_nodes_bench(a.nodes, a.duration, log=common.log, data_dir=common.data_dir(a.data_dir), runs=a.runs,
                               wires=wires)  # fmt: skip
        common.save(a, "live_nodes", command, rows, {"nodes": a.nodes, "duration_s": a.duration, "runs": a.runs,
                                                     "wires": list(wires)})  # fmt: skip
        return
    cases = common.names(a.cases)
    rows = run_live_bench(cases, a.duration, common.data_dir(a.data_dir), None, command=command, log=common.log,
                          stand_in_ms=a.stand_in_ms)  # fmt: skip
    common.save(a, "live_replay", command, rows, {"cases": cases, "duration_s": a.duration})


if __name__ == "__main__":
    main()
