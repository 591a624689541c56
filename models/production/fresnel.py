"""The metal parametrisations of the production models, and their maps from a complex index.

* OpenPBR's **F82-tint** Fresnel (OpenPBR 1.1, section "Metal"; Kutz et al. 2021 after Hoffman
  2019): ``F82(mu) = S(mu) - mu (1 - mu)**6 / (mb (1 - mb)**6) * (S(mb) - t S(mb))`` with the
  Schlick curve ``S(mu) = F0 + (1 - F0) (1 - mu)**5``, ``mb = 1/7`` (about 82 degrees),
  ``F0 = base_weight * base_color`` and ``t = specular_color`` (node ``generalized_schlick_bsdf``
  with ``color0`` and ``color82`` in ``open_pbr_surface.mtlx``), times ``specular_weight``.
* Standard Surface's **artistic IOR** (Gulbrandsen 2014; node ``artistic_ior`` of
  ``standard_surface.mtlx``): reflectivity ``r`` and edge colour ``g`` give the complex index
  ``n = g n_min + (1 - g) n_max`` with ``n_min = (1 - r) / (1 + r)``,
  ``n_max = (1 + sqrt r) / (1 - sqrt r)`` and ``k = sqrt((r (n + 1)**2 - (n - 1)**2) / (1 - r))``,
  which the node ``conductor_bsdf`` then uses in the exact conductor Fresnel.

The maps from our conductor (absolute index ``eta + i kappa`` against air) to these parameters --
:func:`f82_tint_from_ior` and :func:`artistic_from_ior` -- and why they are chosen so:
``docs/production-models.md``. ``mu`` is the cosine between the direction and the microfacet
normal; reflectances are fractions per RGB channel.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from goniometer.optics import np_fresnel_conductor
from models._jit import njit

#: the "82 degree" cosine of the F82-tint model (cos 81.79 deg)
F82_MU = 1.0 / 7.0


@njit(cache=True)
def schlick(mu: float, f0: float) -> float:
    """Schlick's reflectance ``F0 + (1 - F0) (1 - mu)**5`` (``mu`` clamped to [0, 1])."""
    c = min(max(mu, 0.0), 1.0)
    return f0 + (1.0 - f0) * (1.0 - c) ** 5


@njit(cache=True)
def f82_tint(mu: float, f0: float, tint: float) -> float:
    """OpenPBR's F82-tint reflectance at cosine ``mu`` for normal-incidence reflectance ``f0``
    and edge tint ``tint`` (= ``specular_color``; 1 gives the Schlick curve). One channel."""
    c = min(max(mu, 0.0), 1.0)
    mb = F82_MU
    s_mb = schlick(mb, f0)
    scale = c * (1.0 - c) ** 6 / (mb * (1.0 - mb) ** 6)
    return schlick(c, f0) - scale * (s_mb - tint * s_mb)


def f82_tint_from_ior(eta: ArrayLike, kappa: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """``(base_color, specular_color)`` of OpenPBR's metal that matches the conductor of complex
    index ``eta + i kappa`` (relative to the medium the metal is seen from) at normal incidence
    and at ``mu = 1/7``: ``base_color = F(1)``, ``specular_color = F(1/7) / S(1/7)`` with the
    exact conductor Fresnel ``F`` and the Schlick curve ``S`` of ``F(1)``. ``specular_color`` is
    not clamped: it exceeds 1 for weakly absorbing metals whose edge is brighter than Schlick's."""
    eta = np.asarray(eta, dtype=np.float64)
    kappa = np.asarray(kappa, dtype=np.float64)
    f0 = np.asarray(np_fresnel_conductor(np.ones_like(eta), eta, kappa), dtype=np.float64)
    f_mb = np.asarray(np_fresnel_conductor(np.full_like(eta, F82_MU), eta, kappa), dtype=np.float64)
    s_mb = f0 + (1.0 - f0) * (1.0 - F82_MU) ** 5
    return f0, f_mb / s_mb


def artistic_ior(reflectivity: ArrayLike, edge_color: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Gulbrandsen 2014's complex index ``(n, k)`` from reflectivity ``r`` in [0, 1) and edge
    colour ``g`` (the map of Standard Surface's ``artistic_ior`` node, without its clamps)."""
    r = np.asarray(reflectivity, dtype=np.float64)
    g = np.asarray(edge_color, dtype=np.float64)
    sr = np.sqrt(r)
    n_min = (1.0 - r) / (1.0 + r)
    n_max = (1.0 + sr) / (1.0 - sr)
    n = g * n_min + (1.0 - g) * n_max
    k2 = (r * (n + 1.0) ** 2 - (n - 1.0) ** 2) / (1.0 - r)
    return n, np.sqrt(np.maximum(k2, 0.0))


def artistic_from_ior(eta: ArrayLike, kappa: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """The inverse of :func:`artistic_ior`: ``(r, g)`` with ``r = F(1)`` of ``eta + i kappa`` and
    ``g = (n_max - eta) / (n_max - n_min)``; :func:`artistic_ior` of the result gives back
    ``(eta, kappa)`` exactly (for ``r < 1``). ``g`` may leave [0, 1] (not clamped)."""
    eta = np.asarray(eta, dtype=np.float64)
    kappa = np.asarray(kappa, dtype=np.float64)
    r = np.asarray(np_fresnel_conductor(np.ones_like(eta), eta, kappa), dtype=np.float64)
    sr = np.sqrt(r)
    n_min = (1.0 - r) / (1.0 + r)
    with np.errstate(divide="ignore", invalid="ignore"):   # r = 1 (a perfect mirror): g undefined (NaN)
        n_max = (1.0 + sr) / (1.0 - sr)
        return r, (n_max - eta) / (n_max - n_min)

