"""The base of the ``pbrt-layered`` rows: a Lambertian or a rough (or smooth) conductor under the
coat, as pbrt-v4's layered BSDF samples and evaluates it (``docs/pbrt-layered.md``; conventions of
:mod:`models.pbrt_layered.kernel`: both directions pointing up into the coat, no cosine).

:func:`base_f`, :func:`base_pdf` and :func:`base_sample` compose :mod:`goniometer.optics`' formulas
(a conductor index relative to the coat, per slot); :func:`conductor_pair` and
:func:`conductor_sample` are the walk's fused versions for a rough conductor, with the same bits (one
half vector, ``D`` and ``G`` for every slot and the density; ``tests/models/test_pbrt_layered.py``)."""

from __future__ import annotations

import math

from goniometer.optics import (cos_sin_2pi, cosine_from_disk, fresnel_conductor, fresnel_dielectric, ggx_d,
                               ggx_lambda, half_vector, microfacet_reflection, reflect, sample_vndf, smith_g2,
                               vndf_pdf, vndf_pdf_given)
from goniometer.kernel.packing import BASE_LAMBERTIAN
from models._jit import njit
from models.pbrt_layered.numeric import quotient

_INV_PI = 1.0 / math.pi


# ---------------------------------------------------------------------- the base

@njit(cache=True)
def base_f(ox: float, oy: float, oz: float, ix: float, iy: float, iz: float, kind: int, a: float, smooth: bool,
           rho0: float, rho1: float, rho2: float, e0: float, k0: float, e1: float, k1: float, e2: float, k2: float):
    """The base's ``f(wo, wi)`` (no cosine) per slot, both directions pointing up into the coat:
    Lambertian ``rho / pi``, or the GGX conductor of relative index ``eta + i k`` with
    ``G = 1 / (1 + Lambda_o + Lambda_i)`` (0 for a smooth conductor: a mirror)."""
    if oz <= 0.0 or iz <= 0.0:
        return 0.0, 0.0, 0.0
    if kind == BASE_LAMBERTIAN:
        return rho0 * _INV_PI, rho1 * _INV_PI, rho2 * _INV_PI
    if smooth:
        return 0.0, 0.0, 0.0
    f0 = microfacet_reflection(ix, iy, iz, ox, oy, oz, a, a, e0, k0, True)
    if e1 == e0 and k1 == k0:
        f1 = f0
    else:
        f1 = microfacet_reflection(ix, iy, iz, ox, oy, oz, a, a, e1, k1, True)
    if e2 == e1 and k2 == k1:
        f2 = f1
    else:
        f2 = microfacet_reflection(ix, iy, iz, ox, oy, oz, a, a, e2, k2, True)
    return f0, f1, f2


@njit(cache=True)
def base_pdf(ox: float, oy: float, oz: float, ix: float, iy: float, iz: float, kind: int, a: float,
             smooth: bool) -> float:
    """The base's sampling density of ``wi`` given ``wo`` (both up): cosine for the Lambertian, the
    visible-normal reflection density for a rough conductor, 0 for a mirror."""
    if oz <= 0.0 or iz <= 0.0:
        return 0.0
    if kind == BASE_LAMBERTIAN:
        return iz * _INV_PI
    if smooth:
        return 0.0
    hx, hy, hz = half_vector(ox, oy, oz, ix, iy, iz)
    return vndf_pdf(ox, oy, oz, hx, hy, hz, a, a) / (4.0 * abs(ox * hx + oy * hy + oz * hz))


@njit(cache=True)
def base_sample(ox: float, oy: float, oz: float, kind: int, a: float, smooth: bool, rho0: float, rho1: float,
                rho2: float, e0: float, k0: float, e1: float, k1: float, e2: float, k2: float, u1: float, u2: float):
    """Sample the base's reflection from ``wo`` (pointing up). Returns
    ``(ok, wi_x, wi_y, wi_z, weight_0, weight_1, weight_2, pdf)`` with the weight
    ``f |cos wi| / pdf`` per slot (pbrt's ``beta`` factor) and the density."""
    if oz <= 0.0:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    if kind == BASE_LAMBERTIAN:
        c, s = cos_sin_2pi(u2)
        rr = math.sqrt(u1)
        ix, iy, iz = cosine_from_disk(rr * c, rr * s)
        if iz <= 0.0:
            return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        # f |cos| / pdf = (rho / pi) iz / (iz / pi) = rho
        return True, ix, iy, iz, rho0, rho1, rho2, iz * _INV_PI
    if smooth:
        f0 = fresnel_conductor(oz, e0, k0)
        f1 = fresnel_conductor(oz, e1, k1)
        f2 = fresnel_conductor(oz, e2, k2)
        return True, -ox, -oy, oz, f0, f1, f2, 1.0
    mx, my, mz = sample_vndf(ox, oy, oz, a, a, u1, u2)
    ix, iy, iz = reflect(ox, oy, oz, mx, my, mz)
    if iz <= 0.0:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    pdf = base_pdf(ox, oy, oz, ix, iy, iz, kind, a, smooth)
    if pdf <= 0.0:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    f0, f1, f2 = base_f(ox, oy, oz, ix, iy, iz, kind, a, smooth, rho0, rho1, rho2, e0, k0, e1, k1, e2, k2)
    k = iz / pdf
    return True, ix, iy, iz, f0 * k, f1 * k, f2 * k, pdf


# ---------------------------------------------------------------------- the rough conductor base, fused

@njit(cache=True, inline="always")
def _base_fresnel(c: float, e: float, k: float) -> float:
    """The Fresnel factor :func:`goniometer.optics.microfacet_reflection` takes for the index
    ``e + i k``: the conductor's if ``k > 0``, else the dielectric's."""
    if k > 0.0:
        return fresnel_conductor(c, e, k)
    return fresnel_dielectric(c, e)


@njit(cache=True)
def conductor_pair(ox: float, oy: float, oz: float, ix: float, iy: float, iz: float, a: float, lam_o: float,
                   lam_i: float, g1_o: float, e0: float, k0: float, e1: float, k1: float, e2: float, k2: float):
    """:func:`base_f` and :func:`base_pdf` of a rough conductor together, ``(f_0, f_1, f_2, pdf)``,
    given ``lam_o``, ``lam_i`` (``ggx_lambda`` of ``o`` and ``i``) and ``g1_o``
    (``smith_g1_dir`` of ``o``), which the walk computes once per direction.

    The same bits as the two functions: the half vector of ``o + i`` (``optics.half_vector``;
    ``o + i`` equals ``i + o`` exactly), its ``D`` and the masking
    ``smith_g2(lam_i, lam_o)`` are computed once instead of once per slot and once more for the
    density; each slot's value is ``microfacet_reflection``'s ``F D G / (4 i_z o_z)`` in its
    order, the density ``optics.vndf_pdf_given`` over ``4 |o.h|``."""
    if oz <= 0.0 or iz <= 0.0:
        return 0.0, 0.0, 0.0, 0.0
    hx, hy, hz = half_vector(ox, oy, oz, ix, iy, iz)
    d = ggx_d(hx, hy, hz, a, a)
    # the density: vndf_pdf(o, h) / (4 |o.h|)
    pdf = vndf_pdf_given(ox, oy, oz, hx, hy, hz, g1_o, d) / (4.0 * abs(ox * hx + oy * hy + oz * hz))
    # the values: microfacet_reflection(i, o, a, a, e, k, True) per slot, equal indices sharing one
    lh = ix * hx + iy * hy + iz * hz
    g = smith_g2(lam_i, lam_o, False, True)
    den = 4.0 * iz * oz
    f0 = quotient(_base_fresnel(lh, e0, k0) * d * g, den)
    if e1 == e0 and k1 == k0:
        f1 = f0
    else:
        f1 = quotient(_base_fresnel(lh, e1, k1) * d * g, den)
    if e2 == e1 and k2 == k1:
        f2 = f1
    else:
        f2 = quotient(_base_fresnel(lh, e2, k2) * d * g, den)
    return f0, f1, f2, pdf


@njit(cache=True)
def conductor_sample(ox: float, oy: float, oz: float, a: float, lam_o: float, g1_o: float, e0: float, k0: float,
                     e1: float, k1: float, e2: float, k2: float, u1: float, u2: float):
    """:func:`base_sample` of a rough conductor (the same result, bit for bit), its value and
    density from :func:`conductor_pair` with the walk's ``lam_o`` and ``g1_o`` of ``o``."""
    if oz <= 0.0:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    mx, my, mz = sample_vndf(ox, oy, oz, a, a, u1, u2)
    ix, iy, iz = reflect(ox, oy, oz, mx, my, mz)
    if iz <= 0.0:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    f0, f1, f2, pdf = conductor_pair(ox, oy, oz, ix, iy, iz, a, lam_o, ggx_lambda(ix, iy, iz, a, a), g1_o,
                                     e0, k0, e1, k1, e2, k2)
    if pdf <= 0.0:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    k = iz / pdf
    return True, ix, iy, iz, f0 * k, f1 * k, f2 * k, pdf
