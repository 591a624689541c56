"""The albedo-scaling coat both production models share (OpenPBR 1.1, section "Layering",
equation "non-reciprocal albedo scaling with T"; MaterialX's ``layer`` node over a
``dielectric_bsdf`` in reflection mode)::

    f(l, v) = C f_coat(l, v) + A(l, v) (1 - C E_coat(v)) S f_base(l, v)

* ``f_coat``: the coat's GGX dielectric reflection (Walter 2007: exact Fresnel of the coat index,
  Smith masking), the ``top`` lobe; ``C`` the coat weight.
* ``E_coat(v)``: the directional albedo of that lobe seen from the viewer ``v`` (the direction
  light leaves towards), from :func:`models.tables.fgd_slice` -- our quadrature, cached on disk.
* ``A``: the coat's absorption, ``1 + C (T - 1)`` with ``T = coat_color`` (constant, Standard
  Surface's node graph) or ``T = coat_color ** ((1/mu_l' + 1/mu_v') / 2)`` along the directions
  refracted into the coat (OpenPBR's "view-dependent absorption", ``mu' = sqrt(1 - (1 - mu**2) /
  eta**2)``; 0 where a direction cannot enter, eta < 1).
* ``S``: a colour scale of the base (OpenPBR's darkening; 1 for Standard Surface).
* ``f_base``: the base BRDF evaluated at the *outer* pair ``(l, v)`` (no refraction): Lambertian
  ``rho / pi``, a GGX metal with OpenPBR's F82-tint Fresnel, or a GGX conductor with the exact
  Fresnel of ``eta + i kappa`` (Standard Surface's ``conductor_bsdf``).

Conventions (``models.base``): ``l`` (light) and ``v`` (viewer) are unit vectors pointing away
from the surface, ``z`` the macro normal; values are BRDFs without the cosine, in 1/sr, RGB on the
last axis. A perfectly smooth lobe (alpha = 0) is a Dirac and evaluates to 0 pointwise, as in the
other models. Definitions and mappings: ``docs/production-models.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from goniometer.optics import ggx_d, ggx_lambda, half_vector, microfacet_reflection, fresnel_conductor, smith_g2
from goniometer.kernel.packing import BASE_CONDUCTOR, BASE_LAMBERTIAN
from models._jit import njit
from models.production.fresnel import f82_tint
from models.tables import fgd_slice

_INV_PI = 1.0 / math.pi

#: the base kinds: the simulator's codes (:mod:`goniometer.kernel.packing`: ``BASE_LAMBERTIAN`` rho /
#: pi, ``BASE_CONDUCTOR`` a GGX conductor with the exact Fresnel of eta + i kappa) and one of its own
BASE_F82 = 3  #: GGX metal with OpenPBR's F82-tint Fresnel (times specular_weight)
ABSORB_CONSTANT = 0  #: T = coat_color
ABSORB_REFRACTED = 1  #: T = coat_color ** ((1/mu_l' + 1/mu_v') / 2)


@dataclass(frozen=True)
class CoatLayering:
    """The resolved inputs of the albedo-scaling coat (all GGX roughnesses are alphas).

    ``coat_weight`` C in [0, 1]; ``coat_alpha``, ``coat_ior`` (relative to air, > 0);
    ``coat_color`` (RGB, the normal-incidence round-trip transmittance); ``absorption``
    (``ABSORB_CONSTANT`` or ``ABSORB_REFRACTED``); ``base_scale`` S (RGB); ``base_kind``
    (``BASE_*``); ``rho`` (Lambertian albedo, RGB); ``base_alpha``; ``f0``, ``tint`` (F82-tint
    ``base_color`` and ``specular_color``, RGB); ``specular_weight``; ``eta``, ``kappa``
    (conductor index, RGB); ``height_correlated`` (Smith masking of both lobes).
    """

    coat_weight: float
    coat_alpha: float
    coat_ior: float
    coat_color: np.ndarray
    absorption: int
    base_scale: np.ndarray
    base_kind: int
    rho: np.ndarray
    base_alpha: float
    f0: np.ndarray
    tint: np.ndarray
    specular_weight: float
    eta: np.ndarray
    kappa: np.ndarray
    height_correlated: bool


@njit(cache=True, parallel=True)
def _coat_kernel(L, V, e_coat, c_w, a_c, eta_c, coat_color, absorption, base_scale, base_kind, rho,
                 a_b, f0, tint, spec_w, eta, kappa, hc, top, internal):
    """Fill ``top`` (N,) and ``internal`` (N, 3) for the direction pairs ``L[k]``, ``V[k]``, in
    parallel (a pair's values depend on it alone: any thread count gives the same bits)."""
    for k in numba.prange(L.shape[0]):
        lx, ly, lz = L[k, 0], L[k, 1], L[k, 2]
        vx, vy, vz = V[k, 0], V[k, 1], V[k, 2]
        top[k] = 0.0
        for c in range(3):
            internal[k, c] = 0.0
        if not (lz > 0.0 and vz > 0.0) or not math.isfinite(vx + vy + vz + lx + ly + lz):
            continue
        if a_c > 0.0 and c_w > 0.0:
            top[k] = c_w * microfacet_reflection(lx, ly, lz, vx, vy, vz, a_c, a_c, eta_c, 0.0, hc)
        # path exponent of the absorption along the refracted pair (normal-incidence round trip = 1)
        expo = 1.0
        enters = True
        if absorption == ABSORB_REFRACTED:
            sl = 1.0 - (1.0 - lz * lz) / (eta_c * eta_c)
            sv = 1.0 - (1.0 - vz * vz) / (eta_c * eta_c)
            if sl <= 0.0 or sv <= 0.0:
                enters = False
            else:
                expo = 0.5 * (1.0 / math.sqrt(sl) + 1.0 / math.sqrt(sv))
        w = 1.0 - c_w * e_coat[k]
        common = 0.0
        vh = 0.0
        if base_kind != BASE_LAMBERTIAN and a_b > 0.0:
            hx, hy, hz = half_vector(lx, ly, lz, vx, vy, vz)
            vh = vx * hx + vy * hy + vz * hz
            d = ggx_d(hx, hy, hz, a_b, a_b)
            g = smith_g2(ggx_lambda(lx, ly, lz, a_b, a_b), ggx_lambda(vx, vy, vz, a_b, a_b), False, hc)
            common = d * g / (4.0 * lz * vz)
        for c in range(3):
            if base_kind == BASE_LAMBERTIAN:
                fb = rho[c] * _INV_PI
            elif base_kind == BASE_F82:
                fb = spec_w * f82_tint(vh, f0[c], tint[c]) * common
            else:
                fb = fresnel_conductor(vh, eta[c], kappa[c]) * common if common > 0.0 else 0.0
            if enters:
                t = coat_color[c] ** expo if coat_color[c] > 0.0 else 0.0
            else:
                t = 0.0
            a = 1.0 + c_w * (t - 1.0)
            internal[k, c] = a * w * base_scale[c] * fb


def coat_albedo(layering: CoatLayering, mu: np.ndarray) -> np.ndarray:
    """``E_coat(mu)``: directional albedo of the coat's GGX reflection lobe at cosines ``mu``
    (``mu <= 0`` gives 0), from our FGD quadrature (:func:`models.tables.fgd_slice`)."""
    mu = np.asarray(mu, dtype=np.float64)
    out = np.zeros(mu.shape)
    ok = mu > 0.0
    if not ok.any() or layering.coat_weight == 0.0:
        return out
    m = np.minimum(mu[ok], 1.0)
    table = fgd_slice(float(layering.coat_ior), 0.0, height_correlated=layering.height_correlated,
                      mu_min=float(m.min()))
    out[ok] = table(m, np.full(m.shape, float(layering.coat_alpha)))
    return out


def evaluate_layering(layering: CoatLayering, l: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(top, internal)`` of the coat for lights ``l`` and viewers ``v`` (broadcast, (..., 3)):
    ``top`` (...,) the coat lobe, ``internal`` (..., 3) the attenuated base."""
    l, v = np.broadcast_arrays(np.asarray(l, dtype=np.float64), np.asarray(v, dtype=np.float64))
    shape = l.shape[:-1]
    L = np.ascontiguousarray(l.reshape(-1, 3))
    V = np.ascontiguousarray(v.reshape(-1, 3))
    e_coat = coat_albedo(layering, V[:, 2])
    top = np.empty(L.shape[0])
    internal = np.empty((L.shape[0], 3))
    f64 = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731
    _coat_kernel(L, V, e_coat, float(layering.coat_weight), float(layering.coat_alpha), float(layering.coat_ior),
                 f64(layering.coat_color), int(layering.absorption), f64(layering.base_scale),
                 int(layering.base_kind), f64(layering.rho), float(layering.base_alpha), f64(layering.f0),
                 f64(layering.tint), float(layering.specular_weight), f64(layering.eta), f64(layering.kappa),
                 bool(layering.height_correlated), top, internal)
    return top.reshape(shape), internal.reshape(shape + (3,))
