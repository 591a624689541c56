"""``standard-surface-coat``: Autodesk Standard Surface's coat over a metal or diffuse base.

Source: the node graph ``NG_standard_surface_surfaceshader_100`` of ``standard_surface.mtlx``
(MaterialX 1.39.5; nodedef version 1.0.1 inherits it). With coat weight C (input ``coat``)::

    f = C f_coat + (1 + C (coat_color - 1)) (1 - C E_coat(v)) f_base(alpha_b')

* ``f_coat``: GGX dielectric reflection (``dielectric_bsdf`` in mode R) of
  ``alpha = coat_roughness**2`` (node ``roughness_anisotropy``) and ``coat_IOR``; ``E_coat(v)``
  its directional albedo (the ``layer`` node's albedo scaling; our quadrature).
* The coat's absorption is the constant ``coat_color`` (node ``coat_attenuation``): no path
  length, no darkening by internal reflections.
* ``alpha_b' = r'**2`` with ``r' = mix(specular_roughness, 1, coat_affect_roughness * coat *
  coat_roughness)`` (node ``coat_affected_roughness``; the default ``coat_affect_roughness = 0``
  leaves the base roughness alone).
* ``f_base``: GGX conductor (``conductor_bsdf``) with the exact Fresnel of the complex index of
  Gulbrandsen's ``artistic_ior(base * base_color, specular * specular_color)``, or the diffuse
  ``base * base_color**(1 + coat * coat_affect_color) / pi`` (Oren-Nayar of roughness 0).

How our stacks set these inputs (:data:`COAT_INPUTS`, :data:`BASE_INPUTS`,
:func:`standard_surface_parameters`): ``docs/production-models.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from goniometer.stack import Stack
from models.base import Model, ModelError, ModelValue
from models.production.fresnel import artistic_from_ior, artistic_ior
from models.production.layering import (ABSORB_CONSTANT, BASE_CONDUCTOR, BASE_LAMBERTIAN, CoatLayering,
                                        evaluate_layering)
from models.production.stacks import coat_reason, coat_structure

RGB = tuple[float, float, float]

#: reflectivity above which MaterialX's artistic_ior clamps (the metal would not be represented)
MAX_REFLECTIVITY = 0.99

#: every coat input of the Standard Surface node definition -> how a stack sets it (tested against the .mtlx)
COAT_INPUTS: dict[str, str] = {
    "coat": "1 (the stack has a coat); 0 gives the bare base",
    "coat_color": "exp(-2 tau): the normal-incidence round-trip transmittance of the coat medium (1 without medium)",
    "coat_roughness": "sqrt(alpha0) of the coat interface (alpha = roughness**2)",
    "coat_anisotropy": "0 (anisotropic coats are refused)",
    "coat_rotation": "0 (isotropic)",
    "coat_IOR": "the coat interface's ior (relative to air above)",
    "coat_normal": "the macro normal +z",
    "coat_affect_color": "0 (the default)",
    "coat_affect_roughness": "0 (the default)",
}

#: the base inputs of the Standard Surface node definition a stack sets
BASE_INPUTS: dict[str, str] = {
    "base": "1",
    "base_color": "metal: reflectivity r = F(0 deg) of the conductor in air; diffuse: the Lambertian albedo",
    "metalness": "1 for a conductor base, 0 for a Lambertian base",
    "diffuse_roughness": "0 (Lambertian)",
    "specular": "1 for a metal (its edge colour is specular * specular_color); 0 for a Lambertian base",
    "specular_color": "metal: Gulbrandsen's edge colour g of the conductor in air, so artistic_ior gives its (n, k) back",
    "specular_roughness": "sqrt(alpha1) of the conductor interface",
    "specular_anisotropy": "0 (anisotropic bases are refused)",
    "transmission": "0",
    "subsurface": "0",
    "sheen": "0",
    "thin_film_thickness": "0",
}


@dataclass(frozen=True)
class StandardSurfaceParameters:
    """The Standard Surface inputs that matter for a coat over a metal or diffuse base (names and
    meanings as in ``standard_surface.mtlx``; ``alpha = roughness**2``)."""

    coat: float = 1.0
    coat_color: RGB = (1.0, 1.0, 1.0)
    coat_roughness: float = 0.1
    coat_anisotropy: float = 0.0
    coat_rotation: float = 0.0
    coat_IOR: float = 1.5
    coat_affect_color: float = 0.0
    coat_affect_roughness: float = 0.0
    base: float = 1.0
    base_color: RGB = (0.8, 0.8, 0.8)
    diffuse_roughness: float = 0.0
    metalness: float = 0.0
    specular: float = 1.0
    specular_color: RGB = (1.0, 1.0, 1.0)
    specular_roughness: float = 0.2
    specular_anisotropy: float = 0.0


def metal_reason(stack: Stack) -> str | None:
    """Why the conductor base of ``stack`` has no artistic-IOR parameters (None if it has)."""
    cb = coat_structure(stack)
    if cb.base != "conductor":
        return None
    r, _ = artistic_from_ior(cb.eta1, cb.kappa1)
    if float(np.max(r)) > MAX_REFLECTIVITY:
        return (f"conductor reflectivity F(0) = {float(np.max(r)):.4f} above {MAX_REFLECTIVITY}, "
                "where Standard Surface's artistic_ior clamps")
    return None


def standard_surface_parameters(stack: Stack) -> StandardSurfaceParameters:
    """The Standard Surface inputs of a supported stack (mapping of :data:`COAT_INPUTS`, :data:`BASE_INPUTS`)."""
    cb = coat_structure(stack)
    coat = dict(coat=1.0, coat_color=tuple(np.exp(-2.0 * np.asarray(cb.tau, dtype=float)).tolist()),
                coat_roughness=math.sqrt(cb.alpha0), coat_IOR=float(cb.eta0))
    if cb.base == "conductor":
        r, g = artistic_from_ior(cb.eta1, cb.kappa1)
        return StandardSurfaceParameters(**coat, base=1.0, base_color=tuple(r.tolist()), metalness=1.0,
                                         specular=1.0, specular_color=tuple(g.tolist()),
                                         specular_roughness=math.sqrt(float(cb.alpha1)))
    return StandardSurfaceParameters(**coat, base=1.0, base_color=tuple(float(x) for x in cb.rho), metalness=0.0,
                                     specular=0.0, specular_roughness=0.0)


def coat_affected_roughness(specular_roughness, coat_roughness, coat: float = 1.0,
                            coat_affect_roughness: float = 1.0):
    """Standard Surface's base roughness under a coat (node ``coat_affected_roughness``):
    ``mix(specular_roughness, 1, coat_affect_roughness * coat * coat_roughness)``, perceptual
    roughness (``alpha = r**2``); scalars or arrays."""
    return specular_roughness + coat_affect_roughness * coat * coat_roughness * (1.0 - specular_roughness)


def coat_affected_color(base_color, coat: float = 1.0, coat_affect_color: float = 1.0):
    """Standard Surface's diffuse base colour under a coat: ``base_color ** (1 + coat *
    coat_affect_color)`` (``coat`` clamped to [0, 1]; negative colours as 0), i.e. the base darkened
    by the factor ``base_color ** (coat * coat_affect_color)``."""
    return np.maximum(base_color, 0.0) ** (1.0 + min(max(coat, 0.0), 1.0) * coat_affect_color)


def standard_surface_layering(p: StandardSurfaceParameters, height_correlated: bool = True) -> CoatLayering:
    """Resolve ``p`` into the albedo-scaling coat. Raises :class:`ModelError` for inputs this
    evaluation does not cover: anisotropy, fractional metalness, a dielectric specular lobe on a
    diffuse base, diffuse roughness."""
    if p.coat_anisotropy != 0.0 or p.specular_anisotropy != 0.0:
        raise ModelError("standard-surface-coat: anisotropic roughness is not supported")
    if p.metalness not in (0.0, 1.0):
        raise ModelError(f"standard-surface-coat: metalness must be 0 or 1, got {p.metalness}")
    zeros = np.zeros(3)
    color = np.asarray(p.base_color, dtype=float)
    if p.metalness == 1.0:
        r_b = coat_affected_roughness(p.specular_roughness, p.coat_roughness, p.coat, p.coat_affect_roughness)
        n, k = artistic_ior(p.base * color, p.specular * np.asarray(p.specular_color, dtype=float))
        kind = dict(base_kind=BASE_CONDUCTOR, rho=zeros, base_alpha=r_b * r_b, eta=n, kappa=k)
    else:
        if p.specular != 0.0:
            raise ModelError("standard-surface-coat: a diffuse base needs specular 0 (no dielectric specular lobe)")
        if p.diffuse_roughness != 0.0:
            raise ModelError("standard-surface-coat: diffuse_roughness must be 0 (Lambertian)")
        rho = p.base * coat_affected_color(color, p.coat, p.coat_affect_color)
        kind = dict(base_kind=BASE_LAMBERTIAN, rho=rho, base_alpha=0.0, eta=np.ones(3), kappa=zeros)
    return CoatLayering(coat_weight=float(p.coat), coat_alpha=float(p.coat_roughness) ** 2, coat_ior=float(p.coat_IOR),
                        coat_color=np.asarray(p.coat_color, dtype=float), absorption=ABSORB_CONSTANT,
                        base_scale=np.ones(3), f0=zeros, tint=zeros, specular_weight=0.0,
                        height_correlated=bool(height_correlated), **kind)


def evaluate_standard_surface(p: StandardSurfaceParameters, l: np.ndarray, v: np.ndarray,
                              height_correlated: bool = True) -> ModelValue:
    """Standard Surface's coated BRDF for lights ``l`` and viewers ``v`` (broadcast, (..., 3), unit,
    pointing away from the surface): ``top`` the coat lobe (repeated on RGB), ``internal`` the
    rest; 1/sr, no cosine."""
    top, internal = evaluate_layering(standard_surface_layering(p, height_correlated), l, v)
    return ModelValue(top=np.repeat(top[..., None], 3, axis=-1), internal=internal)


class StandardSurfaceCoat(Model):
    """Autodesk Standard Surface's coat (see the module docstring for the formula and its source).

    ``height_correlated``: Smith masking of the coat and metal lobes (MaterialX: height-correlated).
    """

    name = "standard-surface-coat"
    description = ("Autodesk Standard Surface coat (node graph of MaterialX 1.39.5): albedo scaling, constant "
                   "coat colour, artistic-IOR metal; one coat over a conductor or Lambertian base")
    sides = ("brdf",)
    #: GGX, Fresnel and albedo tables of l, v and h only (Model.mirror_symmetric)
    mirror_symmetric = True

    def __init__(self, height_correlated: bool = True) -> None:
        self.height_correlated = bool(height_correlated)

    def support_reason(self, stack: Stack) -> str | None:
        return coat_reason(stack) or metal_reason(stack)

    def _evaluate(self, stack: Stack, l: np.ndarray, v: np.ndarray, side: str) -> ModelValue:
        return evaluate_standard_surface(standard_surface_parameters(stack), l, v, self.height_correlated)
