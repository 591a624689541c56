"""Production coat models in the harness (issue 13): the coats renderers ship, judged on our stacks.

Formulas, sources and how our stacks map onto each model's inputs: ``docs/production-models.md``.
The study of what their coat formulas should be (``gonio production``, ``docs/production.md``) is
the subpackage :mod:`models.production.study`.
"""

# --- OpenPBR and Autodesk Standard Surface coats (openpbr, fresnel, layering, openpbr_coat, standard_surface)
from models.production.openpbr import (alpha_from_roughness, coat_darkening, coat_darkening_spec,
                                       coat_internal_reflection, coat_roughening, coat_roughening_pr261,
                                       roughness_from_alpha)
from models.production.openpbr_coat import OpenPBRCoat, OpenPBRParameters, evaluate_openpbr, openpbr_parameters
from models.production.standard_surface import (StandardSurfaceCoat, StandardSurfaceParameters,
                                                evaluate_standard_surface, standard_surface_parameters)

# --- GGX interface with Kulla-Conty / Turquin energy compensation, and Mitsuba 3's own BSDFs (kulla_conty, mitsuba)
from models.production.kulla_conty import (GGXKullaConty, KullaContyOptions, DielectricSplit, conductor_fresnel_term,
                                           dielectric_split)
from models.production.mitsuba import MitsubaBSDF, MitsubaPrincipled, MitsubaRoughPlastic, mitsuba_variant

__all__ = [
    # --- OpenPBR and Autodesk Standard Surface coats
    "coat_darkening", "coat_roughening", "coat_darkening_spec", "coat_roughening_pr261", "coat_internal_reflection", "alpha_from_roughness",
    "roughness_from_alpha", "OpenPBRCoat", "OpenPBRParameters", "evaluate_openpbr", "openpbr_parameters",
    "StandardSurfaceCoat", "StandardSurfaceParameters", "evaluate_standard_surface",
    "standard_surface_parameters",
    # --- GGX interface with Kulla-Conty / Turquin energy compensation, and Mitsuba 3's own BSDFs
    "GGXKullaConty", "KullaContyOptions", "DielectricSplit", "conductor_fresnel_term", "dielectric_split",
    "MitsubaBSDF", "MitsubaRoughPlastic", "MitsubaPrincipled", "mitsuba_variant",
]
