"""Cross-view depth agreement of a calibration against a reference's, frame by frame (the logic
of ``benchmarks/calib_frame_agreement.py``): per frame the mean over the camera pairs of
``calib.verdicts.pair_agreements`` (the share of a pair's overlapping depth that agrees, tau 5 %)
under each set of extrinsics, for the cameras both place."""

from __future__ import annotations

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
        rows.append(
            {"frame": i, "ours": float(np.mean(list(a.values()))), "reference": float(np.mean(list(b.values())))}
        )
    return rows
