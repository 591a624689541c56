"""Keep numba's on-disk cache consistent with the sources it was compiled from.

numba's ``cache=True`` keys a cached function on the source file that defines it only: a kernel
in ``tracer.py`` that inlines ``optics.fresnel_conductor`` keeps using the old, cached physics
after ``optics.py`` changes. To make that impossible, the cache directory is keyed by a hash of
every source file of the ``goniometer`` and ``models`` packages (and the numba version): any
change to any of them starts a fresh cache.

Location: ``$NUMBA_CACHE_DIR/<key>`` if the user set ``NUMBA_CACHE_DIR``, else
``$GONIOMETER_CACHE/numba/<key>`` (default ``~/.cache/goniometer/numba/<key>``).
Called once from ``goniometer/__init__.py``, before any function is compiled.
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


def configure() -> str:
    """Point ``numba.config.CACHE_DIR`` at the source-keyed directory; returns it."""
    user = os.environ.get("NUMBA_CACHE_DIR")
    base = Path(user) if user else cache_root() / "numba"
    path = str(base / source_key())
    numba.config.CACHE_DIR = path
    return path
