"""The comparison harness's building blocks: analytic models integrated onto the cells of a
simulated file (:func:`integrate`) and their errors against the reference (Bati 2019 eq. 4,
noise floors: :func:`compare`) and their directional albedo by a hemispherical quadrature
(:func:`directional_albedo`, ``docs/furnace.md``). Cell values and errors are defined in ``docs/slices-format.md``
and ``docs/models.md``. Choosing the models of a file and running them is :mod:`models.evaluation`,
above the model families (it asks the registry).
"""

from models.compare.albedo import HemisphereRule, directional_albedo, hemisphere_rule
from models.compare.errors import (LOW_COVERAGE, Coverage, NoCellsError, compare, coverage, error_object, noise_floor,
                                   mueller_errors, reference_parts, require_cells, rmse)
from models.compare.integrate import ModelSlices, MuellerSlices, integrate, integrate_mueller, integrate_slice

__all__ = [
    # integration
    "ModelSlices", "integrate", "integrate_slice",
    # polarized models on polarized files (docs/polarization.md)
    "MuellerSlices", "integrate_mueller", "mueller_errors",
    # errors
    "compare", "error_object", "rmse", "noise_floor", "reference_parts",
    # the support of an error (docs/models.md section 3)
    "Coverage", "coverage", "require_cells", "NoCellsError", "LOW_COVERAGE",
    # directional albedo (docs/furnace.md)
    "directional_albedo", "hemisphere_rule", "HemisphereRule",
]
