"""SIFT matches between the cameras of simulated rigs: a thin wrapper around
``benchmarks.studies.sim_matches`` (its docstring, shown by ``--help``, says what it measures);
prints its report.

    python -m benchmarks.sim_matches --scenes studio room
"""

from __future__ import annotations

from benchmarks import common
from benchmarks.studies import sim_matches


def main(argv: list[str] | None = None) -> None:
    ap = common.parser(sim_matches.__doc__, json=False)
    ap.add_argument("--scenes", default="studio,room", help="comma list of scenes")
    ap.add_argument("--cameras", type=int, default=8)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--noise", default="kinect")
    ap.add_argument("--dynamic", action="store_true")
    ap.add_argument("--ratio", type=float, default=0.75)
    a = ap.parse_args(argv)
    for scene in common.names(a.scenes):
        r = sim_matches.run_scene(scene, a.cameras, a.seed, a.ratio, a.noise, a.dynamic)
        for line in sim_matches.scene_report(scene, r, a.cameras, a.seed, a.noise):
            print(line)


if __name__ == "__main__":
    main()
