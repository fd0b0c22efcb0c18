"""Calibration in repeating rooms from ONE frame: is any camera placed a whole room period off
with verdict "good"? Library code and the definitions: benchmarks.studies.calib_turns.

Two separately written studio families of the simulator: ``symstudio`` (``synth.studios``: an
8-12-sided room, a small figure, 5-10 cameras on one ring (even seeds) or two rings (odd seeds))
and ``polyroom`` (``synth.studio_b``: a 6-12-sided room with its own textures, a seated figure of
boxes and cylinders, Kinect v2 or Azure Kinect time-of-flight noise, 5-10 cameras on one or two
rings 2.5-4 m out). Cameras: 5 + seed % 6. ``fuseflow.calibrate`` with its defaults on the first
``--num-frames`` frames (``--dynamic``: the figure moves between frames).

Per camera: placed, verdict, rotation / centre error against the truth (the calibrated world tied
to the true one through the placed camera that puts the most cameras within 1 deg / 3 cm; a lone
right camera does not count as right), the room turn evidence (``camera_verdicts``' "turn").
Counted: "silently wrong" (placed, verdict "good", more than 2 deg or 5 cm off) and "within
1 deg / 3 cm" (of all cameras).

    python -m benchmarks.calib_room_turns --families symstudio,polyroom --seeds 1000-1009 \
        --resolution 320x240 --json /tmp/turns.json
    python -m benchmarks.calib_room_turns --families polyroom --seeds 1-10 --planted column
    python -m benchmarks.calib_room_turns --seeds 3000-3039 --resolution symstudio=512x424,polyroom=320x240 --save

Seeds run in order, each over every family; ``--progress PATH`` rewrites the rows there after each.
"""

from __future__ import annotations

from pathlib import Path

from benchmarks.common import command, parser, save, seeds
from benchmarks.studies.calib_turns import FAMILIES, run_planted_bench, run_turn_bench


def _resolutions(spec: str, fams: list[str]) -> dict[str, tuple[int, int]]:
    """'WxH' for every family, or 'FAMILY=WxH,...' (families not named: 320x240)."""
    out = dict.fromkeys(fams, (320, 240))
    for part in spec.split(","):
        fam, _, wh = part.rpartition("=")
        for f in [fam] if fam else fams:
            out[f] = tuple(int(x) for x in wh.lower().split("x"))
    return out


def main(argv: list[str] | None = None) -> None:
    ap = parser(__doc__, num_frames=1)
    ap.add_argument("--families", default=",".join(FAMILIES))
    ap.add_argument("--seeds", default="1000-1004", help="e.g. 1000-1019 or 3,5,7")
    ap.add_argument("--resolution", default="320x240", help="WxH, or FAMILY=WxH,FAMILY=WxH")
    ap.add_argument("--dynamic", action="store_true", help="the figure moves between frames")
    ap.add_argument("--progress", type=Path, default=None, help="rewrite the rows here after each seed")
    ap.add_argument(
        "--planted",
        choices=("figure", "column", "none"),
        default=None,
        help="measure the subject's turn evidence alone: true poses, cameras turned by planted periods",
    )
    a = ap.parse_args(argv)
    fams = [f for f in a.families.split(",") if f]
    if any(f not in FAMILIES for f in fams):
        ap.error(f"--families: choose from {', '.join(FAMILIES)}")
    res = _resolutions(a.resolution, fams)
    if a.planted:
        rows = run_planted_bench(fams, seeds(a.seeds), res[fams[0]], a.planted, a.progress)
    else:
        rows = run_turn_bench(fams, seeds(a.seeds), res, a.num_frames, a.dynamic, a.progress)
    save(a, "calib_room_turns", command("calib_room_turns", argv), rows,
         {"resolution": {f: f"{w}x{h}" for f, (w, h) in res.items()}, "frames": a.num_frames})  # fmt: skip


if __name__ == "__main__":
    main()
