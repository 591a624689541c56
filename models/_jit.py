"""``njit`` for the model floor: like ``numba.njit``, but the on-disk cache of every function it
compiles lives under a directory keyed by the numba sources of ``goniometer`` and ``models``
(:func:`models_key`), so an edited optics or model function is never served from a stale cache
(``docs/architecture.md``, caches)."""

from __future__ import annotations

from functools import lru_cache
from typing import Any, Callable

import numba

from goniometer.cache import SIMULATOR_APPLICATION, numba_cache_dir, package_key

#: the application inside ``models``: its sources key the report, not compiled code
APPLICATION = ("models.commands", "models.report")


@lru_cache(maxsize=1)
def models_key() -> str:
    """Hash of the sources of ``goniometer`` and ``models``, the application of both excluded:
    keys the models' compiled functions and the report's cached evaluations."""
    return package_key(("goniometer", "models"), exclude=SIMULATOR_APPLICATION + APPLICATION)


def njit(*args: Any, **options: Any) -> Callable:
    """``numba.njit`` with the models' cache directory; use as ``@njit(cache=True, ...)``."""
    if args:
        raise TypeError("use njit with keyword options only, e.g. @njit(cache=True)")

    def decorate(fn: Callable) -> Callable:
        with numba_cache_dir(models_key()):
            return numba.njit(**options)(fn)

    return decorate
