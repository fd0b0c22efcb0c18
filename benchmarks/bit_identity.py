"""Outputs before and after a change, compared byte for byte: clouds and calib.json on a small
simulated ring, the ICL-NUIM virtual rig and HO-Cap (benchmarks.studies.bit_identity, whose
docstring lists the commands and what is compared). Exit status 1 when any case differs.

    git worktree add /tmp/fuseflow-base <base commit>
    python -m benchmarks.bit_identity --base /tmp/fuseflow-base --work /tmp/fuseflow-bitid --save
"""

from __future__ import annotations

from pathlib import Path

from benchmarks import common
from benchmarks.studies.bit_identity import CASES, run


def main(argv: list[str] | None = None) -> int:
    ap = common.parser(__doc__.split("\n\n")[0], data=True)
    ap.add_argument("--base", type=Path, required=True, help="the other source tree (a folder holding src/fuseflow)")
    ap.add_argument("--head", type=Path, default=common.ROOT, help="this source tree (default: this checkout)")
    ap.add_argument("--work", type=Path, default=Path("/tmp/fuseflow-bit-identity"), help="output folder")
    ap.add_argument("--cases", default=",".join(CASES), help=f"comma list of {', '.join(CASES)}")
    a = ap.parse_args(argv)
    for tree in (a.base, a.head):
        if not (tree / "src" / "fuseflow").is_dir():
            ap.error(f"{tree}: no src/fuseflow (pass a checkout or a git worktree)")
    rows = run(a.base, a.head, common.names(a.cases), a.work, common.data_dir(a.data_dir), common.log)
    common.save(a, "bit_identity", common.command("bit_identity", argv), rows)
    return 0 if all(r.get("identical", True) for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
