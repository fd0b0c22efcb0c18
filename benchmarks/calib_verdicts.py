#!/usr/bin/env python
"""The per-camera verdicts and expected accuracy of ``calibrate`` against the truth: a thin wrapper
around ``benchmarks.studies.calib_verdicts`` , whose
docstring says what is measured (simulated room rings, 320x240, one frame, default config).
Prints one line per camera and a summary; --out writes the rows as JSON.

    python -m benchmarks.calib_verdicts --cameras 4,6 --seeds 1,2 --json /tmp/verdicts.json
"""

from __future__ import annotations

from benchmarks import common
from benchmarks.studies.calib_verdicts import run_calib_verdicts, verdict_summary


def main(argv: list[str] | None = None) -> None:
    ap = common.parser(__doc__.splitlines()[0])
    ap.add_argument("--cameras", default="4,6", help="comma list of ring sizes")
    ap.add_argument("--seeds", default="1,2", help="comma list of simulator seeds")
    a = ap.parse_args(argv)
    rows = run_calib_verdicts(
        common.ints(a.cameras, "--cameras"), common.ints(a.seeds, "--seeds"), log=lambda r: print(r, flush=True)
    )
    line = verdict_summary(rows)
    if line is not None:
        print(line)
    common.save(a, "calib_verdicts", common.command("calib_verdicts", argv), rows)


if __name__ == "__main__":
    main()
