"""goniometer: a Monte Carlo virtual goniometer for layered materials.

Stacks in (:mod:`goniometer.stack`), HDF5 BRDF/BTDF slices out (:mod:`goniometer.store`).
"""

from goniometer import _numba_cache

__version__ = "0.1.0"

#: where numba caches compiled kernels (keyed by a hash of the sources; see _numba_cache)
NUMBA_CACHE_DIR = _numba_cache.configure()
