"""Cross-view depth agreement of a calibration against a reference's, frame by frame: per frame
the mean over the camera pairs of the share of a pair's overlapping depth that agrees (tau 5 %)
under each set of extrinsics, for the cameras both place (``benchmarks.studies.calib_frame_agreement``).

    python -m benchmarks.calib_frame_agreement REC CALIB.json REF.json [--frames 0:25]
"""

from __future__ import annotations

import argparse

import numpy as np

from benchmarks.studies.calib_frame_agreement import frame_agreements


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("recording")
    ap.add_argument("calib")
    ap.add_argument("reference")
    ap.add_argument("--frames", default=None, help="START:STOP (default: every frame)")
    a = ap.parse_args(argv)
    rows = frame_agreements(a.recording, a.calib, a.reference, a.frames)
    for r in rows:
        print(f"frame {r['frame']:3d}  ours {r['ours']:.3f}  reference {r['reference']:.3f}")
    ours, ref = np.array([r["ours"] for r in rows]), np.array([r["reference"] for r in rows])
    print(
        f"{len(rows)} frames: mean {ours.mean():.3f} against {ref.mean():.3f}; ours higher on "
        f"{int((ours > ref).sum())} of {len(rows)}, lowest margin {float((ours - ref).min()):+.3f}"
    )


if __name__ == "__main__":
    main()
