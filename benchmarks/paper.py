"""The analogues of the paper's tables (section IV) on this machine: Tables I/III, IV/VI, V,
VII, VIII and Fig. 5 on simulated rigs and the ICL virtual rig (benchmarks.studies.paper).

Resumable: each cell is cached in OUT/cells and skipped when present; delete a file to redo it.

    python -m benchmarks.paper --out docs/results --quick
    python -m benchmarks.paper --out /tmp/paper --tables gmac,static --no-icl
"""

from __future__ import annotations

from pathlib import Path

from benchmarks import common
from benchmarks.studies import paper


def main(argv: list[str] | None = None) -> int:
    ap = common.parser(__doc__.split("\n\n")[0], data=True, json=False)
    ap.add_argument("--out", type=Path, required=True, help="output folder: cells/*.json, paper_tables.md, PNG")
    ap.add_argument("--quick", action="store_true", help="tiny resolution, 2 frames, 2 seeds: a few minutes")
    ap.add_argument("--tables", default=",".join(paper.TABLES), help=f"comma list of {', '.join(paper.TABLES)}")
    ap.add_argument("--no-icl", action="store_true", help="skip the ICL-NUIM virtual rig (simulated data only)")
    a = ap.parse_args(argv)
    names = common.names(a.tables)
    bad = sorted(set(names) - set(paper.TABLES))
    if not names or bad:
        ap.error(f"--tables: unknown {bad or 'empty list'}; choose from {', '.join(paper.TABLES)}")
    data_dir = common.data_dir(a.data_dir)
    if not a.no_icl and not paper.icl_path(data_dir).is_dir():
        ap.error(f"the ICL-NUIM data is not at {paper.icl_path(data_dir)}; pass --data-dir, or --no-icl")
    pc = paper.QUICK if a.quick else paper.FULL

    def step(i: int, n: int, key: str) -> None:
        print(f"\r{i}/{n} {key[:60]:60s}", end="", flush=True)

    files = paper.run(a.out, pc, names, command=common.command("paper", argv), progress=step, icl=not a.no_icl,
                      data_dir=data_dir)  # fmt: skip
    print(f"\ncomputed {files['computed']} cells; tables: {files['markdown']}")
    if "fig5" in files:
        print(f"Fig. 5: {files['fig5']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
