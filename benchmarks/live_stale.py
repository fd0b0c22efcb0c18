"""How old is the frame a slow viewer shows? A recording replayed as cameras through the live loop
and its server at ``--rate`` fps (10 by default); one viewer, in a process of its own, that needs
``--viewer-ms`` (500 by default: a 2 fps viewer) to decode and show a frame, acknowledges each frame
once shown (``/ws?ack=1``, as the page does) and measures, per frame shown, its age: the time from
the frame's capture stamp (the source's release time, in the server's clock: same machine) to the
moment it is shown.

    python benchmarks/live_stale.py [--cases sim4,hocap8] [--rate 10] [--viewer-ms 500]
        [--duration 20] [--data-dir ../shared/data] [--json benchmarks/results/live_stale.json]
        [--stand-in-ms 50]

Bound checked per frame shown: age <= 2 frame intervals + the viewer's own time for that frame
(decode + show). The age is also split: capture to sent (``sent_age``: fusion, encoding and the
wait for the viewer's acknowledgement), sent to the viewer starting on it (``in_transit``), and
the viewer's own time (``busy``). Cases: ``sim4`` (a simulated 4-camera 320x240 dynamic studio, 30 frames, looped),
``hocap8`` (hocap-8rs: 8 real RealSense 640x480, its frame looped). FUSE preset ``live`` on the
CPU, compact codec.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from fuseflow.eval.bench.live_stale import run_stale_bench  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", default="sim4,hocap8")
    ap.add_argument("--rate", type=float, default=10.0)
    ap.add_argument("--viewer-ms", type=float, default=500.0)
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--data-dir", type=Path, default=Path("../shared/data"))
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--stand-in-ms", type=float, default=None, help="replace FUSE by a sleep of this many ms")
    a = ap.parse_args()
    command = "python benchmarks/live_stale.py " + " ".join(sys.argv[1:])
    run_stale_bench([c for c in a.cases.split(",") if c], a.rate, a.viewer_ms, a.duration, a.data_dir, a.json,
                    command, a.stand_in_ms, print)  # fmt: skip


if __name__ == "__main__":
    main()
