"""OpenPBR Surface 1.1's coat formulas: the base darkening and the base roughening by a coat.

These are the two closed forms the OpenPBR node graph (``open_pbr_surface.mtlx`` of MaterialX
1.39.5, nodes ``Kcoat`` ... ``modulated_base_darkening`` and ``coat_roughness_to_power_4`` ...
``effective_specular_roughness``) and the specification (section "Coat", sub-sections
"darkening" and "roughening") define. Our own account of them, and how our stacks map onto
OpenPBR's parameters: ``docs/production-models.md``.

Roughness convention: OpenPBR's ``roughness`` r is the *perceptual* roughness; the GGX alpha of an
isotropic lobe is ``alpha = r**2`` (node ``open_pbr_anisotropy`` with anisotropy 0). The
functions below take and return r, as the specification does; :func:`alpha_from_roughness` and
:func:`roughness_from_alpha` convert.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike


def alpha_from_roughness(roughness: ArrayLike) -> np.ndarray:
    """GGX alpha of an isotropic OpenPBR lobe of perceptual roughness r: ``alpha = r**2``."""
    r = np.asarray(roughness, dtype=np.float64)
    return r * r


def roughness_from_alpha(alpha: ArrayLike) -> np.ndarray:
    """OpenPBR perceptual roughness of a GGX lobe of alpha in [0, 1]: ``r = sqrt(alpha)``."""
    return np.sqrt(np.asarray(alpha, dtype=np.float64))


def coat_internal_reflection(coat_ior: ArrayLike) -> np.ndarray:
    """OpenPBR's ``K_coat``: the fraction of light diffusely distributed inside the coat that the
    coat's top interface reflects back down, approximated by the specification as
    ``K = 1 - (1 - F0) / n**2`` with ``F0 = ((n - 1) / (n + 1))**2`` and ``n`` = ``coat_ior``
    (coat index relative to the medium above, > 0). Independent of the coat roughness."""
    n = np.asarray(coat_ior, dtype=np.float64)
    f0 = ((n - 1.0) / (n + 1.0)) ** 2
    return 1.0 - (1.0 - f0) / (n * n)


def coat_darkening(coat_ior: ArrayLike, base_albedo: ArrayLike, coat_weight: float = 1.0,
                   darkening: float = 1.0) -> np.ndarray:
    """OpenPBR's base darkening factor under a coat (multiplies the base BSDF, colour-wise).

    ``Delta = (1 - K) / (1 - E_base K)`` with ``K`` = :func:`coat_internal_reflection` of
    ``coat_ior``, then blended towards 1: ``1 + coat_weight * darkening * (Delta - 1)``
    (the node graph's ``mix(1, Delta, coat_weight * coat_darkening)``).

    Inputs:
    * ``coat_ior``: coat index of refraction relative to the medium above (OpenPBR ``coat_ior``).
    * ``base_albedo``: the base's directional-albedo *estimate* ``E_base`` in [0, 1] (scalar or
      RGB), as the node graph takes it: ``base_color * specular_weight`` for a metal base,
      ``base_color`` for a diffuse base (it is not the base's true albedo; it is the user colour).
    * ``coat_weight``: OpenPBR ``coat_weight`` in [0, 1] (presence of the coat).
    * ``darkening``: OpenPBR ``coat_darkening`` in [0, 1] (1 = the physical darkening).

    This is the node graph's ``K``; the specification text recommends a refinement
    (``K = lerp(K_s, K_r, r_b)`` with the hemispherical Fresnel albedo), which
    ``docs/production-models.md`` states and this function does not implement.

    Returns the factor with the broadcast shape of ``coat_ior`` and ``base_albedo``: 1 without
    coat (weight 0), for an index-matched coat (n = 1 gives K = 0) and for a white base
    (E_base = 1); ``1 - K`` for a black base estimate (E_base = 0).
    """
    k = coat_internal_reflection(coat_ior)
    e = np.asarray(base_albedo, dtype=np.float64)
    delta = (1.0 - k) / (1.0 - e * k)
    mix = float(coat_weight) * float(darkening)
    return 1.0 + mix * (delta - 1.0)


def coat_roughening(base_roughness: ArrayLike, coat_roughness: ArrayLike,
                    coat_weight: float = 1.0) -> np.ndarray:
    """OpenPBR's effective base roughness under a rough coat (perceptual roughness, not alpha).

    ``r_eff = min(1, r_base**4 + 2 r_coat**4) ** (1/4)``, blended linearly with the bare base
    roughness by ``coat_weight``: ``r_base + coat_weight * (r_eff - r_base)``. In GGX alphas
    (``alpha = r**2``) the rule reads ``alpha_eff**2 = min(1, alpha_base**2 + 2 alpha_coat**2)``.

    Inputs:
    * ``base_roughness``: OpenPBR ``specular_roughness`` r_base in [0, 1] of the base lobe.
    * ``coat_roughness``: OpenPBR ``coat_roughness`` r_coat in [0, 1].
    * ``coat_weight``: OpenPBR ``coat_weight`` in [0, 1].

    The specification's formula does not depend on the coat index (OpenPBR issue #239).
    """
    rb = np.asarray(base_roughness, dtype=np.float64)
    rc = np.asarray(coat_roughness, dtype=np.float64)
    r_eff = np.minimum(1.0, rb ** 4 + 2.0 * rc ** 4) ** 0.25
    return rb + float(coat_weight) * (r_eff - rb)


def coat_darkening_spec(coat_ior: ArrayLike, base_albedo: ArrayLike, base_roughness: ArrayLike, mu: ArrayLike,
                        corrected: bool = False) -> np.ndarray:
    """The specification's coat darkening ``Delta`` (the text's refinement of the node graph's
    :func:`coat_darkening`), at the cosine ``mu`` of the direction it is evaluated for.

    ``K = lerp(K_s, K_r, r_b)`` with ``K_s = F(mu; n)`` (a smooth base: the coat's Fresnel
    reflectance) and ``K_r = 1 - (1 - E_F(n)) / n**2`` (a rough, diffusing base: the coat's internal
    diffuse reflectance; ``E_F`` the hemispherical Fresnel albedo, exact here:
    :func:`models.tables.microfacet_albedo.fresnel_average`), ``r_b`` the base's perceptual
    roughness (1 for a diffuse base). OpenPBR 1.1 (the specification and its ``dev_1.2`` branch):
    ``Delta = (1 - K) / (1 - E_b K)``. ``corrected``: the numerator of the write-up's listing
    (OpenPBR issue #269, the comment of PR #253): ``Delta = (1 - K_r) / (1 - E_b K)``, the escape
    fraction of diffuse light whatever the base's roughness. The two agree for a rough base
    (``r_b = 1``). No coat weight or ``coat_darkening`` blend (both 1). Sources and our reading:
    ``docs/lut.md`` section 8."""
    from goniometer.optics import np_fresnel_dielectric
    from models.tables.microfacet_albedo import fresnel_average
    n = np.asarray(coat_ior, dtype=np.float64)
    e_f = np.vectorize(lambda x: fresnel_average(float(x)))(n)
    k_r = 1.0 - (1.0 - e_f) / (n * n)
    k_s = np_fresnel_dielectric(np.asarray(mu, dtype=np.float64), n)
    r_b = np.asarray(base_roughness, dtype=np.float64)
    k = k_s + r_b * (k_r - k_s)
    e = np.asarray(base_albedo, dtype=np.float64)
    return ((1.0 - k_r) if corrected else (1.0 - k)) / (1.0 - e * k)


def coat_roughening_pr261(base_roughness: ArrayLike, coat_roughness: ArrayLike, coat_ior: ArrayLike,
                          coat_weight: float = 1.0) -> np.ndarray:
    """The coat roughening of OpenPBR pull request #261 ("Roughening improvements", its version of
    2026-03-31), in perceptual roughness like :func:`coat_roughening`.

    In GGX alphas (``alpha = r**2``), ``n`` = ``coat_ior``:
    ``B(n) = 1.05 (n - 1) sqrt(1 + n**2) / n``,
    ``alpha_raw = sqrt((n alpha_base)**2 + (B(n) alpha_coat)**2)``,
    ``alpha_eff = 0.85 tanh(alpha_raw / 0.85)`` (total internal reflection at the coat's exit caps
    the lobe's width), ``r_eff = sqrt(alpha_eff)``, blended with the bare base roughness by
    ``coat_weight``. Source: ``docs/lut.md`` section 8."""
    rb = np.asarray(base_roughness, dtype=np.float64)
    ab = rb * rb
    ac = np.asarray(coat_roughness, dtype=np.float64) ** 2
    n = np.asarray(coat_ior, dtype=np.float64)
    b = 1.05 * (n - 1.0) * np.sqrt(1.0 + n * n) / n
    raw = np.sqrt((n * ab) ** 2 + (b * ac) ** 2)
    r_eff = np.sqrt(0.85 * np.tanh(raw / 0.85))
    return rb + float(coat_weight) * (r_eff - rb)
