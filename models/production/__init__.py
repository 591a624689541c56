"""Production coat models in the harness (issue 13): the coats renderers ship, judged on our stacks.

Formulas and mappings: ``docs/production-models.md``.
"""

from models.production.openpbr import (alpha_from_roughness, coat_darkening, coat_internal_reflection,
                                       coat_roughening, roughness_from_alpha)

__all__ = [
    # OpenPBR's coat formulas (models.production.openpbr)
    "coat_darkening", "coat_roughening", "coat_internal_reflection", "alpha_from_roughness",
    "roughness_from_alpha",
]
