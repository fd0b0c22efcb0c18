"""SIFT matches between the cameras of simulated rigs: a thin wrapper around
``fuseflow.eval.bench.sim_matches`` (its docstring, shown by ``--help``, says what it measures);
prints its report.

    .venv/bin/python benchmarks/sim_matches.py --scenes studio room
"""

from __future__ import annotations

import argparse

from fuseflow.eval.bench import sim_matches


def main() -> None:
    ap = argparse.ArgumentParser(description=sim_matches.__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", nargs="+", default=["studio", "room"])
    ap.add_argument("--cameras", type=int, default=8)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--noise", default="kinect")
    ap.add_argument("--dynamic", action="store_true")
    ap.add_argument("--ratio", type=float, default=0.75)
    a = ap.parse_args()
    for scene in a.scenes:
        r = sim_matches.run_scene(scene, a.cameras, a.seed, a.ratio, a.noise, a.dynamic)
        for line in sim_matches.scene_report(scene, r, a.cameras, a.seed, a.noise):
            print(line)


if __name__ == "__main__":
    main()
