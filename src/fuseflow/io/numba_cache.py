"""Where numba keeps FuseFlow's compiled kernels, made to work on any machine.

``use_usable_cache(__file__)`` runs before a kernel module decorates its functions with
``@njit(cache=True)``. numba caches in the package's ``__pycache__`` (or NUMBA_CACHE_DIR) and
fails with a traceback when that cannot be written (a read-only install, NUMBA_CACHE_DIR
unwritable or a file, HOME unset) or when a cache file is damaged (an index replaced by
garbage, a ``.nbc`` cut short by a crash). Here: the first writable directory of
NUMBA_CACHE_DIR, the package's ``__pycache__``, ``$XDG_CACHE_HOME``/``~/.cache``/fuseflow/numba
and ``$TMPDIR``/fuseflow-numba-<uid> is used (a fresh temporary directory, i.e. no lasting
cache, when none is), and a damaged cache file counts as a cache miss: the kernel is compiled
again and the file rewritten. Each fallback warns once (``NumbaCacheWarning``).

numba checks a cached kernel against its own file only, yet a kernel that calls (or inlines)
kernels of other files holds their code too. ``use_usable_cache(__file__, package=True)`` stamps
every kernel of the module's package with all the package's ``.py`` files (and ``depends``): an
edit to any of them compiles the package's kernels again.
"""

from __future__ import annotations

import os
import tempfile
import warnings
from pathlib import Path

__all__ = ["use_usable_cache", "NumbaCacheWarning", "writable_dir"]


class NumbaCacheWarning(UserWarning):
    """numba's kernel cache was moved or bypassed (the message says why)."""


_DONE: set[str] = set()


def writable_dir(path: Path) -> bool:
    """True when ``path`` is (or can be made) a directory a file can be created in."""
    try:
        path.mkdir(parents=True, exist_ok=True)
        fd, name = tempfile.mkstemp(prefix=".probe-", dir=path)
        os.close(fd)
        os.unlink(name)
        return True
    except OSError:
        return False


def _candidates() -> list[Path]:
    out = []
    xdg = os.environ.get("XDG_CACHE_HOME")
    home = os.environ.get("HOME")
    if xdg:
        out.append(Path(xdg) / "fuseflow" / "numba")
    elif home:
        out.append(Path(home) / ".cache" / "fuseflow" / "numba")
    try:
        out.append(Path(tempfile.gettempdir()) / f"fuseflow-numba-{os.getuid()}")
    except OSError:  # no usable temporary directory at all
        pass
    return out


def _choose_dir(package_dir: Path) -> str | None:
    """The cache directory to set (None: numba's own choice, the package's __pycache__, works)."""
    import numba

    given = os.environ.get("NUMBA_CACHE_DIR", "")
    if given and writable_dir(Path(given)):
        return given
    if not given and writable_dir(package_dir / "__pycache__"):
        return None
    why = f"NUMBA_CACHE_DIR={given} cannot be written" if given else f"{package_dir / '__pycache__'} cannot be written"
    for cand in _candidates():
        if writable_dir(cand):
            warnings.warn(f"{why}; numba caches FuseFlow's kernels in {cand}", NumbaCacheWarning, stacklevel=3)
            return str(cand)
    fresh = tempfile.mkdtemp(prefix="fuseflow-numba-") if writable_dir(Path(tempfile.gettempdir())) else ""
    warnings.warn(f"{why} and no cache directory is writable: kernels are compiled on each start", NumbaCacheWarning,
                  stacklevel=3)  # fmt: skip
    numba.config.CACHE_DIR = fresh
    return fresh or None


def _tolerate_damaged_files() -> None:
    """A damaged cache file (index or data) is a cache miss, never an exception."""
    from numba.core import caching

    cls = caching.IndexDataCacheFile
    if getattr(cls, "_fuseflow_tolerant", False):
        return
    load, save = cls.load, cls.save

    def tolerant_load(self, key):
        try:
            return load(self, key)
        except Exception as exc:  # noqa: BLE001 - any unpickling error of a damaged file
            _warn_damaged(self, exc)
            try:
                os.unlink(self._index_path)
            except OSError:
                pass
            return None

    def tolerant_save(self, key, data):
        try:
            return save(self, key, data)
        except Exception as exc:  # noqa: BLE001
            _warn_damaged(self, exc)
            return None

    cls.load, cls.save, cls._fuseflow_tolerant = tolerant_load, tolerant_save, True


def _warn_damaged(cache_file, exc: Exception) -> None:
    where = str(getattr(cache_file, "_index_path", "numba's cache"))
    if where not in _DONE:
        _DONE.add(where)
        warnings.warn(f"{where}: damaged numba cache file ({type(exc).__name__}); compiling again", NumbaCacheWarning,
                      stacklevel=2)  # fmt: skip


#: package directory -> extra files whose edits also invalidate its kernels (``package=True``)
_STAMPED: dict[str, tuple[str, ...]] = {}


def package_stamp(package_dir: str) -> tuple:
    """(name, mtime_ns, size) of every ``.py`` file of ``package_dir`` and of its ``depends``."""
    files = sorted(str(p) for p in Path(package_dir).glob("*.py")) + list(_STAMPED.get(package_dir, ()))
    out = []
    for f in files:
        st = os.stat(f)
        out.append((f, st.st_mtime_ns, st.st_size))
    return tuple(out)


class _PackageStampLocator:
    """A numba cache locator for the kernels of a stamped package: numba's own locator (same
    cache directory) with the package's stamp as the source stamp."""

    @classmethod
    def from_function(cls, py_func, py_file):
        from numba.core import caching

        where = str(Path(py_file).resolve().parent)
        if where not in _STAMPED:
            return None
        for other in caching.CacheImpl._locator_classes:
            if other is cls:
                continue
            loc = other.from_function(py_func, py_file)
            if loc is not None:
                loc.get_source_stamp = lambda: package_stamp(where)
                return loc
        return None


def _stamp_package(package_dir: Path, depends: tuple[str | Path, ...]) -> None:
    from numba.core import caching

    # the union over the package's modules: one that names no dependency must not drop another's
    known = set(_STAMPED.get(str(package_dir), ()))
    _STAMPED[str(package_dir)] = tuple(sorted(known | {str(Path(d).resolve()) for d in depends}))
    locators = getattr(getattr(caching, "CacheImpl", None), "_locator_classes", None)
    if locators is None:  # a numba without this hook: kernels are stamped by their own file only
        warnings.warn("numba's cache locators are not reachable: an edit to one kernel file may leave "
                      "a kernel that inlines it stale in the cache (delete __pycache__)", NumbaCacheWarning,
                      stacklevel=3)  # fmt: skip
        return
    if _PackageStampLocator not in locators:
        locators.insert(0, _PackageStampLocator)


def use_usable_cache(module_file: str | Path, package: bool = False, depends: tuple[str | Path, ...] = ()) -> None:
    """Make ``@njit(cache=True)`` in the module ``module_file`` (and its package) work (see the module doc);
    also silence numba's note that the TBB threading layer is missing (numba falls back to its
    own threads: nothing for a user to do). ``package``: a kernel's cache holds while no ``.py``
    file of the package and none of ``depends`` (e.g. the module of an inlined helper) changed."""
    import numba

    warnings.filterwarnings("ignore", message="The TBB threading layer requires", category=numba.NumbaWarning)
    package_dir = Path(module_file).resolve().parent
    if package:
        _stamp_package(package_dir, depends)
    if str(package_dir) in _DONE:
        return
    _DONE.add(str(package_dir))
    chosen = _choose_dir(package_dir)
    if chosen:
        os.environ["NUMBA_CACHE_DIR"] = chosen
        numba.config.CACHE_DIR = chosen
    _tolerate_damaged_files()
