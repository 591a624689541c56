"""Production coat models in the harness (issue 13): the coats renderers ship, judged on our stacks.

Formulas, sources and how our stacks map onto each model's inputs: ``docs/production-models.md``.
"""

# --- GGX interface with Kulla-Conty / Turquin energy compensation, and Mitsuba 3's own BSDFs (kulla_conty, mitsuba)
from models.production.kulla_conty import (GGXKullaConty, KullaContyOptions, DielectricSplit, conductor_fresnel_term,
                                           dielectric_split)
from models.production.mitsuba import MitsubaBSDF, MitsubaPrincipled, MitsubaRoughPlastic, mitsuba_variant

__all__ = [
    # --- GGX interface with Kulla-Conty / Turquin energy compensation, and Mitsuba 3's own BSDFs
    "GGXKullaConty", "KullaContyOptions", "DielectricSplit", "conductor_fresnel_term", "dielectric_split",
    "MitsubaBSDF", "MitsubaRoughPlastic", "MitsubaPrincipled", "mitsuba_variant",
]
