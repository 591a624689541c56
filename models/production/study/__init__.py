"""The production-coat study (``gonio production``, ``make production``; ``docs/production.md``):
what OpenPBR's coat darkening and roughening should be, measured on simulated coats.

* :mod:`~models.production.study.effective`: the effective darkening and effective base roughness
  of a coated base, measured on its slices against its bare twin (sections 2-3);
* :mod:`~models.production.study.measure`: every coated material of a results directory, the
  reference's and belcour-fwd's (section 4);
* :mod:`~models.production.study.fitting_formulas`: the closed-form replacements, the held-out
  split and the fits (section 5);
* :mod:`~models.production.study.analysis`: samples, predictions, errors and the summary (sections 5-6).

The models of production coats themselves (OpenPBR, Standard Surface, Kulla-Conty, Mitsuba) are
:mod:`models.production`; the report that writes the study down is :mod:`models.report.production`.
"""

from models.production.study.analysis import (QUANTITIES, REFERENCE_SCATTERING, QuantityResult, Samples,
                                              build_samples, run_study, summary_document)
from models.production.study.effective import (CoatedBase, Darkening, ProductionError, Roughness, bare_key,
                                               coated_base, effective_darkening, effective_roughness)
from models.production.study.fitting_formulas import (DARKENING, ROUGHENING, SPLIT_SEED, Fit, Formula, fit_formula,
                                                      heldout_iors, is_heldout)
from models.production.study.measure import Measurement, measure_pair, measure_results, result_files

__all__ = [
    "ProductionError", "CoatedBase", "coated_base", "bare_key", "Darkening", "Roughness", "effective_darkening",
    "effective_roughness", "Measurement", "measure_pair", "measure_results", "result_files", "Formula", "Fit",
    "DARKENING", "ROUGHENING", "SPLIT_SEED", "fit_formula", "heldout_iors", "is_heldout", "Samples",
    "QuantityResult", "QUANTITIES", "REFERENCE_SCATTERING", "build_samples", "run_study", "summary_document",
]
