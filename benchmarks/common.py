"""The harness every program in ``benchmarks/`` shares: options, data discovery, timing and
results.

Run a benchmark from the checkout's root as a module, ``python -m benchmarks.NAME [options]``
(``--help`` lists its options). The options below mean the same in every program:

* ``--num-frames N``: how many frames (``--frames A:B[:step]`` selects frames, as in the CLI);
* ``--data-dir DIR``: the shared data folder (``hocap-8rs``, ``icl-livingroom1``, ...); default
  ``$FUSEFLOW_DATA``, else ``../shared/data`` beside the checkout (:func:`data_dir`);
* ``--json PATH``: write the results there; ``--save`` writes them to
  ``benchmarks/results/<version>/<benchmark>.json`` (:func:`results_path`).

Results use one schema (:mod:`fuseflow.eval.results`: schema, benchmark, version, machine,
command, meta, rows), so any file under ``benchmarks/results/`` says which fuseflow, which
machine and which command made it. The studies behind the programs live in
``benchmarks/studies/``; the package (``src/fuseflow``) never imports anything here.
"""

from __future__ import annotations

import argparse
import os
import shlex
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
"""The checkout's root (the folder holding ``benchmarks/`` and ``src/``)."""
RESULTS = ROOT / "benchmarks" / "results"
"""Committed results: one folder per fuseflow version."""


def data_dir(explicit: str | Path | None = None) -> Path:
    """The shared data folder: ``explicit``, else ``$FUSEFLOW_DATA``, else ``../shared/data``
    relative to the checkout (never an absolute path written into a program)."""
    if explicit is not None:
        return Path(explicit)
    env = os.environ.get("FUSEFLOW_DATA")
    return Path(env) if env else ROOT.parent / "shared" / "data"


def results_path(benchmark: str, version: str | None = None) -> Path:
    """``benchmarks/results/<version>/<benchmark>.json`` (version: this fuseflow's)."""
    if version is None:
        from fuseflow import __version__ as version
    return RESULTS / version / f"{benchmark}.json"


def parser(
    doc: str | None, *, num_frames: int | None = None, data: bool = False, json: bool = True
) -> argparse.ArgumentParser:
    """An argument parser with the shared options (module docstring): ``--num-frames`` when
    ``num_frames`` is a default count, ``--data-dir`` with ``data``, ``--json`` / ``--save`` with ``json``."""
    ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    if num_frames is not None:
        ap.add_argument("--num-frames", type=int, default=num_frames, help=f"frames (default {num_frames})")
    if data:
        ap.add_argument("--data-dir", type=Path, default=None,
                        help="shared data folder (default $FUSEFLOW_DATA, else ../shared/data beside the checkout)")  # fmt: skip
    if json:
        ap.add_argument("--json", type=Path, default=None, help="write the results (one schema) here")
        ap.add_argument("--save", action="store_true", help="write them to benchmarks/results/<version>/NAME.json")
    return ap


def command(module: str, argv: Sequence[str] | None = None) -> str:
    """The command line that reproduces this run: ``python -m benchmarks.NAME ARGS``."""
    args = sys.argv[1:] if argv is None else list(argv)
    name = module if module.startswith("benchmarks.") else f"benchmarks.{module}"
    return " ".join(["python -m", name, *(shlex.quote(a) for a in args)])


def save(
    args: argparse.Namespace, benchmark: str, cmd: str, rows: list[Any], meta: dict[str, Any] | None = None
) -> Path | None:
    """Write the rows in the results schema to ``--json`` and/or (``--save``) to
    :func:`results_path`; returns the last path written (None when neither was asked for)."""
    from fuseflow.eval.results import write_result

    out = None
    for path in (getattr(args, "json", None), results_path(benchmark) if getattr(args, "save", False) else None):
        if path is not None:
            out = write_result(path, benchmark, cmd, rows, meta)
            print(f"wrote {out}", flush=True)
    return out


def log(line: str) -> None:
    """Report lines of the studies go to stdout, flushed (they run for minutes)."""
    print(line, flush=True)


def timed(fn: Callable[..., Any], *args: Any, **kwargs: Any) -> tuple[Any, float]:
    """``fn(*args, **kwargs)`` and its wall time in seconds (perf_counter)."""
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t0


def median_ms(fn: Callable[[], Any], repeats: int, warmup: int = 1) -> float:
    """Median wall time of ``fn()`` in ms over ``repeats`` calls after ``warmup`` untimed ones."""
    for _ in range(warmup):
        fn()
    return statistics.median(timed(fn)[1] * 1000.0 for _ in range(max(1, repeats)))


def ints(text: str, option: str) -> list[int]:
    """A comma list of integers, or argparse's error naming ``option``."""
    try:
        return [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise SystemExit(f"error: {option}: expected a comma list of integers, got {text!r}") from None


def seeds(text: str) -> list[int]:
    """Seeds written as ranges and lists: ``"100-119"``, ``"3,5,7"``, ``"1-4,9"``."""
    out: list[int] = []
    for part in text.split(","):
        a, _, b = part.partition("-")
        out += list(range(int(a), int(b) + 1)) if b else [int(a)]
    return out


def names(text: str) -> list[str]:
    """A comma list of names."""
    return [v.strip() for v in text.split(",") if v.strip()]
