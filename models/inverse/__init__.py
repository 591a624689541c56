"""The inverse method of Bati, Pacanowski and Barla 2021: BRDF lobes at normal incidence -> layered materials.

Users describe the lobes they want -- energy ``R_k`` (RGB) and variance ``sigma_k`` of each lobe,
top lobe first, 1 or 2 interfaces each -- and get physical layer stacks that produce them under
Belcour's forward model (:mod:`models.belcour.model`), with the equivalence classes (the stacks
giving the same lobes) to explore. ``docs/inverse.md`` states the method as implemented: the
paper's equations by number, the classes, the free choices and their defaults, the options and
the validation.

Modules: :mod:`~models.inverse.lobes` (inputs: :class:`Lobe`, :class:`Pick`,
:class:`InverseOptions`, errors), :mod:`~models.inverse.equations` (eqs. 1-19),
:mod:`~models.inverse.kernels` (compiled FGD at normal incidence and adding),
:mod:`~models.inverse.context` (alg. 3), :mod:`~models.inverse.classes`,
:mod:`~models.inverse.one_layer` (section 5.1), :mod:`~models.inverse.two_layer` (section 5.2),
:mod:`~models.inverse.solver` (alg. 2: :func:`solve`, :func:`invert`), and the validation:
:mod:`~models.inverse.validation`, :mod:`~models.inverse.estimate`; from a measured BRDF:
:mod:`~models.inverse.measured` (:func:`invert_measured`, :func:`simulate_against`). Reports and figures of the
method are the application's (:mod:`models.report.inverse`).
"""

from models.inverse.classes import Layer, LobeClass, LobeSolution, inherent_variance_spread
from models.inverse.context import Context, SubLobe
from models.inverse.equations import (CONDUCTOR_R_MIN, conductor_eta_bounds, eq1_reflectance, eq2_adding, eq7_roots,
                                      eq8_kappa, eq9_eta_max, eq10_eta_min, eq11_inverse_adding, eq13_tau,
                                      eq15_sigma_r12, eq17_energy, eq18_r_prime, eq19_sigma_r, eta_sigma_max)
from models.inverse.estimate import (SEPARABLE_RATIO, SIGMA_RES, LobeFit, RingData, estimate_lobes, fit_lobes,
                                     fit_ring_lobes, lobe_albedo, lobe_groups, lobe_ring_fractions, ring_data)
from models.inverse.kernels import albedo_normal, fgd_for, fgd_normal, kernel_for
from models.inverse.lobes import (ETA_MAX_DEFAULT, PICK_FIELDS, InverseError, InverseOptions, Interval, Lobe,
                                  NotAchievable, Pick, PickError, jsonable, parse_lobe, parse_picks)
from models.inverse.measured import (MeasuredFit, MeasuredInversion, MeasuredRings, fit_measured_lobes,
                                     invert_measured, measured_rings, normal_reference, simulate_against)
from models.inverse.one_layer import (ConductorClass, OneLayerDielectricClass, conductor_class, conductor_point,
                                      one_layer_dielectric_class)
from models.inverse.solver import (FIG17_LOBES, Inversion, bench_invert, equivalence_classes, invert, layers_to_stack,
                                   lobe_class, solve)
from models.inverse.two_layer import TwoLayerClass, TwoLayerPoint, two_layer_class, two_layer_energy_max
from models.inverse.validation import (DEFAULT_RAYS, DEFAULT_RESOLUTION, FORWARD_RTOL, Case, CaseResult, LobeCheck,
                                       forward_check, forward_lobes, inversion_json, load_cases, run_case,
                                       run_validation, simulate_case, validation_json)

__all__ = [
    # inputs and errors
    "Lobe", "parse_lobe", "Pick", "parse_picks", "PICK_FIELDS", "InverseOptions", "ETA_MAX_DEFAULT",
    "InverseError", "NotAchievable", "PickError", "Interval", "jsonable",
    # the method (alg. 2)
    "solve", "invert", "equivalence_classes", "Inversion", "layers_to_stack", "lobe_class",
    "bench_invert", "FIG17_LOBES",
    # classes and their points
    "Context", "SubLobe", "Layer", "LobeClass", "LobeSolution", "inherent_variance_spread",
    "OneLayerDielectricClass", "one_layer_dielectric_class", "ConductorClass", "conductor_class", "conductor_point",
    "TwoLayerClass", "TwoLayerPoint", "two_layer_class", "two_layer_energy_max",
    # the paper's equations
    "eq1_reflectance", "eq2_adding", "eq7_roots", "eq8_kappa", "eq9_eta_max", "eq10_eta_min",
    "conductor_eta_bounds", "CONDUCTOR_R_MIN", "eq11_inverse_adding", "eq13_tau", "eq15_sigma_r12",
    "eq17_energy", "eq18_r_prime", "eq19_sigma_r", "eta_sigma_max",
    # FGD at normal incidence
    "kernel_for", "fgd_normal", "albedo_normal", "fgd_for",
    # validation
    "Case", "load_cases", "LobeCheck", "forward_lobes", "forward_check", "inversion_json", "simulate_case",
    "CaseResult", "run_case", "run_validation", "validation_json", "FORWARD_RTOL", "DEFAULT_RAYS",
    "DEFAULT_RESOLUTION",
    # lobe estimator
    "RingData", "ring_data", "LobeFit", "fit_lobes", "lobe_ring_fractions", "lobe_albedo", "lobe_groups",
    "estimate_lobes", "SEPARABLE_RATIO", "SIGMA_RES", "fit_ring_lobes",
    # from a measurement
    "normal_reference", "MeasuredRings", "measured_rings", "MeasuredFit", "fit_measured_lobes", "MeasuredInversion",
    "invert_measured", "simulate_against",
]
