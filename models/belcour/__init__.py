"""Belcour 2018's layered BSDF: GGX lobes whose energies and roughnesses come from an adding-doubling
of per-lobe statistics through the stack, and its anisotropic extension (Yamaguchi et al. 2019).

Models: ``belcour-fwd`` (:class:`BelcourForward`), ``belcour-sym`` (:class:`BelcourSymmetric`),
``belcour-bati19`` (:class:`BelcourBati19`), ``belcour-btdf`` (:class:`BelcourBTDF`) and
``belcour-aniso`` (:class:`BelcourAniso`); the statistics themselves (:func:`stack_statistics`,
:func:`lobe_statistics`, :func:`aniso_statistics`) for the inverse method. Conventions, equations
and choices: ``docs/belcour.md``.

Modules: ``options`` (switches), ``covariance`` (roughness <-> variance, 2 x 2 covariances),
``packing`` (a stack as kernel arrays), ``adding`` (the adding-doubling kernel), ``lobes`` (lobe
evaluation kernels), ``statistics``, ``model`` (the isotropic models), ``aniso``.
"""

from models.belcour.adding import AddingDoubling, run_adding_doubling
from models.belcour.aniso import (AZIMUTH_GRID, AnisoLobe, AnisoOptions, AnisoStatistics, BelcourAniso,
                                  aniso_statistics, isotropic_proxy, pack_aniso)
from models.belcour.covariance import (blended_alpha, interface_covariance, lookup_alpha, principal,
                                       roughness_to_variance, variance_to_roughness)
from models.belcour.model import BelcourBati19, BelcourBTDF, BelcourForward, BelcourModel, BelcourSymmetric
from models.belcour.options import DIRECTION_GRID, BelcourOptions
from models.belcour.packing import (G_MIN, BelcourPackedStack, forward_scattering_variance, pack_stack,
                                    unsupported_reason)
from models.belcour.statistics import BelcourLobe, StackStatistics, lobe_statistics, stack_statistics

__all__ = [
    # models
    "BelcourModel", "BelcourForward", "BelcourSymmetric", "BelcourBati19", "BelcourBTDF", "BelcourAniso",
    # options
    "BelcourOptions", "AnisoOptions", "DIRECTION_GRID", "AZIMUTH_GRID",
    # statistics
    "BelcourLobe", "StackStatistics", "stack_statistics", "lobe_statistics",
    "AnisoLobe", "AnisoStatistics", "aniso_statistics",
    # stacks and the kernel
    "BelcourPackedStack", "pack_stack", "pack_aniso", "unsupported_reason", "isotropic_proxy",
    "G_MIN", "forward_scattering_variance",
    "AddingDoubling", "run_adding_doubling",
    # roughness, variance and covariance
    "roughness_to_variance", "variance_to_roughness", "interface_covariance", "principal", "blended_alpha",
    "lookup_alpha",
]
