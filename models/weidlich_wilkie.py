"""Weidlich & Wilkie's layered BRDF and two of its variants (Bati, Pacanowski, Barla 2019, sec. 3.1, 5.1).

All three models share one formula for a dielectric coat (top interface, GGX roughness
``alpha0``, absolute index ``eta0``), an optional absorbing medium of optical depth ``tau`` (RGB)
and an opaque base (Lambertian of albedo ``rho`` or GGX conductor)::

    f(l0, v0) = f_r0(l0, v0) + T01 * f_r1(lb, vb) * a * X
    a = exp(-tau * (1 / |n.l1| + 1 / |n.v1|))

where ``f_r0`` is the GGX dielectric reflection BRDF of the coat (the ``top`` lobe), ``(l1, v1)``
is the refracted pair inside the coat, ``(lb, vb)`` the pair at which the base BRDF is evaluated,
and ``X`` is either Weidlich & Wilkie's TIR term ``t = (1 - G) + T10 G`` or, in Bati 2019's
corrected variant (their eq. 5), ``T10 / eta0**2``. How each variant chooses these (Bati 2019,
table 2) is held in a :class:`Variant`; see the model classes for the choices.

Conventions (as :mod:`models.base` and :mod:`goniometer.optics`):

* ``z`` is the macro normal ``n``. ``l0`` (the light) and ``v0`` (the viewer) point away from the
  surface, into the air above; ``h0 = normalize(l0 + v0)`` is the top microfacet normal.
* The refracted pair ``(l1, v1)`` lives inside the coat and points **away from the base**
  (upwards, towards the coat's top interface), i.e. it is minus the transmitted propagation
  direction; its ``z`` is positive. The base BRDF is evaluated with this pair as ``(l, v)``.
* Values are BRDF values without the cosine factor, in 1/sr, RGB on the last axis.
* Fresnel, GGX D, Smith Lambda, refraction and the Walter 2007 microfacet BRDF all come from
  :mod:`goniometer.optics`. Masking is separable Smith, ``G(a, b) = G1(a) G1(b)`` with
  ``G1 = 1 / (1 + Lambda)`` of the coat's roughness ``alpha0``.
* The conductor base uses its complex index relative to the coat: ``(eta1 + i kappa1) / eta0``.

Degenerate cases return 0 instead of NaN: ``v_z <= 0`` (or non-finite ``v``); a perfectly smooth
top (``alpha0 == 0``) has a Dirac ``f_r0`` that cannot be evaluated pointwise, so ``top`` is 0
there; likewise a perfectly smooth conductor base (effective ``alpha1 == 0``) gives an internal
conductor lobe of 0; total internal reflection on the way in (a coat index below 1) gives 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from goniometer.optics import fresnel_dielectric, ggx_lambda, half_vector, microfacet_reflection, refract
from goniometer.stack import Stack
from goniometer.kernel.packing import BASE_CONDUCTOR, BASE_LAMBERTIAN
from models._jit import njit
from models.base import CoatedBase, Model, ModelError, ModelValue, coated_base

_INV_PI = 1.0 / math.pi

# integer codes the kernel understands
NORMAL_N = 0  #: the geometric normal n = +z
NORMAL_H0 = 1  #: the top microfacet normal h0 = normalize(l0 + v0)
TIR_NONE = 0  #: no TIR term: X = T10 (Bati 2019, eq. 5)
TIR_G_REFRACTED = 1  #: t = (1 - G) + T10 G with G = G(l1, v1)
TIR_G_OUTER = 2  #: t = (1 - G) + T10 G with G = G(l0, v0)


@dataclass(frozen=True)
class Variant:
    """The choices that distinguish members of the Weidlich & Wilkie family (Bati 2019, table 2).

    ``transmit_normal``: normal (``NORMAL_N`` or ``NORMAL_H0``) about which T01 and T10 are taken.
    ``refract_normal``: normal about which Snell's law gives the refracted pair ``(l1, v1)``.
    ``base_at_refracted``: evaluate ``f_r1`` at ``(l1, v1)`` (True) or at ``(l0, v0)`` (False).
    ``tir``: ``TIR_NONE``, ``TIR_G_REFRACTED`` or ``TIR_G_OUTER``.
    ``max_roughness``: Elek's rule ``alpha1 <- max(alpha0, alpha1)`` for a conductor base.
    ``jacobian``: multiply the internal term by ``1 / eta0**2`` (Bati 2019, appendix C).
    """

    transmit_normal: int
    refract_normal: int
    base_at_refracted: bool
    tir: int
    max_roughness: bool
    jacobian: bool


WW09_VARIANT = Variant(NORMAL_H0, NORMAL_H0, False, TIR_G_REFRACTED, False, False)
ELEK10_VARIANT = Variant(NORMAL_H0, NORMAL_N, True, TIR_G_OUTER, True, False)
BATI19_VARIANT = Variant(NORMAL_N, NORMAL_N, True, TIR_NONE, True, True)


# ---------------------------------------------------------------------- kernel

@njit(cache=True)
def _inner(wx: float, wy: float, wz: float, mx: float, my: float, mz: float, eta: float):
    """The direction inside the coat paired with the outer direction ``w`` through normal ``m``.

    Refracts ``w`` (pointing away, into air) through a facet ``m`` into a medium of relative
    index ``eta`` and flips the result so that it points back up towards the interface.
    Returns ``(x, y, z, ok)``; ``ok`` is False on total internal reflection.
    """
    tx, ty, tz, ok = refract(wx, wy, wz, mx, my, mz, eta)
    return -tx, -ty, -tz, ok


@njit(cache=True)
def _smith_g(ax: float, ay: float, az: float, bx: float, by: float, bz: float, alpha: float) -> float:
    """Separable Smith masking-shadowing G1(a) G1(b) of a GGX surface of roughness ``alpha``."""
    la = ggx_lambda(ax, ay, az, alpha, alpha)
    lb = ggx_lambda(bx, by, bz, alpha, alpha)
    return 1.0 / ((1.0 + la) * (1.0 + lb))


@njit(cache=True, parallel=True)
def _ww_kernel(l: np.ndarray, v: np.ndarray, transmit_normal: int, refract_normal: int,
               base_at_refracted: bool, tir: int, jacobian: bool,
               alpha0: float, eta0: float, tau: np.ndarray, base_kind: int, rho: np.ndarray,
               alpha1: float, eta1: np.ndarray, kappa1: np.ndarray,
               top: np.ndarray, internal: np.ndarray) -> None:
    """Fill ``top`` (N,) and ``internal`` (N, 3) for light ``l`` (3,) and views ``v`` (N, 3).

    ``eta0`` is the coat index relative to air; ``eta1``/``kappa1`` (RGB) the conductor's index
    relative to the coat; ``alpha1`` the base roughness already modified by any roughness rule.
    Directions run in parallel (each one's values depend on it alone, so any thread count gives the
    same bits); a channel whose inputs equal the previous channel's takes its value.
    """
    lx, ly, lz = l[0], l[1], l[2]
    same_base = np.zeros(3, dtype=np.bool_)
    same_tau = np.zeros(3, dtype=np.bool_)
    for c in range(1, 3):
        same_base[c] = (rho[c] == rho[c - 1] and eta1[c] == eta1[c - 1] and kappa1[c] == kappa1[c - 1])
        same_tau[c] = tau[c] == tau[c - 1]
    for k in numba.prange(v.shape[0]):
        vx, vy, vz = v[k, 0], v[k, 1], v[k, 2]
        top[k] = 0.0
        internal[k, 0] = 0.0
        internal[k, 1] = 0.0
        internal[k, 2] = 0.0
        if not (vz > 0.0 and lz > 0.0) or not math.isfinite(vx + vy + vz):
            continue
        # top lobe: the coat's own GGX reflection (a Dirac for a perfectly smooth coat)
        if alpha0 > 0.0:
            top[k] = microfacet_reflection(lx, ly, lz, vx, vy, vz, alpha0, alpha0, eta0, 0.0, False)
        hx, hy, hz = half_vector(lx, ly, lz, vx, vy, vz)
        # Fresnel transmittances in and out
        if transmit_normal == NORMAL_H0:
            # the light leaves through the facet it entered by: v0.h0 = l0.h0, so T10 = T01
            t01 = 1.0 - fresnel_dielectric(lx * hx + ly * hy + lz * hz, eta0)
            t10 = t01
        else:
            t01 = 1.0 - fresnel_dielectric(lz, eta0)
            t10 = 1.0 - fresnel_dielectric(vz, eta0)
        if t01 <= 0.0:
            continue
        # refracted pair inside the coat (pointing up)
        if refract_normal == NORMAL_H0:
            mx, my, mz = hx, hy, hz
        else:
            mx, my, mz = 0.0, 0.0, 1.0
        l1x, l1y, l1z, okl = _inner(lx, ly, lz, mx, my, mz, eta0)
        v1x, v1y, v1z, okv = _inner(vx, vy, vz, mx, my, mz, eta0)
        if not (okl and okv) or l1z <= 0.0 or v1z <= 0.0:
            continue
        # exit factor: TIR term t, or T10 alone
        if tir == TIR_G_REFRACTED:
            g = _smith_g(l1x, l1y, l1z, v1x, v1y, v1z, alpha0)
            x = (1.0 - g) + t10 * g
        elif tir == TIR_G_OUTER:
            g = _smith_g(lx, ly, lz, vx, vy, vz, alpha0)
            x = (1.0 - g) + t10 * g
        else:
            x = t10
        if jacobian:
            x /= eta0 * eta0
        path = 1.0 / l1z + 1.0 / v1z
        fr1 = 0.0
        att = 0.0
        for c in range(3):
            if c == 0 or not same_base[c]:
                if base_kind == BASE_LAMBERTIAN:
                    fr1 = rho[c] * _INV_PI
                elif alpha1 > 0.0:
                    if base_at_refracted:
                        fr1 = microfacet_reflection(l1x, l1y, l1z, v1x, v1y, v1z, alpha1, alpha1,
                                                    eta1[c], kappa1[c], False)
                    else:
                        fr1 = microfacet_reflection(lx, ly, lz, vx, vy, vz, alpha1, alpha1,
                                                    eta1[c], kappa1[c], False)
                else:
                    fr1 = 0.0  # a perfectly smooth base: Dirac lobe, not evaluable pointwise
            if c == 0 or not same_tau[c]:
                att = math.exp(-tau[c] * path)
            internal[k, c] = t01 * fr1 * att * x


# ---------------------------------------------------------------------- models

_STRUCTURE = ("needs exactly [dielectric interface, optional medium, Lambertian or conductor base]")


def _reason(stack: Stack) -> str | None:
    """Why the WW family cannot represent ``stack`` (None if it can)."""
    cb = coated_base(stack)
    if cb is None:
        return f"unsupported stack: {_STRUCTURE}"
    if cb.base == "dielectric":
        return f"a dielectric base (slab) transmits light; this BRDF-only model {_STRUCTURE}"
    return None


def evaluate_variant(variant: Variant, cb: CoatedBase, l: np.ndarray, v: np.ndarray) -> ModelValue:
    """Evaluate ``variant`` on the coated base ``cb``; ``l`` (3,) and ``v`` (..., 3) as in Model."""
    shape = v.shape[:-1]
    vv = np.ascontiguousarray(v, dtype=np.float64).reshape(-1, 3)
    n = vv.shape[0]
    top = np.empty(n)
    internal = np.empty((n, 3))
    if cb.base == "lambertian":
        base_kind = BASE_LAMBERTIAN
        rho = np.asarray(cb.rho, dtype=np.float64)
        alpha1 = 0.0
        eta1 = np.ones(3)
        kappa1 = np.zeros(3)
    elif cb.base == "conductor":
        base_kind = BASE_CONDUCTOR
        rho = np.zeros(3)
        alpha1 = float(cb.alpha1)
        if variant.max_roughness:
            alpha1 = max(float(cb.alpha0), alpha1)
        eta1 = np.asarray(cb.eta1, dtype=np.float64) / cb.eta0
        kappa1 = np.asarray(cb.kappa1, dtype=np.float64) / cb.eta0
    else:
        raise ModelError(f"base {cb.base!r} is not supported")
    _ww_kernel(np.ascontiguousarray(l, dtype=np.float64), vv, variant.transmit_normal,
               variant.refract_normal, variant.base_at_refracted, variant.tir, variant.jacobian,
               float(cb.alpha0), float(cb.eta0), np.ascontiguousarray(cb.tau, dtype=np.float64),
               base_kind, rho, alpha1, eta1, kappa1, top, internal)
    top3 = np.repeat(top[:, None], 3, axis=1)
    return ModelValue(top=top3.reshape(shape + (3,)), internal=internal.reshape(shape + (3,)))


class _WWFamily(Model):
    """Shared plumbing: stack checks and evaluation of the class's :class:`Variant`."""

    variant: Variant
    sides = ("brdf",)
    #: cosines and Fresnel of l, v and h only (Model.mirror_symmetric)
    mirror_symmetric = True

    def support_reason(self, stack: Stack) -> str | None:
        return _reason(stack)

    def _evaluate(self, stack: Stack, l: np.ndarray, v: np.ndarray, side: str) -> ModelValue:
        cb = coated_base(stack)
        if cb is None:  # unreachable: Model.evaluate checked support_reason first
            raise ModelError(f"{self.name}: {_reason(stack)}")
        return evaluate_variant(self.variant, cb, l, v)


class WW09(_WWFamily):
    """Weidlich & Wilkie as implemented by the authors ([WW09]; Bati 2019 eq. 2, table 2 row 1).

    * T01 = 1 - F(l0.h0, eta0) about the top microfacet normal h0 = normalize(l0 + v0).
    * (l1, v1) = l0, v0 refracted through the facet h0 (Snell about h0); they set the path
      lengths of the absorption ``a`` and the masking of the TIR term.
    * f_r1 evaluated at (l0, v0) -- the authors' implementation bug that Bati 2019 reproduces.
      For a Lambertian base this changes nothing (f_r1 is constant); a and G still use the
      h0-refracted pair, so WW09 differs from Elek10 on plastics too.
    * t = (1 - G) + T10 G with G = G1(l1) G1(v1), separable Smith of the coat's roughness alpha0.
    * Choice (papers vague): T10 is taken about h0 as well, for the outgoing pair (v1, v0). WW07
      assumes light leaves through the facet it entered by; by Stokes reciprocity the transmittance
      of v1 -> v0 through h0 is 1 - F(v0.h0, eta0), and v0.h0 = l0.h0, so T10 = T01.
    * No roughness rule: the base keeps its own alpha1.
    """

    name = "ww09"
    description = "Weidlich & Wilkie 2009 (authors' implementation: base BRDF at unrefracted directions)"
    variant = WW09_VARIANT


class Elek10(_WWFamily):
    """Elek 2010's variant of Weidlich & Wilkie (Bati 2019 eq. 2, table 2 row 2).

    * T01 = 1 - F(l0.h0, eta0) about h0 = normalize(l0 + v0).
    * (l1, v1) = l0, v0 refracted about the geometric normal n; f_r1 evaluated at (l1, v1).
    * t = (1 - G) + T10 G with G = G1(l0) G1(v0), separable Smith of alpha0.
    * Choice (papers vague): T10 about h0 for the outgoing pair, which by reciprocity equals
      1 - F(v0.h0, eta0) = T01 (same argument as :class:`WW09`). Taking the inner direction
      v1 (refracted about n) against h0 instead would mix two normals and can show spurious TIR.
    * Roughness rule alpha1 <- max(alpha0, alpha1) for a conductor base.
    """

    name = "elek10"
    description = "Elek 2010 variant of Weidlich & Wilkie (refracted pair about n, alpha1 <- max(alpha0, alpha1))"
    variant = ELEK10_VARIANT


class WWBati19(_WWFamily):
    """Bati 2019's corrected Weidlich & Wilkie (their eq. 5 and appendix C).

        f = f_r0(l0, v0) + T01 f_r1(l1, v1) a T10 / eta0**2

    * T01 = 1 - F(n.l0, eta0) and T10 = 1 - F(n.v0, eta0), both about the geometric normal n
      (T10 is the transmittance of v1 -> v0, equal by reciprocity to that of v0 -> v1).
    * (l1, v1) refracted about n; f_r1 evaluated at (l1, v1); a uses |n.l1|, |n.v1|.
    * Jacobian 1 / eta0**2 with eta0 the coat index relative to air (their eta_1): the radiance
      leaving a dense medium drops as L / eta**2.
    * No TIR term t (removed by the paper), hence no masking G beyond f_r0 and f_r1.
    * Elek's roughness rule alpha1 <- max(alpha0, alpha1) is kept.
    """

    name = "ww-bati19"
    description = "Bati 2019 corrected Weidlich & Wilkie (eq. 5: T about n, Jacobian 1/eta^2, no TIR term)"
    variant = BATI19_VARIANT
