"""goniometer: a Monte Carlo virtual goniometer for layered materials.

Stacks in (:mod:`goniometer.stack`), HDF5 BRDF/BTDF slices out (:mod:`goniometer.store`).
"""

__version__ = "0.1.0"
