"""How old is the frame a slow viewer shows? (benchmarks.studies.live_stale): a recording replayed
as cameras through the live loop and its server at ``--rate`` fps; one viewer, in a process of its
own, that needs ``--viewer-ms`` (500: a 2 fps viewer) to decode and show a frame and acknowledges
each frame once shown, as the page does. Per frame shown: its age from the capture stamp, checked
against 2 frame intervals + the viewer's own time. Cases: sim4 (simulated 4 x 320x240 studio),
hocap8 (hocap-8rs, 8 real RealSense 640x480).

    python -m benchmarks.live_stale [--cases sim4,hocap8] [--rate 10] [--viewer-ms 500]
        [--duration 20] [--data-dir ../shared/data] [--json PATH | --save] [--stand-in-ms 50]
"""

from __future__ import annotations

from benchmarks import common
from benchmarks.studies.live_stale import run_stale_bench


def main(argv: list[str] | None = None) -> None:
    ap = common.parser(__doc__, data=True)
    ap.add_argument("--cases", default="sim4,hocap8")
    ap.add_argument("--rate", type=float, default=10.0)
    ap.add_argument("--viewer-ms", type=float, default=500.0)
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--stand-in-ms", type=float, default=None, help="replace FUSE by a sleep of this many ms")
    a = ap.parse_args(argv)
    rows = run_stale_bench(
        common.names(a.cases), a.rate, a.viewer_ms, a.duration, common.data_dir(a.data_dir), a.stand_in_ms, common.log
    )
    common.save(a, "live_stale", common.command("live_stale", argv), rows)


if __name__ == "__main__":
    main()
