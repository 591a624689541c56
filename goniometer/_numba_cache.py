"""Keep numba's on-disk cache consistent with the sources it was compiled from.

numba's ``cache=True`` keys a cached function on the source file that defines it only: a kernel
in ``tracer.py`` that inlines ``optics.fresnel_conductor`` keeps using the old, cached physics
after ``optics.py`` changes. To make that impossible, the cache directory is keyed by a hash of
every source file of the ``goniometer`` and ``models`` packages (and the numba version): any
change to any of them starts a fresh cache.

Location: ``$NUMBA_CACHE_DIR/<key>`` if the user set ``NUMBA_CACHE_DIR``, else
``$GONIOMETER_CACHE/numba/<key>`` (default ``~/.cache/goniometer/numba/<key>``).
Called once from ``goniometer/__init__.py``, before any function is compiled.

Old caches: every source change starts a new directory, so under the default location (not under
a user's ``NUMBA_CACHE_DIR``) :func:`configure` marks the directory it uses (``.last-used``) and
removes sibling directories beyond the :data:`KEEP` most recently used that have not been used for
:data:`STALE_S` seconds.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numba


def cache_root() -> Path:
    """The project's cache directory (tables, compiled kernels): ``$GONIOMETER_CACHE`` or
    ``~/.cache/goniometer``."""
    env = os.environ.get("GONIOMETER_CACHE")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "goniometer"


def source_key() -> str:
    """Hash of the project's numba-bearing Python sources (files that mention numba) and the
    numba version. Compiled code can only depend on njit functions and the constants they read,
    which live in such files; editing a report or CLI module does not invalidate the cache."""
    root = Path(__file__).resolve().parent.parent
    h = hashlib.sha256(numba.__version__.encode())
    for pkg in ("goniometer", "models"):
        for p in sorted((root / pkg).rglob("*.py")):
            data = p.read_bytes()
            if b"numba" not in data:
                continue
            h.update(p.relative_to(root).as_posix().encode())
            h.update(data)
    return h.hexdigest()[:16]


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


def configure() -> str:
    """Point ``numba.config.CACHE_DIR`` at the source-keyed directory; returns it."""
    user = os.environ.get("NUMBA_CACHE_DIR")
    base = Path(user) if user else cache_root() / "numba"
    path = str(base / source_key())
    if not user:
        prune(base, Path(path))
    numba.config.CACHE_DIR = path
    return path
