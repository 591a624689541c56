"""Fitted compact BRDF models: Holzschuch & Pacanowski 2015 (``hp15-fit``) and one-/two-lobe GGX
baselines (``ggx1-fit``, ``ggx2-fit``), fitted by least squares to the BRDF slices of one simulated
file (:func:`fit`) so that their eq. 4 errors sit beside the physical models'. Families, the choices
where the paper is vague, the objective and the optimiser: ``docs/fitted.md``.

Modules: ``samples`` (direction samples by cell), ``family`` (parameter layout), ``hp15`` and
``ggx`` (the families), ``model`` (the fitted :class:`models.base.Model` classes), ``data`` (cells,
samples and weights of a fit), ``fitting`` (the driver).
"""

from models.fitted.data import GRAZING_RAD, PEAK_DEG, FitData, auto_peak_subcells, auto_subcells, fit_data
from models.fitted.family import Family, ParamSpec
from models.fitted.fitting import FitResult, fit
from models.fitted.ggx import GGXFamily
from models.fitted.hp15 import (WAVELENGTHS_UM, HP15Family, diffraction_norm, hp_d, hp_g1, hp_lambda,
                                hp_lambda_lookup, hp_lambda_table)
from models.fitted.model import FAMILIES, MODELS, FittedModel, GGX1Fit, GGX2Fit, HP15Fit, model_class
from models.fitted.samples import Samples

__all__ = [
    # fitting
    "fit", "FitResult", "fit_data", "FitData", "auto_subcells", "auto_peak_subcells", "GRAZING_RAD", "PEAK_DEG",
    # models
    "FittedModel", "HP15Fit", "GGX1Fit", "GGX2Fit", "MODELS", "model_class",
    # families
    "Family", "ParamSpec", "Samples", "FAMILIES", "GGXFamily", "HP15Family",
    # the HP15 distribution, shadowing and diffraction
    "WAVELENGTHS_UM", "hp_d", "hp_lambda", "hp_lambda_table", "hp_lambda_lookup", "hp_g1", "diffraction_norm",
]
