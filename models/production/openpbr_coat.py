"""``openpbr-coat``: OpenPBR Surface 1.1's coat over a metal or diffuse base.

Source: the node graph ``NG_open_pbr_surface_surfaceshader`` of ``open_pbr_surface.mtlx``
(MaterialX 1.39.5, nodedef version 1.1.1) read with the specification v1.1, sections "Layering"
(albedo scaling), "Metal" (F82-tint), "Coat" (darkening, view-dependent absorption,
roughening) and "Microfacet model" (``alpha = roughness**2``). With coat weight C::

    f = C f_coat + A (1 - C E_coat(v)) Delta f_base(alpha_b')

* ``f_coat``: GGX dielectric reflection of ``alpha = coat_roughness**2`` and ``coat_ior``;
  ``E_coat(v)`` its directional albedo (our quadrature, :mod:`models.production.layering`).
* ``A = 1 + C (T - 1)``, ``T = coat_color ** ((1/mu_l' + 1/mu_v') / 2)`` along the refracted
  directions (spec, "View-dependent absorption"; the node graph itself multiplies by the
  constant ``coat_color``, its normal-incidence value).
* ``Delta``: :func:`models.production.openpbr.coat_darkening` with the node graph's albedo
  estimate (``base_color * specular_weight`` for a metal, ``base_color`` for a diffuse base).
* ``alpha_b' = r_b'**2`` with ``r_b'`` = :func:`models.production.openpbr.coat_roughening`.
* ``f_base``: GGX metal with F82-tint Fresnel (``base_color``, ``specular_color``,
  ``specular_weight``), or the diffuse ``base_weight * base_color / pi`` (Oren-Nayar of roughness 0).

How our stacks set these inputs (:data:`COAT_INPUTS`, :data:`BASE_INPUTS`,
:func:`openpbr_parameters`): ``docs/production-models.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from goniometer.stack import Stack
from models.base import Model, ModelError, ModelValue
from models.production.fresnel import f82_tint_from_ior
from models.production.layering import (ABSORB_REFRACTED, BASE_F82, BASE_LAMBERTIAN, CoatLayering,
                                        evaluate_layering)
from models.production.openpbr import alpha_from_roughness, coat_darkening, coat_roughening
from models.production.stacks import coat_reason, coat_structure

RGB = tuple[float, float, float]

#: every coat input of the OpenPBR node definition -> how a stack sets it (tested against the .mtlx)
COAT_INPUTS: dict[str, str] = {
    "coat_weight": "1 (the stack has a coat); 0 gives the bare base",
    "coat_color": "exp(-2 tau): the normal-incidence round-trip transmittance of the coat medium (1 without medium)",
    "coat_roughness": "sqrt(alpha0) of the coat interface (alpha = roughness**2)",
    "coat_roughness_anisotropy": "0 (anisotropic coats are refused)",
    "coat_ior": "the coat interface's ior (relative to air above)",
    "coat_darkening": "1 (the physical darkening)",
    "geometry_coat_normal": "the macro normal +z",
    "geometry_coat_tangent": "the macro x axis (irrelevant: isotropic)",
}

#: the base inputs of the OpenPBR node definition a stack sets (the others keep their defaults
#: or are irrelevant with base_metalness 0 or 1, transmission_weight = subsurface_weight = 0)
BASE_INPUTS: dict[str, str] = {
    "base_weight": "1",
    "base_color": "metal: F(0 deg) of the conductor in air; diffuse: the Lambertian albedo",
    "base_metalness": "1 for a conductor base, 0 for a Lambertian base",
    "base_diffuse_roughness": "0 (Lambertian)",
    "specular_weight": "1 for a metal; 0 for a Lambertian base (no dielectric specular interface)",
    "specular_color": "metal: F(mu = 1/7) / Schlick(1/7) of the conductor in air (F82-tint)",
    "specular_roughness": "sqrt(alpha1) of the conductor interface",
    "specular_roughness_anisotropy": "0 (anisotropic bases are refused)",
    "transmission_weight": "0",
    "subsurface_weight": "0",
    "fuzz_weight": "0",
    "thin_film_weight": "0",
}


@dataclass(frozen=True)
class OpenPBRParameters:
    """The OpenPBR Surface inputs that matter for a coat over a metal or diffuse base (names and
    meanings as in ``open_pbr_surface.mtlx``; roughnesses are OpenPBR's, ``alpha = r**2``)."""

    coat_weight: float = 1.0
    coat_color: RGB = (1.0, 1.0, 1.0)
    coat_roughness: float = 0.0
    coat_roughness_anisotropy: float = 0.0
    coat_ior: float = 1.6
    coat_darkening: float = 1.0
    base_weight: float = 1.0
    base_color: RGB = (0.8, 0.8, 0.8)
    base_metalness: float = 0.0
    base_diffuse_roughness: float = 0.0
    specular_weight: float = 1.0
    specular_color: RGB = (1.0, 1.0, 1.0)
    specular_roughness: float = 0.3
    specular_roughness_anisotropy: float = 0.0


def openpbr_parameters(stack: Stack) -> OpenPBRParameters:
    """The OpenPBR inputs of a supported stack (mapping of :data:`COAT_INPUTS`, :data:`BASE_INPUTS`)."""
    cb = coat_structure(stack)
    coat = dict(coat_weight=1.0, coat_color=tuple(np.exp(-2.0 * np.asarray(cb.tau, dtype=float)).tolist()),
                coat_roughness=math.sqrt(cb.alpha0), coat_ior=float(cb.eta0), coat_darkening=1.0)
    if cb.base == "conductor":
        f0, tint = f82_tint_from_ior(cb.eta1, cb.kappa1)
        return OpenPBRParameters(**coat, base_weight=1.0, base_color=tuple(f0.tolist()), base_metalness=1.0,
                                 specular_weight=1.0, specular_color=tuple(tint.tolist()),
                                 specular_roughness=math.sqrt(float(cb.alpha1)))
    return OpenPBRParameters(**coat, base_weight=1.0, base_color=tuple(float(x) for x in cb.rho),
                             base_metalness=0.0, base_diffuse_roughness=0.0, specular_weight=0.0,
                             specular_roughness=0.0)


def openpbr_layering(p: OpenPBRParameters, height_correlated: bool = True) -> CoatLayering:
    """Resolve ``p`` into the albedo-scaling coat (darkening, roughening, F82-tint metal).

    Raises :class:`ModelError` for inputs this evaluation does not cover: anisotropy, a
    fractional ``base_metalness``, a dielectric specular lobe on a diffuse base, diffuse roughness."""
    if p.coat_roughness_anisotropy != 0.0 or p.specular_roughness_anisotropy != 0.0:
        raise ModelError("openpbr-coat: anisotropic roughness is not supported")
    if p.base_metalness not in (0.0, 1.0):
        raise ModelError(f"openpbr-coat: base_metalness must be 0 or 1, got {p.base_metalness}")
    zeros = np.zeros(3)
    color = np.asarray(p.base_color, dtype=float)
    if p.base_metalness == 1.0:
        e_base = color * p.specular_weight
        r_b = float(coat_roughening(p.specular_roughness, p.coat_roughness, p.coat_weight))
        kind = dict(base_kind=BASE_F82, rho=zeros, base_alpha=float(alpha_from_roughness(r_b)),
                    f0=p.base_weight * color, tint=np.asarray(p.specular_color, dtype=float),
                    specular_weight=float(p.specular_weight))
    else:
        if p.specular_weight != 0.0:
            raise ModelError("openpbr-coat: a diffuse base needs specular_weight 0 (no dielectric specular lobe)")
        if p.base_diffuse_roughness != 0.0:
            raise ModelError("openpbr-coat: base_diffuse_roughness must be 0 (Lambertian)")
        e_base = color
        kind = dict(base_kind=BASE_LAMBERTIAN, rho=p.base_weight * color, base_alpha=0.0, f0=zeros, tint=zeros,
                    specular_weight=0.0)
    delta = coat_darkening(p.coat_ior, e_base, p.coat_weight, p.coat_darkening)
    return CoatLayering(coat_weight=float(p.coat_weight), coat_alpha=float(alpha_from_roughness(p.coat_roughness)),
                        coat_ior=float(p.coat_ior), coat_color=np.asarray(p.coat_color, dtype=float),
                        absorption=ABSORB_REFRACTED, base_scale=np.broadcast_to(delta, (3,)).astype(float),
                        eta=np.ones(3), kappa=zeros, height_correlated=bool(height_correlated), **kind)


def evaluate_openpbr(p: OpenPBRParameters, l: np.ndarray, v: np.ndarray, height_correlated: bool = True) -> ModelValue:
    """OpenPBR's coated BRDF for lights ``l`` and viewers ``v`` (broadcast, (..., 3), unit, pointing
    away from the surface): ``top`` the coat lobe (repeated on RGB), ``internal`` the rest; 1/sr,
    no cosine."""
    top, internal = evaluate_layering(openpbr_layering(p, height_correlated), l, v)
    return ModelValue(top=np.repeat(top[..., None], 3, axis=-1), internal=internal)


class OpenPBRCoat(Model):
    """OpenPBR Surface 1.1's coat (see the module docstring for the formula and its sources).

    ``height_correlated``: Smith masking of the coat and metal lobes (MaterialX's GGX uses the
    height-correlated form; the default).
    """

    name = "openpbr-coat"
    description = ("OpenPBR Surface 1.1 coat (node graph of MaterialX 1.39.5): albedo scaling, darkening, "
                   "roughening, F82-tint metal; one coat over a conductor or Lambertian base")
    sides = ("brdf",)
    #: GGX, Fresnel and albedo tables of l, v and h only (Model.mirror_symmetric)
    mirror_symmetric = True

    def __init__(self, height_correlated: bool = True) -> None:
        self.height_correlated = bool(height_correlated)

    def support_reason(self, stack: Stack) -> str | None:
        return coat_reason(stack)

    def _evaluate(self, stack: Stack, l: np.ndarray, v: np.ndarray, side: str) -> ModelValue:
        return evaluate_openpbr(openpbr_parameters(stack), l, v, self.height_correlated)
