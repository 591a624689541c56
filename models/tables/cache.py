"""Cached table files of the analytic models (:mod:`models.tables.belcour`, :mod:`models.tables.multilayer`).

A table file is an ``.npz`` in the project's cache directory (:func:`default_cache_dir`:
``$GONIOMETER_CACHE`` if set, else ``~/.cache/goniometer``) holding the arrays of one build plus
``version`` (an int64 stamp the owning module bumps whenever a table's definition, numerics or
layout changes) and ``signature`` (a string describing the grid). Files are written atomically
(:func:`save_atomic`: temporary file in the same directory, then rename), read only when both
stamps match (:func:`read_current`), and rebuilt, never reused, otherwise (:func:`load_or_build`).
What a table contains, its file name, version and signature stay with the owning module; this
module only handles the files.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Callable, TypeVar

import numpy as np

from goniometer import atomic
from goniometer.cache import cache_root

T = TypeVar("T")


def default_cache_dir() -> Path:
    """The project's cache directory (:func:`goniometer.cache.cache_root`):
    ``$GONIOMETER_CACHE`` if set, else ``~/.cache/goniometer`` (under ``$XDG_CACHE_HOME`` if set)."""
    return cache_root().expanduser()


def cache_directory(cache_dir: str | os.PathLike | None = None) -> Path:
    """``cache_dir`` (user-expanded) or, if None, :func:`default_cache_dir`."""
    return Path(cache_dir).expanduser() if cache_dir is not None else default_cache_dir()


def memo_key(cache_dir: str | os.PathLike | None = None) -> str:
    """The resolved :func:`cache_directory` as a string: the key of the loaders' in-process memos."""
    return str(cache_directory(cache_dir).resolve())


#: ``np.savez(path, **arrays)`` through a temporary file and a rename (readers never see a partial
#: file; the temporary file is removed on failure): :func:`goniometer.atomic.write_npz`
save_atomic = atomic.write_npz


def read_current(path: Path, version: int, signature: str, keys: tuple[str, ...],
                 dtype: type | None = None) -> dict[str, np.ndarray] | None:
    """The arrays ``keys`` of the table file ``path`` (copied, as ``dtype`` if given) if it exists
    and carries this ``version`` and ``signature``; None if it is missing, stale, unreadable or
    lacks a key."""
    if not path.exists():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            if int(z["version"]) != version or str(z["signature"]) != signature:
                return None
            return {k: np.array(z[k], dtype=dtype) for k in keys}
    except (OSError, KeyError, ValueError):
        return None


def load_or_build(read: Callable[[], T | None], build: Callable[[], object], what: str) -> T:
    """``read()``; if that gives None (no current table), ``build()`` then ``read()`` again.
    Raises OSError naming ``what`` if the rebuilt table still cannot be read."""
    got = read()
    if got is None:
        build()
        got = read()
        if got is None:  # pragma: no cover - disk trouble
            raise OSError(f"could not write or read {what}")
    return got
