"""pbrt-v4's layered BSDF (``coateddiffuse``/``coatedconductor``, Pharr, Jakob & Humphreys, PBR 4th ed.,
section 14.3; Guo et al. 2018) as stochastic model rows: ``pbrt-layered`` (pbrt's defaults),
``pbrt-layered-converged`` (its estimator with deep walks and many samples) and
``pbrt-layered-fixed`` (a control with the consistent MIS density). ``docs/pbrt-layered.md``.

Modules: ``kernel`` (the numba walk), ``model`` (the rows, the mapping of our stacks to pbrt's
parameters, integration with standard errors).
"""

from models.pbrt_layered.model import (G_CLAMP, STRUCTURE, Packed, PBRTLayered, PBRTLayeredConverged, PBRTLayeredFixed,
                                       PBRTParameters, built_in_models, pack, pbrt_parameters, support_reason)

__all__ = [
    # the rows
    "PBRTLayered", "PBRTLayeredConverged", "PBRTLayeredFixed", "built_in_models",
    # the mapping to pbrt's parameters
    "PBRTParameters", "pbrt_parameters", "support_reason", "pack", "Packed", "STRUCTURE", "G_CLAMP",
]
