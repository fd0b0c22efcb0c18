"""`fuseflow bench paper`: regenerate the analogues of the paper's tables (fuseflow.eval.paper)."""

from __future__ import annotations

import shlex
import sys
from pathlib import Path

import typer

from fuseflow.cli.app import console, fail
from fuseflow.cli.bench import bench_app


@bench_app.command("paper")
def bench_paper(
    out: Path = typer.Option(..., "--out", help="Output folder: cached cells (cells/*.json), paper_tables.md, PNG."),
    quick: bool = typer.Option(False, "--quick", help="Tiny resolution, 2 frames, 2 seeds: a few minutes (CI)."),
    tables: str = typer.Option(
        "gmac,static,dynamic,ablation,extrinsics,fps",
        "--tables",
        help="Comma list of gmac (I/III), static (IV/VI), dynamic (V), ablation (VII), extrinsics (VIII), fps (Fig. 5).",
    ),
    no_icl: bool = typer.Option(False, "--no-icl", help="Skip the ICL-NUIM virtual rig (simulated data only)."),
) -> None:
    """Tables I/III, IV/VI, V, VII, VIII and Fig. 5 on simulated rigs and the ICL virtual rig.

    Resumable: each cell is cached in OUT/cells and skipped when present; delete a file to redo it.
    """
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from fuseflow.eval import paper

    names = [t.strip() for t in tables.split(",") if t.strip()]
    bad = sorted(set(names) - set(paper.TABLES))
    if not names or bad:
        fail(f"--tables: unknown {bad or 'empty list'}; choose from {', '.join(paper.TABLES)}")
    icl = not no_icl
    if icl and not paper.ICL_PATH.is_dir():
        fail(f"the ICL-NUIM data is not at {paper.ICL_PATH}; pass --no-icl to use simulated data only")
    pc = paper.QUICK if quick else paper.FULL
    command = "fuseflow bench paper " + " ".join(shlex.quote(a) for a in sys.argv[3:]) if len(sys.argv) > 2 else ""
    if not command.strip() or "paper" not in sys.argv:
        command = f"fuseflow bench paper --out {shlex.quote(str(out))}" + (" --quick" if quick else "")
        command += f" --tables {tables}" + (" --no-icl" if no_icl else "")
    with Progress(
        TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
        console=console, transient=False,
    ) as prog:  # fmt: skip
        task = prog.add_task("cells", total=None)

        def step(i: int, n: int, key: str) -> None:
            prog.update(task, total=n, completed=i, description=key[:60])

        files = paper.run(out, pc, names, command=command, progress=step, icl=icl)
    console.print(f"computed {files['computed']} cells; tables: {files['markdown']}")
    if "fig5" in files:
        console.print(f"Fig. 5: {files['fig5']}")
