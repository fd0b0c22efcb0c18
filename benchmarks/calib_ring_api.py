"""The simulated 4-camera 320x240 ring, calibrated by the CLI and by the Python API: the same
cameras placed, the same verdicts, the same poses, and every camera within 1 deg / 3 cm of the
truth or flagged.

Per seed: ``fuseflow simulate REC --cameras 4 --num-frames 6 --resolution 320x240 --dynamic
--uncalibrated --seed S``; then ``fuseflow calibrate REC --out OUT`` (a subprocess) and
``fuseflow.calibrate(fuseflow.open_recording(REC))`` (this process, warnings recorded). Errors:
each camera's rotation (deg) and position (cm) after aligning the worlds on the placed cameras
(``calib.reference.compare_to_reference``, the same as ``calibrate --reference``) against the
simulator's gt.json. "Silently wrong": placed, verdict good, more than 2 deg or 5 cm off.

    python -m benchmarks.calib_ring_api --seeds 1-10 --work /tmp/ring-api [--json OUT]
"""

from __future__ import annotations

from pathlib import Path

from benchmarks import common
from benchmarks.studies.calib_ring_api import run_ring_api


def main(argv: list[str] | None = None) -> None:
    ap = common.parser(__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="1-10", help="simulator seeds, e.g. 1-10 or 1,4,7")
    ap.add_argument("--work", type=Path, default=Path("/tmp/fuseflow-ring-api"), help="recordings and outputs")
    a = ap.parse_args(argv)
    rows, agreement = run_ring_api(common.seeds(a.seeds), a.work)
    cmd = common.command("calib_ring_api", ["--seeds", a.seeds])
    common.save(a, "calib_ring_api", cmd, rows, {"agreement": agreement})


if __name__ == "__main__":
    main()
