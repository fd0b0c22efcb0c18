#!/usr/bin/env python
"""The per-camera verdicts and expected accuracy of ``calibrate`` against the truth: a thin wrapper
around ``fuseflow.eval.bench.calib_verdicts`` (also ``fuseflow bench calib-verdicts``), whose
docstring says what is measured (simulated room rings, 320x240, one frame, default config).
Prints one line per camera and a summary; --out writes the rows as JSON.

    python benchmarks/calib_verdicts.py --cameras 4 6 --seeds 1 2 --out /tmp/verdicts.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from fuseflow.eval.bench.calib_verdicts import run_calib_verdicts, verdict_summary


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cameras", type=int, nargs="+", default=[4, 6])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--out", type=Path)
    a = ap.parse_args()
    rows = run_calib_verdicts(a.cameras, a.seeds, log=lambda r: print(r, flush=True))
    line = verdict_summary(rows)
    if line is not None:
        print(line)
    if a.out:
        a.out.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
