"""The comparison harness: analytic models integrated onto the cells of a simulated file
(:func:`integrate`), their errors against the reference (Bati 2019 eq. 4, noise floors:
:func:`compare`) and the evaluation of every model on a file (:func:`evaluate`, with saved model
slices). Cell values and errors are defined in ``docs/slices-format.md``; which side a stack is
judged on and what "internal" means: :mod:`models.compare.evaluate`.
"""

from models.compare.errors import compare, error_object, noise_floor, reference_parts, rmse
from models.compare.evaluate import (ISOTROPIZE, MODEL_SLICES_FORMAT, Evaluation, comparison_side, evaluate,
                                     isotropized, read_slices, save_slices)
from models.compare.integrate import ModelSlices, integrate, integrate_slice

__all__ = [
    # integration
    "ModelSlices", "integrate", "integrate_slice",
    # errors
    "compare", "error_object", "rmse", "noise_floor", "reference_parts",
    # evaluation
    "Evaluation", "evaluate", "comparison_side", "isotropized", "ISOTROPIZE", "save_slices", "read_slices",
    "MODEL_SLICES_FORMAT",
]
