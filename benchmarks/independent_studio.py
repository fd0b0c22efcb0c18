"""Write an independently rendered repeating studio as a recording: a regular 6-, 8-, 10- or
12-sided room whose wall panels, floor and ceiling sectors repeat exactly, a seated figure of
boxes and cylinders at the centre, 5-10 depth cameras on one or two rings 2.5-3.5 m out. Scene,
textures and sensor models: benchmarks.studies.independent_scene (written apart from the
simulator's studio families).

OUT holds rig.json (intrinsics and sensor preset, no extrinsics), the colour and depth PNGs of
every camera and frame, OUT/reference.json (the true extrinsics as a calib.json, for ``fuseflow
calibrate OUT -o C.json --reference OUT/reference.json``) and OUT/scene.json (the parameters).

    python -m benchmarks.independent_studio /tmp/studio --seed 100
    python -m benchmarks.independent_studio /tmp/studio --seed 7 --resolution 512x424 --frames 5 --moving
"""

from __future__ import annotations

import json
from pathlib import Path

from benchmarks.common import parser
from benchmarks.studies.independent_scene import SENSORS, make_studio, write_studio


def main(argv: list[str] | None = None) -> None:
    ap = parser(__doc__, json=False)
    ap.add_argument("out", type=Path, help="recording directory to write")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--resolution", default="320x240", choices=sorted(SENSORS),
                    help="320x240 (Kinect v2 field of view), 512x424 (Kinect v2), 640x576 (Azure Kinect NFOV)")  # fmt: skip
    ap.add_argument("--frames", type=int, default=1)
    ap.add_argument("--moving", action="store_true", help="the figure turns its torso, head and arms between frames")
    ap.add_argument("--sides", type=int, choices=(6, 8, 10, 12), default=None, help="default: drawn from the seed")
    ap.add_argument("--cameras", type=int, default=None, help="default: 5-10, drawn from the seed")
    a = ap.parse_args(argv)
    if a.frames < 1:
        ap.error("--frames: at least 1")
    if a.cameras is not None and not 2 <= a.cameras <= 16:
        ap.error("--cameras: 2 to 16")
    studio = make_studio(a.seed, a.resolution, a.frames, a.moving, a.sides, a.cameras)
    print(json.dumps(write_studio(a.out, studio)))


if __name__ == "__main__":
    main()
