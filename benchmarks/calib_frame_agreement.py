"""Cross-view depth agreement of a calibration against a reference's, frame by frame: per frame
the mean over the camera pairs of ``calib.verdicts.pair_agreements`` (the share of a pair's
overlapping depth that agrees, tau 5 %) under each set of extrinsics, for the cameras both place.

    python -m benchmarks.calib_frame_agreement REC CALIB.json REF.json [--frames 0:25]
"""

from __future__ import annotations

import argparse

import numpy as np


def frame_agreements(rec_path: str, calib_path: str, ref_path: str, frames: str | None = None) -> list[dict]:
    """One row per frame: index, mean agreement under the calibration and under the reference."""
    import fuseflow
    from fuseflow.calib.verdicts import pair_agreements
    from fuseflow.io.calibration import read_calibration, read_reference

    rec = fuseflow.open_recording(rec_path)
    ours, ref = read_calibration(calib_path).T_cam_world, read_reference(ref_path).T_cam_world
    both = [c for c in rec.rig.ids if c in ours and c in ref]
    lo, hi = (int(x) for x in frames.split(":")) if frames else (0, len(rec))
    rows = []
    for i in range(lo, min(hi, len(rec))):
        f = rec[i]
        a = pair_agreements(f, rec.rig, {c: ours[c] for c in both})
        b = pair_agreements(f, rec.rig, {c: ref[c] for c in both})
        rows.append({"frame": i, "ours": float(np.mean(list(a.values()))), "reference": float(np.mean(list(b.values())))})
    return rows


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
