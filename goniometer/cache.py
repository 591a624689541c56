"""The project's caches, keyed by the code they depend on.

numba's ``cache=True`` keys a cached function on the source file that defines it only: a kernel
in ``tracer.py`` that inlines ``optics.fresnel_conductor`` would keep the old, cached physics
after ``optics.py`` changes. So the cache directory is keyed by a hash of whole packages
(:func:`package_key`): the simulator's kernels by ``goniometer`` (:func:`simulator_key`), the
models' by ``goniometer`` + ``models`` (``models`` decorates its functions inside
:func:`numba_cache_dir`), the command-line and report code excluded. Any other source change
starts a fresh cache.

Location: ``$NUMBA_CACHE_DIR/<key>`` if the user set ``NUMBA_CACHE_DIR``, else
``$GONIOMETER_CACHE/numba/<key>`` (default ``~/.cache/goniometer/numba/<key>``).
Configured once from ``goniometer/__init__.py``, before any function is compiled.

Old caches: every source change starts a new directory, so under the default location (not under
a user's ``NUMBA_CACHE_DIR``) :func:`configure` marks the directory it uses (``.last-used``) and
removes sibling directories beyond the :data:`KEEP` most recently used that have not been used for
:data:`STALE_S` seconds.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.util
import os
from pathlib import Path
from typing import Iterator, Sequence

import numba


def cache_root() -> Path:
    """The project's cache directory (tables, compiled kernels): ``$GONIOMETER_CACHE`` or
    ``~/.cache/goniometer``."""
    env = os.environ.get("GONIOMETER_CACHE")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "goniometer"


def package_key(packages: Sequence[str], *, exclude: Sequence[str] = ()) -> str:
    """Hash of the Python sources of whole packages (found without importing them) and the numba
    version: every ``.py`` file below each package's directory, minus the subpackages or modules
    named in ``exclude`` (dotted names). Paths enter the hash relative to the package's parent, so a file moved inside a
    package changes the key once, and a file outside the packages never does."""
    h = hashlib.sha256(numba.__version__.encode())
    skip = [_package_dir(name) for name in exclude]
    for name in packages:
        root = _package_dir(name)
        files = sorted(root.rglob("*.py")) if root.is_dir() else [root.with_suffix(".py")]
        for p in files:
            if any(p == s.with_suffix(".py") or s in p.parents for s in skip):
                continue
            h.update(p.relative_to(root.parent).as_posix().encode())
            h.update(p.read_bytes())
    return h.hexdigest()[:16]


def _package_dir(dotted: str) -> Path:
    """Directory of a package (or, for a module, its path without ``.py``), without importing it."""
    head, _, tail = dotted.partition(".")
    spec = importlib.util.find_spec(head)
    if spec is None or not spec.submodule_search_locations:
        raise ValueError(f"{head}: not an importable package")
    base = Path(next(iter(spec.submodule_search_locations))).resolve()
    return base.joinpath(*tail.split(".")) if tail else base


#: the application inside ``goniometer`` (the ``gonio`` host and its commands): outside the key
SIMULATOR_APPLICATION = ("goniometer.cli",)


def simulator_key() -> str:
    """Key of the simulator's code: every source of ``goniometer`` but its CLI. It keys the numba
    cache directory and checkpoints, so no change to the physics, the stack packing or the
    assembly of results can reuse what older code compiled or traced."""
    return package_key(("goniometer",), exclude=SIMULATOR_APPLICATION)


@contextlib.contextmanager
def numba_cache_dir(key: str) -> Iterator[str]:
    """Within the block, functions decorated with ``numba.njit(cache=True)`` cache under the
    directory of ``key`` (numba fixes a function's cache location when it is decorated). Used by
    packages above the simulator whose compiled code depends on their own sources too."""
    previous = numba.config.CACHE_DIR
    path = _cache_base()[0] / key
    try:
        path.mkdir(parents=True, exist_ok=True)
        (path / ".last-used").touch()   # so that :func:`prune` sees it in use
    except OSError:
        pass
    numba.config.CACHE_DIR = str(path)
    try:
        yield str(path)
    finally:
        numba.config.CACHE_DIR = previous


#: cache directories (source versions) always kept
KEEP = 8
#: a directory beyond the KEEP most recent is removed once unused for this long (seconds)
STALE_S = 86400.0


def _last_used(d: Path) -> float:
    try:
        return (d / ".last-used").stat().st_mtime
    except OSError:
        try:
            return d.stat().st_mtime
        except OSError:
            return 0.0


def prune(base: Path, current: Path, keep: int = KEEP, stale_s: float = STALE_S) -> list[Path]:
    """Mark ``current`` as used now and remove the sibling cache directories under ``base`` that are
    neither among the ``keep`` most recently used nor used within ``stale_s`` seconds. Only
    directories named like a source key (16 hex digits) are considered; errors are ignored (another
    process may be pruning too). Returns the directories removed."""
    import shutil
    import time
    try:
        current.mkdir(parents=True, exist_ok=True)
        (current / ".last-used").touch()
        siblings = [d for d in base.iterdir() if d.is_dir() and d != current and len(d.name) == 16
                    and all(ch in "0123456789abcdef" for ch in d.name)]
    except OSError:
        return []
    siblings.sort(key=_last_used, reverse=True)
    now = time.time()
    removed = []
    for d in siblings[max(keep - 1, 0):]:
        if now - _last_used(d) > stale_s:
            shutil.rmtree(d, ignore_errors=True)
            removed.append(d)
    return removed


def _cache_base() -> tuple[Path, bool]:
    """The directory under which keyed numba caches live, and whether the user chose it."""
    user = os.environ.get("NUMBA_CACHE_DIR")
    return (Path(user), True) if user else (cache_root() / "numba", False)


def configure() -> str:
    """Point ``numba.config.CACHE_DIR`` at the simulator's keyed directory; returns it."""
    base, user = _cache_base()
    path = str(base / simulator_key())
    if not user:
        prune(base, Path(path))
    numba.config.CACHE_DIR = path
    return path
