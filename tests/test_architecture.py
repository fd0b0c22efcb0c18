"""The architecture of docs/architecture.md, checked: import layering (import-linter contracts in
pyproject.toml), no private name imported across modules, no function over 80 lines outside
the compiled kernels, commands registered in one list; the benchmark home outside the package:
benchmarks/*.py thin programs (120 lines, the public API, fuseflow.eval or benchmarks/studies),
never imported by the package, no absolute path, results in one folder per version;
benchmarks/investigations/ named by a doc and imported by nothing."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src" / "fuseflow"
MAX_LINES = 80
# Known offenders being split; the lists only shrink.
PENDING_LONG: set[str] = set()
PENDING_PRIVATE: set[str] = set()
PENDING_CYCLE: set[str] = set()


def _modules():
    for path in sorted(SRC.rglob("*.py")):
        yield path, ast.parse(path.read_text(), filename=str(path))


def _module_name(path: Path) -> str:
    parts = path.relative_to(SRC.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def test_import_layers_hold():
    pytest.importorskip("importlinter")
    exe = Path(sys.executable).with_name("lint-imports")
    res = subprocess.run([str(exe), "--no-cache"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, (
        f"import-linter contracts broken (pyproject.toml):\n{res.stdout[-3000:]}{res.stderr[-2000:]}"
    )


def test_no_private_name_imported_across_modules():
    offenders = []
    for path, tree in _modules():
        here = _module_name(path)
        package = here if path.name == "__init__.py" else here.rsplit(".", 1)[0]
        for node in ast.walk(tree):
            if not isinstance(node, ast.ImportFrom) or not (node.module or "").startswith("fuseflow"):
                continue
            for alias in node.names:
                if alias.name.startswith("_") and not alias.name.startswith("__") and alias.name not in PENDING_PRIVATE:
                    offenders.append(f"{path.relative_to(ROOT)}:{node.lineno} imports {node.module}.{alias.name}")
            private_module = any(p.startswith("_") and not p.startswith("__") for p in node.module.split("."))
            if private_module and not node.module.startswith(package + "."):
                offenders.append(f"{path.relative_to(ROOT)}:{node.lineno} imports private module {node.module}")
    assert not offenders, "\n".join(offenders)


def _is_kernel(fn: ast.FunctionDef) -> bool:
    """A numba-compiled kernel (@njit / @numba.njit(...) / @jit): exempt from the length limit."""
    for d in fn.decorator_list:
        target = d.func if isinstance(d, ast.Call) else d
        name = target.attr if isinstance(target, ast.Attribute) else getattr(target, "id", "")
        if name in ("njit", "jit", "vectorize", "guvectorize"):
            return True
    return False


def test_no_function_over_80_lines():
    long = []
    for path, tree in _modules():
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and not _is_kernel(node):
                n = node.end_lineno - node.lineno + 1
                if n > MAX_LINES and node.name not in PENDING_LONG:
                    long.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name} ({n} lines)")
    assert not long, "functions over 80 lines (split them into named steps):\n" + "\n".join(long)


def test_commands_are_registered_in_one_list():
    from fuseflow.cli import COMMANDS, GROUPS, app

    registered = {c.name for c in app.registered_commands} | {g.name for g in app.registered_groups}
    assert registered == set(COMMANDS) | set(GROUPS)
    for path, tree in _modules():
        if "cli" in path.parts:
            for node in ast.walk(tree):
                if isinstance(node, ast.Attribute) and node.attr in ("command", "add_typer"):
                    owner = getattr(node.value, "id", "")
                    assert owner != "app" or path.name == "__init__.py", (
                        f"{path}: registers on app outside cli/__init__.py"
                    )


def _strongly_connected(adj: dict[str, set[str]]) -> list[list[str]]:
    """Components of more than one module in the import graph (Tarjan, iterative)."""
    index, low, on, stack, out, counter = {}, {}, set(), [], [], [0]
    for root in adj:
        if root in index:
            continue
        work = [(root, iter(sorted(adj[root])))]
        index[root] = low[root] = counter[0]
        counter[0] += 1
        stack.append(root)
        on.add(root)
        while work:
            v, it = work[-1]
            w = next((x for x in it if x in adj), None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = counter[0]
                    counter[0] += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(adj[w]))))
                elif w in on:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    x = stack.pop()
                    on.discard(x)
                    comp.append(x)
                    if x == v:
                        break
                if len(comp) > 1:
                    out.append(sorted(comp))
    return out


def test_no_import_cycle_between_modules():
    grimp = pytest.importorskip("grimp")
    graph = grimp.build_graph("fuseflow")
    adj = {m: set(graph.find_modules_directly_imported_by(m)) for m in graph.modules}
    cycles = [c for c in _strongly_connected(adj) if not set(c) <= PENDING_CYCLE]
    assert not cycles, f"import cycles (lazy imports count): {cycles}"


MAX_BENCHMARK_LINES = 120


def test_benchmark_scripts_are_thin_wrappers():
    long = []
    for path in sorted((ROOT / "benchmarks").glob("*.py")):
        if path.name in ("common.py", "__init__.py"):  # the shared harness
            continue
        n = len(path.read_text().splitlines())
        if n > MAX_BENCHMARK_LINES:
            long.append(f"benchmarks/{path.name}: {n} lines (at most {MAX_BENCHMARK_LINES})")
    assert not long, "benchmark programs over their size (move the logic into benchmarks/studies):\n" + "\n".join(long)


def test_compiled_kernels_do_not_load_torch():
    """The numba path runs without torch (fuse/kernels/ imports no PyTorch stage module)."""
    pytest.importorskip("numba")
    code = "import sys, fuseflow.fuse.kernels.driver; print('torch' in sys.modules)"
    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0 and res.stdout.strip() == "False", res.stdout + res.stderr[-2000:]


# benchmarks/*.py import the public API only: `fuseflow`, the names a subpackage's __init__ or a
# top-level module (errors, types) exports (its __all__), fuseflow.eval (the metrics, baselines
# and the benchmarks the wheel ships) or benchmarks.* (the harness and the studies, where a
# benchmark's logic lives). One-off studies live in benchmarks/investigations/ under their own
# rule (test_investigations_are_cited_and_imported_by_nothing).


def _public_names(module: str) -> set[str] | None:
    """__all__ of a fuseflow subpackage's __init__ or top-level module (errors, types); None
    for anything deeper."""
    init = SRC.parent.joinpath(*module.split("."), "__init__.py")
    if not init.exists():
        init = SRC.parent.joinpath(*module.split(".")).with_suffix(".py")
    if not init.exists():
        return None
    for node in ast.parse(init.read_text()).body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", "") == "__all__" for t in node.targets):
            return {ast.literal_eval(e) for e in node.value.elts}
    return set()


def _internal_imports(tree: ast.AST) -> list[str]:
    bad = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            mods = [(a.name, None) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0:
            mods = [(node.module or "", [a.name for a in node.names])]
        else:
            continue
        for mod, names in mods:
            if not mod.startswith("fuseflow") or mod == "fuseflow" or mod.startswith("fuseflow.eval"):
                continue
            public = _public_names(mod) if mod.count(".") == 1 else None
            if public is None or (names is not None and not set(names) <= public):
                bad.append(f"{mod} {names or ''}".strip())
    return bad


def test_benchmarks_import_only_the_public_api():
    offenders = []
    for path in sorted((ROOT / "benchmarks").glob("*.py")):
        bad = _internal_imports(ast.parse(path.read_text()))
        if bad:
            offenders.append(f"benchmarks/{path.name}: {', '.join(bad)}")
    assert not offenders, "benchmarks reach into modules (use the public API or benchmarks/studies):\n" + "\n".join(
        offenders
    )


def _imported_modules(tree: ast.AST) -> list[tuple[int, str]]:
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0:
            out.append((node.lineno, node.module or ""))
    return out


def test_the_package_never_imports_the_benchmarks():
    """benchmarks/ is outside the wheel: nothing in src/fuseflow imports it."""
    offenders = [
        f"{path.relative_to(ROOT)}:{line} imports {mod}"
        for path, tree in _modules()
        for line, mod in _imported_modules(tree)
        if mod.split(".")[0] == "benchmarks"
    ]
    assert not offenders, "\n".join(offenders)


def test_every_eval_module_is_used_by_the_package():
    """src/fuseflow holds no module that only benchmarks import: each module of fuseflow.eval is
    imported by another part of the package (the CLI, another eval module) or is the package's
    own __init__."""
    importers: dict[str, set[str]] = {}
    for path, tree in _modules():
        here = _module_name(path)
        for _, mod in _imported_modules(tree):
            importers.setdefault(mod, set()).add(here)
    lonely = []
    for path in sorted((SRC / "eval").rglob("*.py")):
        mod = _module_name(path)
        if path.name == "__init__.py":
            continue
        users = {u for m, us in importers.items() if m == mod or m.startswith(mod + ".") for u in us} - {mod}
        parent = mod.rsplit(".", 1)[0]
        users |= {u for u in importers.get(parent, set()) if u != mod}  # `from fuseflow.eval import metrics`
        if not users:
            lonely.append(mod)
    assert not lonely, f"modules no part of the package imports (move them to benchmarks/): {lonely}"


ROUND_NAME = re.compile(r"(^|_)(s\d+|v\d+|round\d*|issue\d*|before|after)(_|\.|$)")


def test_benchmark_results_live_in_one_folder_per_version_without_round_names():
    results = ROOT / "benchmarks" / "results"
    bad = [p.name for p in results.iterdir() if not (p.is_dir() and re.fullmatch(r"\d+\.\d+\.\d+", p.name))]
    bad += [str(p.relative_to(results)) for p in results.rglob("*") if p.is_file() and ROUND_NAME.search(p.name)]
    assert not bad, f"benchmarks/results/ holds <version>/<benchmark>.<ext> only: {bad}"


def test_benchmarks_hold_no_absolute_path():
    """Data is found relative to the checkout (benchmarks/common.py: data_dir), never at a path of
    one machine."""
    pattern = re.compile(r"[\"'](/work|/home|/Users|/mnt)/")
    bad = [
        str(p.relative_to(ROOT)) for p in sorted((ROOT / "benchmarks").rglob("*.py")) if pattern.search(p.read_text())
    ]
    assert not bad, f"absolute paths in {bad}"


def test_investigations_are_cited_and_imported_by_nothing():
    """benchmarks/investigations/ holds one-off studies: they may reach into any module and have
    no size cap, but each is named by a doc (docs/, README.md or benchmarks/notes/, so the number it
    measured can be re-run) and nothing in src/, tests/ or benchmarks/*.py imports one."""
    docs = "\n".join(
        p.read_text()
        for p in [ROOT / "README.md", *(ROOT / "docs").rglob("*.md"), *(ROOT / "benchmarks" / "notes").glob("*.md")]
    )
    code = [*(SRC.rglob("*.py")), *(ROOT / "tests").rglob("*.py"), *(ROOT / "benchmarks").glob("*.py")]
    studies = sorted((ROOT / "benchmarks" / "investigations").glob("*.py"))
    assert studies
    bad = [f"benchmarks/investigations/{p.name}: no doc names it" for p in studies if p.name not in docs]
    for path in code:
        for node in ast.walk(ast.parse(path.read_text())):
            mods = (
                [a.name for a in node.names]
                if isinstance(node, ast.Import)
                else [node.module or ""]
                if isinstance(node, ast.ImportFrom)
                else []
            )
            bad += [
                f"{path.relative_to(ROOT)} imports {m}"
                for m in mods
                if m.split(".")[0] in {p.stem for p in studies} or "investigations" in m
            ]
    assert not bad, "\n".join(bad)


def test_rgbd_backbone_is_imported_through_its_package():
    """Code outside calib/backbones/rgbd/ imports the rgbd backbone's public names
    (``fuseflow.calib.backbones.rgbd``), never one of its modules."""
    inside = "fuseflow.calib.backbones.rgbd"
    offenders = []
    for path, tree in _modules():
        if _module_name(path).startswith(inside):
            continue
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.level == 0:
                mods = [node.module or ""]
            elif isinstance(node, ast.Import):
                mods = [a.name for a in node.names]
            else:
                continue
            offenders += [
                f"{path.relative_to(ROOT)}:{node.lineno} imports {m}" for m in mods if m.startswith(inside + ".")
            ]
    assert not offenders, "\n".join(offenders)


SOLVERS = {"lstsq", "least_squares", "minimize", "solve", "curve_fit", "leastsq"}


def test_io_holds_formats_and_calls_no_solver():
    """io reads and writes formats (timestamps included); estimating anything from them (the
    sync offsets) lives above it, in fuseflow.pipeline.sync."""
    offenders = []
    for path, tree in _modules():
        if not _module_name(path).startswith("fuseflow.io"):
            continue
        for node in ast.walk(tree):
            if isinstance(node, ast.Call):
                f = node.func
                name = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", "")
                if name in SOLVERS:
                    offenders.append(f"{path.relative_to(ROOT)}:{node.lineno} calls {name}")
    assert not offenders, "solvers in io (move them to pipeline.sync or another layer above io):\n" + "\n".join(
        offenders
    )
