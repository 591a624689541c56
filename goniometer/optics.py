"""The single home of the project's microfacet, Fresnel and scattering-medium physics.

Every function here is a scalar ``numba.njit`` function (usable from the tracer's
kernel and from other njit code) unless its name starts with ``np_``, in which
case it is a vectorised NumPy ufunc of the scalar function it calls, compiled (or
loaded from numba's cache) on its first call, not at import (:class:`LazyUfunc`).

Conventions (shared by the whole project)
-----------------------------------------
* All directions are unit vectors that point **away** from the surface point:
  ``wi``/``l`` towards where the light comes from, ``wo``/``v`` towards where it goes.
* Functions work in a **local frame** whose z axis is the macro-surface normal
  of the side the light arrives from (callers flip z for light arriving from below
  and rotate x, y into the interface's tangent frame for anisotropic roughness).
* Roughness is the GGX (Trowbridge-Reitz) ``alpha`` along the local x and y axes,
  ``(ax, ay)``; isotropic callers pass ``ax == ay``.
* ``eta`` is always a *relative* index: (index on the far side) / (index on the
  side of ``wi``). Conductors take the relative complex index ``eta + i kappa``.
* BSDF values are returned **without** the cosine factor, in 1/sr.
* Transmission values are **flux based** ("importance" transport with wi = l): the
  fraction of incident power per unit projected solid angle. The radiance BTDF is
  this value times ``eta**2`` with ``eta = n_v / n_l`` (radiance is higher in the
  denser medium; see ``docs/slices-format.md``, transmission convention).
"""

from __future__ import annotations

import cmath
import math

import numba
import numpy as np

from goniometer.bits import double_as_int64, int64_as_double

_INV_PI = 1.0 / math.pi


# --------------------------------------------------------------------------- numerics

_TWO_PI = 2.0 * math.pi
# Taylor coefficients of sin and cos (of angles below 2 pi / 256)
_S3, _S5, _S7 = -1.0 / 6.0, 1.0 / 120.0, -1.0 / 5040.0
_C2, _C4, _C6 = -0.5, 1.0 / 24.0, -1.0 / 720.0


#: cos and sin of 2 pi j / 256, j = 0 .. 256 (within an ulp)
_TURN_STEPS = 256
_COS_TURN = np.cos(_TWO_PI * np.arange(_TURN_STEPS + 1) / _TURN_STEPS)
_SIN_TURN = np.sin(_TWO_PI * np.arange(_TURN_STEPS + 1) / _TURN_STEPS)
_COS_TURN[0], _SIN_TURN[0], _COS_TURN[_TURN_STEPS], _SIN_TURN[_TURN_STEPS] = 1.0, 0.0, 1.0, 0.0
_COS_TURN.setflags(write=False)
_SIN_TURN.setflags(write=False)


@numba.njit(cache=True, error_model='numpy', inline='always')
def cos_sin_2pi(u: float):
    """``(cos(2 pi u), sin(2 pi u))`` for ``u`` in [0, 1], without a libm call or branch.

    The turn is split exactly into ``j / 256`` and a rest ``d`` below ``2 pi / 256``; the cosine
    and sine of ``2 pi j / 256`` come from a table, those of the rest from their Taylor series to
    degree 6 / 7 (truncation < 1e-17), and the two are composed. Agrees with ``math.cos``/``math.sin``
    of ``2 pi u`` to a few ulp; ``cos_sin_2pi(0) = (1, 0)`` exactly. Inlined in the tracer it keeps
    its loops vectorised (the table reads are gathers from constant memory).
    """
    t = u * float(_TURN_STEPS)  # exact
    jf = math.floor(t)
    j = min(np.int64(jf), _TURN_STEPS)
    d = (t - jf) * (_TWO_PI / _TURN_STEPS)  # t - jf is exact
    d2 = d * d
    s = d + d * d2 * (_S3 + d2 * (_S5 + d2 * _S7))
    c = 1.0 + d2 * (_C2 + d2 * (_C4 + d2 * _C6))
    cj = _COS_TURN[j]
    sj = _SIN_TURN[j]
    return cj * c - sj * s, sj * c + cj * s


@numba.njit(cache=True, error_model='numpy', inline='always')
def cosine_from_disk(x: float, y: float):
    """A direction of the upper hemisphere with density ``cos theta / pi`` from a point ``(x, y)``
    uniform in the open unit disk (Malley's method: the disk point lifted onto the hemisphere),
    ``(x, y, sqrt(1 - x^2 - y^2))``, ``z > 0``."""
    return x, y, math.sqrt(1.0 - (x * x + y * y))


#: 2^(j / 64), j = 0 .. 63 (within an ulp)
_EXP_STEPS = 64
_EXP2_TABLE = 2.0 ** (np.arange(_EXP_STEPS) / _EXP_STEPS)
_EXP2_TABLE.setflags(write=False)
_INV_LN2_STEP = _EXP_STEPS / math.log(2.0)
# ln 2 / 64 in two parts (Cody-Waite): n times the first is exact for |n| < 2^21
_LN2_STEP_HI = 0.693147180369123816490 / _EXP_STEPS
_LN2_STEP_LO = 1.90821492927058770002e-10 / _EXP_STEPS


@numba.njit(cache=True, error_model='numpy', inline='always')
def exp_neg(x: float) -> float:
    """``exp(x)`` for ``x <= 0`` without a libm call, so that loops using it vectorise (LLVM has
    no vector form of libm's ``exp`` here): ``x = (64 k + j) ln 2 / 64 + r`` with ``|r| <= ln 2 / 128``
    (Cody-Waite split of ln 2), ``e^r`` by its Taylor series to degree 5 (truncation < 1e-16),
    ``2^(j / 64)`` from a table and ``2^k`` from the exponent bits. Within a few ulp of
    ``math.exp``; ``exp_neg(0) = 1`` exactly; arguments below -708 give ``exp(-708)`` (not
    denormals; callers use it for attenuation factors, where the difference is below 1e-307)."""
    x = max(x, -708.0)
    nf = math.floor(x * _INV_LN2_STEP + 0.5)
    r = (x - nf * _LN2_STEP_HI) - nf * _LN2_STEP_LO
    n = np.int64(nf)
    p = 1.0 + r * (1.0 + r * (0.5 + r * (1.0 / 6.0 + r * (1.0 / 24.0 + r * (1.0 / 120.0)))))
    return _EXP2_TABLE[n & (_EXP_STEPS - 1)] * p * _pow2(n >> 6)


@numba.njit(cache=True, error_model='numpy', inline='always')
def _pow2(k: int) -> float:
    """``2.0 ** k`` for ``-1022 <= k <= 1023``, from the exponent bits."""
    return int64_as_double((k + 1023) << 52)


#: log(1 + j / 64) and 1 / (1 + j / 64), j = 0 .. 64
_LOG_STEPS = 64
_LOG_TABLE = np.log1p(np.arange(_LOG_STEPS + 1) / _LOG_STEPS)
_INV_TABLE = 1.0 / (1.0 + np.arange(_LOG_STEPS + 1) / _LOG_STEPS)
_LOG_TABLE.setflags(write=False)
_INV_TABLE.setflags(write=False)
_LN2_HI = 0.693147180369123816490
_LN2_LO = 1.90821492927058770002e-10


@numba.njit(cache=True, error_model='numpy', inline='always')
def log_pos(x: float) -> float:
    """``log(x)`` for a positive normal ``x`` without a libm call, so that loops using it vectorise:
    ``x = 2^e m`` (``m`` in [1, 2), from the bits), ``m = (1 + j / 64)(1 + r)`` with ``j`` the top six
    bits of the mantissa and ``0 <= r < 1 / 64``, ``log(1 + r)`` by its series to degree 9
    (truncation < 1e-18) and ``log(1 + j / 64)`` from a table; ``e ln 2`` in two parts. Error below
    ``1e-15 max(1, |log x|)`` (a few ulp where ``|log x| >= 0.5``; absolute near ``x = 1``, which is
    what counts where the walks use it, for probabilities); ``log_pos(1) = 0`` exactly."""
    b = double_as_int64(x)
    e = ((b >> 52) & 0x7FF) - 1023
    j = (b >> 46) & 0x3F
    m = int64_as_double((b & 0xFFFFFFFFFFFFF) | (1023 << 52))
    r = m * _INV_TABLE[j] - 1.0
    p = r * (1.0 + r * (-0.5 + r * (1.0 / 3.0 + r * (-0.25 + r * (0.2 + r * (-1.0 / 6.0 + r * (
        1.0 / 7.0 + r * (-0.125 + r * (1.0 / 9.0)))))))))
    ef = float(e)
    return (ef * _LN2_HI + _LOG_TABLE[j]) + (p + ef * _LN2_LO)


# --------------------------------------------------------------------------- Fresnel

@numba.njit(cache=True, error_model='numpy')
def fresnel_dielectric_cos_t(cos_i: float, eta: float):
    """Exact unpolarised Fresnel reflectance of a dielectric boundary and the refracted cosine.

    ``cos_i`` is the cosine between the incident direction and the (micro)normal
    on the incident side (its absolute value is used). ``eta`` = n_far / n_near.
    Returns ``(F, cos_t)``: total internal reflection gives ``(1, 0)``; ``eta == 1`` gives
    ``(0, cos_i)``; otherwise grazing incidence (``cos_i = 0``) gives ``(1, cos_t)``.
    """
    return fresnel_dielectric_cos_t_inv(cos_i, eta, 1.0 / eta)


@numba.njit(cache=True, error_model='numpy', inline='always')
def fresnel_dielectric_terms(cos_i: float, eta: float, inv_eta: float):
    """The parts of :func:`fresnel_dielectric_cos_t_inv`: ``(num, den, cos_t, tir)`` with the
    reflectance ``min(1, num / den)`` unless ``tir`` (total internal reflection: 1) or ``eta = 1``
    (0), ``den > 0``; for callers that share the division with other fractions."""
    c = min(abs(cos_i), 1.0)
    sin2_t = (1.0 - c * c) * (inv_eta * inv_eta)
    tir = sin2_t >= 1.0
    cos_t = math.sqrt(max(0.0, 1.0 - sin2_t))
    # r_s = a / b, r_p = p / q: F = (r_s^2 + r_p^2) / 2 over a common denominator
    a = c - eta * cos_t
    b = c + eta * cos_t
    p = eta * c - cos_t
    q = eta * c + cos_t
    bq = b * q
    cos_t = c if eta == 1.0 else (0.0 if tir else cos_t)
    return 0.5 * (a * a * (q * q) + p * p * (b * b)), max(bq * bq, 1e-300), cos_t, tir


@numba.njit(cache=True, error_model='numpy', inline='always')
def fresnel_dielectric_select(ratio: float, eta: float, tir: bool) -> float:
    """The reflectance from the parts of :func:`fresnel_dielectric_terms` (``ratio = num / den``)."""
    f = min(1.0, ratio)
    return 0.0 if eta == 1.0 else (1.0 if tir else f)


@numba.njit(cache=True, error_model='numpy')
def fresnel_dielectric_cos_t_inv(cos_i: float, eta: float, inv_eta: float):
    """:func:`fresnel_dielectric_cos_t` for callers that already hold ``inv_eta = 1 / eta``
    (the tracer precomputes both per interface, which keeps divisions off its critical path).

    Written without branches (selects only, square roots of ``max(0, x)``, one division), so that
    the tracer's lane loop vectorises with it inlined."""
    c = min(abs(cos_i), 1.0)
    if eta != 1.0 and (1.0 - c * c) * (inv_eta * inv_eta) >= 1.0:
        # total internal reflection: nothing else to compute (scalar callers, e.g. the walks)
        return 1.0, 0.0
    num, den, cos_t, tir = fresnel_dielectric_terms(cos_i, eta, inv_eta)
    return fresnel_dielectric_select(num / den, eta, tir), cos_t


@numba.njit(cache=True, error_model='numpy')
def fresnel_dielectric(cos_i: float, eta: float) -> float:
    """Exact unpolarised Fresnel reflectance of a dielectric boundary (see
    :func:`fresnel_dielectric_cos_t`): total internal reflection returns 1, ``eta == 1``
    returns 0, otherwise grazing incidence returns 1."""
    return fresnel_dielectric_cos_t(cos_i, eta)[0]


@numba.njit(cache=True, error_model='numpy', inline='always')
def _conductor_terms(cos_i: float, eta: float, kappa: float):
    """``(num, den)`` with the conductor reflectance ``num / den`` (:func:`fresnel_conductor`)."""
    c = min(abs(cos_i), 1.0)
    c2 = c * c
    s2 = 1.0 - c2
    t = eta * eta - kappa * kappa - s2
    a2b2 = math.sqrt(max(0.0, t * t + 4.0 * eta * eta * kappa * kappa))
    a = math.sqrt(max(0.0, 0.5 * (a2b2 + t)))
    t1 = a2b2 + c2
    t2 = 2.0 * a * c
    t3 = a2b2 * c2 + s2 * s2
    t4 = t2 * s2
    return (t1 - t2) * t3, (t1 + t2) * (t3 + t4)


@numba.njit(cache=True, error_model='numpy')
def fresnel_conductor(cos_i: float, eta: float, kappa: float) -> float:
    """Exact unpolarised Fresnel reflectance for a complex relative index ``eta + i kappa``.

    Valid for any ``kappa >= 0`` (``kappa = 0`` gives the dielectric result, total internal
    reflection included). ``cos_i`` as in :func:`fresnel_dielectric`. Real-arithmetic form
    (Born & Wolf): with ``a^2 + b^2 = sqrt((eta^2 - kappa^2 - sin^2)^2 + 4 eta^2 kappa^2)`` and
    ``a = sqrt((a^2 + b^2 + eta^2 - kappa^2 - sin^2) / 2)`` (``a + i b = sqrt(n^2 - sin^2)``),
    ``Rs = (a^2+b^2 - 2a cos + cos^2) / (a^2+b^2 + 2a cos + cos^2)`` and
    ``Rp = Rs (a^2+b^2 cos^2 - 2a cos sin^2 + sin^4) / (a^2+b^2 cos^2 + 2a cos sin^2 + sin^4)``,
    so ``(Rs + Rp) / 2 = Rs t3 / (t3 + t4)`` with the last fraction's terms: one division, no
    branch (selects only), so that the tracer's lane loop vectorises with it inlined.
    """
    num, den = _conductor_terms(cos_i, eta, kappa)
    # den = 0 only for the degenerate index 0 at normal incidence, a perfect reflector
    f = num / den if den > 0.0 else 1.0
    return 0.0 if (eta == 1.0 and kappa == 0.0) else f


@numba.njit(cache=True, error_model='numpy', inline='always')
def fresnel_conductor_rgb(cos_i: float, eta0: float, kappa0: float, eta1: float, kappa1: float, eta2: float,
                          kappa2: float, num: float = 0.0, den: float = 1.0):
    """:func:`fresnel_conductor` of three channels with one division between them (each
    denominator lies between ``|n|^2``-sized bounds away from 0 and overflow, so their product
    is safe; a few ulp from the per-channel values); also a caller's fraction ``num / den``
    (``den`` > 0, bounded) from the same division: ``(F0, F1, F2, num / den)``."""
    n0, d0 = _conductor_terms(cos_i, eta0, kappa0)
    n1, d1 = _conductor_terms(cos_i, eta1, kappa1)
    n2, d2 = _conductor_terms(cos_i, eta2, kappa2)
    e0 = d0 if d0 > 0.0 else 1.0
    e1 = d1 if d1 > 0.0 else 1.0
    e2 = d2 if d2 > 0.0 else 1.0
    inv = 1.0 / (e0 * e1 * e2 * den)
    f0 = n0 * (e1 * e2 * den) * inv if d0 > 0.0 else 1.0
    f1 = n1 * (e0 * e2 * den) * inv if d1 > 0.0 else 1.0
    f2 = n2 * (e0 * e1 * den) * inv if d2 > 0.0 else 1.0
    return (0.0 if (eta0 == 1.0 and kappa0 == 0.0) else f0, 0.0 if (eta1 == 1.0 and kappa1 == 0.0) else f1,
            0.0 if (eta2 == 1.0 and kappa2 == 0.0) else f2, num * (e0 * e1 * e2) * inv)


@numba.njit(cache=True, error_model='numpy', inline='always')
def fresnel_conductor_pair(cos_i: float, eta0: float, kappa0: float, eta1: float, kappa1: float, num: float = 0.0,
                           den: float = 1.0):
    """:func:`fresnel_conductor_rgb` for two channels (RGB indices with two channels alike); also
    a caller's fraction ``num / den`` (``den`` > 0, bounded, e.g. the dielectric Fresnel of the
    same cosine) from the same division: ``(F0, F1, num / den)``."""
    n0, d0 = _conductor_terms(cos_i, eta0, kappa0)
    n1, d1 = _conductor_terms(cos_i, eta1, kappa1)
    e0 = d0 if d0 > 0.0 else 1.0
    e1 = d1 if d1 > 0.0 else 1.0
    inv = 1.0 / (e0 * e1 * den)
    f0 = n0 * (e1 * den) * inv if d0 > 0.0 else 1.0
    f1 = n1 * (e0 * den) * inv if d1 > 0.0 else 1.0
    return (0.0 if (eta0 == 1.0 and kappa0 == 0.0) else f0, 0.0 if (eta1 == 1.0 and kappa1 == 0.0) else f1,
            num * (e0 * e1) * inv)


@numba.njit(cache=True, error_model='numpy', inline='always')
def fresnel_conductor_channels(cos_i: float, eta0: float, kappa0: float, eta1: float, kappa1: float, eta2: float,
                               kappa2: float, g_is_r: bool, b_is_g: bool):
    """The three channels' conductor Fresnel reflectances: computed once for channels that share
    their complex index (``g_is_r``: green has red's, ``b_is_g``: blue has green's), the others
    with one division between them (:func:`fresnel_conductor_pair`, :func:`fresnel_conductor_rgb`)."""
    if g_is_r and b_is_g:
        r0 = fresnel_conductor(cos_i, eta0, kappa0)
        return r0, r0, r0
    if b_is_g:
        r0, r1, _ = fresnel_conductor_pair(cos_i, eta0, kappa0, eta1, kappa1)
        return r0, r1, r1
    if g_is_r:
        r0, r2, _ = fresnel_conductor_pair(cos_i, eta0, kappa0, eta2, kappa2)
        return r0, r0, r2
    r0, r1, r2, _ = fresnel_conductor_rgb(cos_i, eta0, kappa0, eta1, kappa1, eta2, kappa2)
    return r0, r1, r2


# --------------------------------------------------------------------------- thin films
#
# A thin film on an interface: three media, the region on the side the light arrives from (real
# index n1), the film (nf + i kf, thickness d) and the far side (n3 + i k3: the medium below, a
# conductor's complex index, or, seen from below, the region above). Amplitudes summed over the
# film's internal reflections (Airy), s and p separately, the intensities averaged. Written with
# real arithmetic only (complex numbers as pairs), branch-free and libm-free, so that the lane
# kernel's loop vectorises with it inlined (docs/kernel.md).

@numba.njit(cache=True, error_model='numpy', inline='always')
def _cmul(ar: float, ai: float, br: float, bi: float):
    """The complex product ``(ar + i ai)(br + i bi)``."""
    return ar * br - ai * bi, ar * bi + ai * br


@numba.njit(cache=True, error_model='numpy', inline='always')
def _csqrt(ar: float, ai: float):
    """The principal square root of ``ar + i ai`` (real part >= 0; imaginary part of the sign of
    ``ai``, ``ai = -0`` counting as positive), in the form without cancellation."""
    m = math.sqrt(ar * ar + ai * ai)
    t = math.sqrt(0.5 * (m + abs(ar)))
    h = 0.5 * abs(ai) / max(t, 1e-300)
    s = t if ai >= 0.0 else -t
    hs = h if ai >= 0.0 else -h
    return (t if ar >= 0.0 else h), (hs if ar >= 0.0 else s)


@numba.njit(cache=True, error_model='numpy', inline='always')
def film_rt_terms(cos_i: float, n1: float, nf: float, kf: float, n3: float, k3: float, d_lam: float):
    """:func:`film_rt` as its parts ``(Rs_num, Ts_num, s_den, Rp_num, Tp_num, p_den)``: ``R = (Rs_num /
    s_den + Rp_num / p_den) / 2`` and likewise ``T`` (``s_den, p_den > 0``), for callers that share
    the divisions of several channels."""
    c = min(abs(cos_i), 1.0)
    # n^2 sin^2 theta, the invariant of Snell's law
    s2 = n1 * n1 * (1.0 - c * c)
    q1 = n1 * c
    # the film: nf^2 and q2 = sqrt(nf^2 - s2) (Im >= 0: the field decays into an absorbing film)
    a2r = nf * nf - kf * kf
    a2i = 2.0 * nf * kf
    q2r, q2i = _csqrt(a2r - s2, a2i)
    # (q2 = 0, the film's own critical angle, makes the Airy sum 0 / 0: a limit the result reaches
    # smoothly, and an even function of q2; q2 is kept 1e-8 away from it)
    tiny = q2r * q2r + q2i * q2i < 1e-16
    q2r = 1e-8 if tiny else q2r
    # the far side: q3 with Im >= 0 (decays in a conductor, evanescent beyond total reflection)
    a3r = n3 * n3 - k3 * k3
    a3i = 2.0 * n3 * k3
    q3r, q3i = _csqrt(a3r - s2, a3i)
    # E = exp(2 i beta), beta = 2 pi (d / lambda) q2: |E| = exp(-4 pi (d / lambda) Im q2), phase 2 beta
    # in turns 2 (d / lambda) Re q2 (>= 0), reduced to [0, 1)
    u = 2.0 * d_lam * q2r
    u = u - math.floor(u)
    ce, se = cos_sin_2pi(u)
    ea = exp_neg(-4.0 * math.pi * d_lam * q2i)
    er = ea * ce
    ei = ea * se
    # s: eta = q; r_ij = (q_i - q_j) / (q_i + q_j)
    n12r = q1 - q2r
    n12i = -q2i
    p12r = q1 + q2r
    p12i = q2i
    n23r = q2r - q3r
    n23i = q2i - q3i
    p23r = q2r + q3r
    p23i = q2i + q3i
    rs_num, s_den = _airy(n12r, n12i, p12r, p12i, n23r, n23i, p23r, p23i, er, ei)
    # T_s = 16 q1 Re(q3) |q2|^2 |E| / |P12 P23 + N12 N23 E|^2
    ts_num = 16.0 * q1 * max(q3r, 0.0) * (q2r * q2r + q2i * q2i) * ea
    # p: eta = n^2 / q; r_ij = (a_i q_j - a_j q_i) / (a_i q_j + a_j q_i), a = n^2 (a1 = n1^2 real)
    a1 = n1 * n1
    a2q1r = a2r * q1
    a2q1i = a2i * q1
    n12r = a1 * q2r - a2q1r
    n12i = a1 * q2i - a2q1i
    p12r = a1 * q2r + a2q1r
    p12i = a1 * q2i + a2q1i
    x1r, x1i = _cmul(a2r, a2i, q3r, q3i)
    x2r, x2i = _cmul(a3r, a3i, q2r, q2i)
    n23r = x1r - x2r
    n23i = x1i - x2i
    p23r = x1r + x2r
    p23i = x1i + x2i
    rp_num, p_den = _airy(n12r, n12i, p12r, p12i, n23r, n23i, p23r, p23i, er, ei)
    # T_p = 16 a1 q1 Re(a3 conj(q3)) |a2 q2|^2 |E| / |P12 P23 + N12 N23 E|^2
    a2q2r, a2q2i = _cmul(a2r, a2i, q2r, q2i)
    tp_num = 16.0 * a1 * q1 * max(a3r * q3r + a3i * q3i, 0.0) * (a2q2r * a2q2r + a2q2i * a2q2i) * ea
    return rs_num, ts_num, s_den, rp_num, tp_num, p_den


@numba.njit(cache=True, error_model='numpy', inline='always')
def _airy(n12r, n12i, p12r, p12i, n23r, n23i, p23r, p23i, er, ei):
    """``(|N12 P23 + N23 P12 E|^2, max(|P12 P23 + N12 N23 E|^2, 1e-300))``: the Airy sum's
    reflectance ``r = (r12 + r23 E) / (1 + r12 r23 E)`` as a fraction, ``r_ij = N_ij / P_ij``."""
    ar, ai = _cmul(n12r, n12i, p23r, p23i)
    br, bi = _cmul(n23r, n23i, p12r, p12i)
    br, bi = _cmul(br, bi, er, ei)
    cr, ci = _cmul(p12r, p12i, p23r, p23i)
    dr, di = _cmul(n12r, n12i, n23r, n23i)
    dr, di = _cmul(dr, di, er, ei)
    nr = ar + br
    ni = ai + bi
    mr = cr + dr
    mi = ci + di
    return nr * nr + ni * ni, max(mr * mr + mi * mi, 1e-300)


@numba.njit(cache=True, error_model='numpy')
def film_rt(cos_i: float, n1: float, nf: float, kf: float, n3: float, k3: float, d_lam: float):
    """Unpolarised reflectance and transmittance ``(R, T)`` of a thin film (Airy summation; Born &
    Wolf 1.6, Macleod's admittances; ``docs/material-format.md``, thin films).

    The light arrives at ``cos_i`` (its absolute value is used) from a medium of real index
    ``n1`` onto a film of complex index ``nf + i kf`` and thickness ``d``, behind which lies
    ``n3 + i k3``; ``d_lam = d / lambda`` (the thickness in vacuum wavelengths). Indices may be
    absolute or all relative to one medium (only their ratios and ``nf d / lambda`` in absolute
    units count: pass absolute indices with the vacuum wavelength). With ``q_j = n_j cos theta_j``
    (``sqrt(n_j^2 - n1^2 sin^2 theta_1)``, the branch with ``Im >= 0``, so that the field decays
    in an absorbing film or substrate and beyond total reflection), the admittances ``eta_s = q``,
    ``eta_p = n^2 / q`` give ``r_ij = (eta_i - eta_j) / (eta_i + eta_j)``, the phase
    ``beta = 2 pi d q_2 / lambda``, ``r = (r12 + r23 e^{2 i beta}) / (1 + r12 r23 e^{2 i beta})``,
    ``R = |r|^2`` and ``T = Re(eta_3) / eta_1 |t|^2`` (the power crossing into the far medium;
    0 beyond total reflection). Each polarisation's ``R`` and ``T`` are fractions of one
    denominator; ``R`` and ``T`` are the means of the s and p values. A non-absorbing film between
    non-absorbing media gives ``R + T = 1``; ``d = 0`` gives the bare interface's Fresnel terms."""
    rs, ts, ds, rp, tp, dp = film_rt_terms(cos_i, n1, nf, kf, n3, k3, d_lam)
    return 0.5 * (rs / ds + rp / dp), 0.5 * (ts / ds + tp / dp)


@numba.njit(cache=True, error_model='numpy', inline='always')
def film_rt_channel(cos_i: float, n1: float, nf: float, kf: float, n3: float, k3: float, d_lam: float):
    """:func:`film_rt` with one division (for the lane kernel, which inlines it)."""
    rs, ts, ds, rp, tp, dp = film_rt_terms(cos_i, n1, nf, kf, n3, k3, d_lam)
    inv = 0.5 / (ds * dp)
    return (rs * dp + rp * ds) * inv, (ts * dp + tp * ds) * inv


# --------------------------------------------------------------------------- polarization (Mueller calculus)
#
# Conventions (docs/polarization.md): a beam travelling along k carries a Stokes vector (S0, S1, S2,
# S3) in a frame (x, y = k x x): S1 > 0 linear along x, S2 > 0 along (x + y) / sqrt 2, S3 > 0 right
# circular -- Mitsuba 3's convention (fields as exp(+i omega t), complex indices n - i k inside the
# formulas, the "Verdet" sign of r_p: r_p = -r_s at normal incidence). A Fresnel event (reflection or
# refraction on a plane) has, in the frames x = s (the unit normal of the plane of incidence, the
# same vector for the beam before and after) and y = k x s, the Mueller matrix
#
#     [[a, b, 0, 0], [b, a, 0, 0], [0, 0, c, s], [0, 0, -s, c]]
#
# with a = (|r_s|^2 + |r_p|^2) / 2, b = (|r_s|^2 - |r_p|^2) / 2, c = Re(r_s r_p*), s = Im(r_s r_p*)
# for a reflection (a is the unpolarized reflectance), and the same of the transmission amplitudes
# times n_t cos(theta_t) / (n_i cos(theta_i)) for a refraction (a is the unpolarized transmittance).
# The functions below return these four numbers; :func:`mueller_event` applies them.


@numba.njit(cache=True, error_model='numpy')
def _verdet(cos_i: float, eta: complex, cos_t: complex):
    """The reflection and transmission amplitudes ``(r_s, r_p, t_s, t_p)`` of a plane interface
    (Verdet's sign of ``r_p``) for the relative index ``eta`` (n - i k form) and ``cos_t``."""
    ec = eta * cos_t
    rs = (cos_i - ec) / (cos_i + ec)
    rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    ts = 2.0 * cos_i / (cos_i + ec)
    tp = 2.0 * cos_i / (eta * cos_i + cos_t)
    return rs, rp, ts, tp


@numba.njit(cache=True, error_model='numpy')
def mueller_terms(x: complex, y: complex, factor: float):
    """``(a, b, c, s)`` of the Mueller matrix of the Jones matrix ``diag(x, y)`` (s and p) times
    ``factor`` (see the section's comment)."""
    xx = x.real * x.real + x.imag * x.imag
    yy = y.real * y.real + y.imag * y.imag
    z = x * y.conjugate()
    return 0.5 * factor * (xx + yy), 0.5 * factor * (xx - yy), factor * z.real, factor * z.imag


@numba.njit(cache=True, error_model='numpy', inline='always')
def fresnel_dielectric_mueller(cos_i: float, eta: float):
    """The Fresnel event of a dielectric interface, relative index ``eta`` (far side / arrival side),
    light arriving at ``cos_i`` in (0, 1]: ``(ra, rb, rc, rs, ta, tb, tc, ts)``, the reflection's and
    the refraction's ``(a, b, c, s)`` (section comment). Beyond the critical angle the reflection
    keeps all the light with a retardance between s and p (``rs != 0``) and the refraction is 0.
    ``ra`` equals :func:`fresnel_dielectric` (``cos_i``, ``eta``). Real arithmetic and selects
    (the lane kernel's event vectorises it)."""
    sin2_t = (1.0 - cos_i * cos_i) / (eta * eta)
    tir = sin2_t >= 1.0
    # below the critical angle every amplitude is real (as _verdet's formulas give them)
    ct = math.sqrt(max(1.0 - sin2_t, 0.0))
    ec = eta * ct
    rs = (cos_i - ec) / (cos_i + ec)
    rp = (eta * cos_i - ct) / (eta * cos_i + ct)
    ts = 2.0 * cos_i / (cos_i + ec)
    tp = 2.0 * cos_i / (eta * cos_i + ct)
    f = ec / cos_i
    # total internal reflection: cos_t = -i q, q = sqrt(sin^2_t - 1) (the decaying wave of
    # exp(+i omega t)); r_s = (c + i eta q) / (c - i eta q), r_p = (eta c + i q) / (eta c - i q), both
    # of modulus 1: a = 1, b = 0, c + i s = r_s conj(r_p)
    q = math.sqrt(max(sin2_t - 1.0, 0.0))
    u = eta * q
    ds = 1.0 / (cos_i * cos_i + u * u)
    srr = (cos_i * cos_i - u * u) * ds
    sri = 2.0 * cos_i * u * ds
    v = eta * cos_i
    dp = 1.0 / (v * v + q * q)
    prr = (v * v - q * q) * dp
    pri = 2.0 * v * q * dp
    return (1.0 if tir else 0.5 * (rs * rs + rp * rp), 0.0 if tir else 0.5 * (rs * rs - rp * rp),
            srr * prr + sri * pri if tir else rs * rp, sri * prr - srr * pri if tir else 0.0,
            0.0 if tir else 0.5 * f * (ts * ts + tp * tp), 0.0 if tir else 0.5 * f * (ts * ts - tp * tp),
            0.0 if tir else f * ts * tp, 0.0)


@numba.njit(cache=True, error_model='numpy', inline='always')
def fresnel_conductor_mueller(cos_i: float, eta: float, kappa: float):
    """The reflection ``(a, b, c, s)`` of a conductor of relative complex index ``eta + i kappa``
    (the graphics convention, ``kappa >= 0``; the formulas use ``n = eta - i kappa``), light arriving
    at ``cos_i`` in (0, 1]. ``a`` equals :func:`fresnel_conductor` (``cos_i``, ``eta``, ``kappa``).
    Real arithmetic without branches (the lane kernel's event vectorises it): ``cos_t =
    sqrt(1 - sin^2 / n^2)`` on the branch that decays into the metal (``Im cos_t <= 0``), then
    ``r_s = (c - n cos_t) / (c + n cos_t)``, ``r_p = (n c - cos_t) / (n c + cos_t)``."""
    s2 = 1.0 - cos_i * cos_i
    e2 = eta * eta - kappa * kappa          # n^2 = e2 - i m2
    m2 = 2.0 * eta * kappa
    inv = s2 / (e2 * e2 + m2 * m2)
    zr = 1.0 - e2 * inv                     # z = 1 - sin^2 / n^2 = zr + i zi, zi <= 0
    zi = -m2 * inv
    # cos_t = sr - i si: the larger part from sqrt((|z| + |zr|) / 2), the other as |zi| / (2 that) (no
    # cancellation)
    t = math.sqrt(0.5 * (math.sqrt(zr * zr + zi * zi) + abs(zr)))
    o = -zi / (2.0 * max(t, 1e-300))
    sr = t if zr >= 0.0 else o
    si = o if zr >= 0.0 else t
    # n cos_t = u - i w
    u = eta * sr - kappa * si
    w = eta * si + kappa * sr
    # r_s = N_s / D_s = (c - u + i w) / (c + u - i w); r_p = N_p / D_p = (n c - cos_t) / (n c + cos_t),
    # n c = eta c - i kappa c; |r|^2 = |N|^2 / |D|^2 and r_s conj(r_p) = N_s conj(N_p) / (D_s conj(D_p))
    nsr, nsi, dsr, dsi = cos_i - u, w, cos_i + u, -w
    npr, npi, dpr, dpi = eta * cos_i - sr, si - kappa * cos_i, eta * cos_i + sr, -kappa * cos_i - si
    ds2 = dsr * dsr + dsi * dsi
    dp2 = dpr * dpr + dpi * dpi
    rs2 = (nsr * nsr + nsi * nsi) / ds2
    rp2 = (npr * npr + npi * npi) / dp2
    xr = nsr * npr + nsi * npi          # N_s conj(N_p)
    xi = nsi * npr - nsr * npi
    yr = dsr * dpr + dsi * dpi          # D_s conj(D_p)
    yi = dsi * dpr - dsr * dpi
    q = 1.0 / (ds2 * dp2)
    return 0.5 * (rs2 + rp2), 0.5 * (rs2 - rp2), (xr * yr + xi * yi) * q, (xi * yr - xr * yi) * q


@numba.njit(cache=True, error_model='numpy')
def film_mueller(cos_i: float, n1: float, nf: float, kf: float, n3: float, k3: float, d_lam: float):
    """The Fresnel event of a thin film (:func:`film_rt`'s arguments and Airy summation, with the
    amplitudes' phases): ``(ra, rb, rc, rs, ta, tb, tc, ts)`` as :func:`fresnel_dielectric_mueller`
    returns them. ``ra`` and ``ta`` equal :func:`film_rt`'s ``R`` and ``T``. The far side ``n3 + i
    k3`` may absorb (a conductor: no transmission is asked for there)."""
    c = min(abs(cos_i), 1.0)
    n1c = complex(n1, 0.0)
    n2 = complex(nf, -kf)
    n3c = complex(n3, -k3)
    s = n1 * math.sqrt(max(1.0 - c * c, 0.0))
    # cos theta_j with the branch of decay (Im <= 0) in the film and the far side
    c2 = cmath.sqrt(1.0 - (s / n2) * (s / n2))
    if c2.imag > 0.0:
        c2 = c2.conjugate()
    c3 = cmath.sqrt(1.0 - (s / n3c) * (s / n3c))
    if c3.imag > 0.0:
        c3 = c3.conjugate()
    r12s, r12p, t12s, t12p = _verdet(c, n2 / n1c, c2)
    r23s, r23p, t23s, t23p = _verdet(c2, n3c / n2, c3)
    # the phase thickness: fields as exp(+i omega t), exp(-i beta) per traversal, Im(beta) < 0 decays
    beta = 2.0 * math.pi * d_lam * n2 * c2
    e1 = cmath.exp(complex(0.0, -1.0) * beta)
    e2 = e1 * e1
    ds = 1.0 + r12s * r23s * e2
    dp = 1.0 + r12p * r23p * e2
    rs = (r12s + r23s * e2) / ds
    rp = (r12p + r23p * e2) / dp
    ra, rb, rc, rs_ = mueller_terms(rs, rp, 1.0)
    q3 = n3c * c3
    if k3 != 0.0 or q3.real <= 0.0:
        return ra, rb, rc, rs_, 0.0, 0.0, 0.0, 0.0
    ts = t12s * t23s * e1 / ds
    tp = t12p * t23p * e1 / dp
    ta, tb, tc, tsn = mueller_terms(ts, tp, q3.real / (n1 * c))
    return ra, rb, rc, rs_, ta, tb, tc, tsn


@numba.njit(cache=True, error_model='numpy', inline='always')
def stokes_rotation(kx: float, ky: float, kz: float, xx: float, xy: float, xz: float, sx: float, sy: float,
                    sz: float):
    """``(cos 2 theta, sin 2 theta)`` of the rotation by ``theta`` about the beam's direction ``k``
    that takes its frame's ``x`` to ``s`` (both unit, normal to ``k``): the rotation of a Stokes
    vector into the new frame is ``S1' = cos 2 theta S1 + sin 2 theta S2``, ``S2' = -sin 2 theta S1 +
    cos 2 theta S2`` (Mitsuba 3's ``rotator(theta)``)."""
    c = xx * sx + xy * sy + xz * sz
    si = kx * (xy * sz - xz * sy) + ky * (xz * sx - xx * sz) + kz * (xx * sy - xy * sx)
    return c * c - si * si, 2.0 * c * si


@numba.njit(cache=True, error_model='numpy', inline='always')
def mueller_rotate(m, ch: int, c2: float, s2: float) -> None:
    """Re-express channel ``ch`` of the accumulated Mueller matrices ``m`` ((C, 16), row-major 4 x 4
    each: incident Stokes vector -> the beam's) in the frame rotated by ``theta`` (cos and sin of
    ``2 theta`` from :func:`stokes_rotation`)."""
    for j in range(4):
        r1 = m[ch, 4 + j]
        r2 = m[ch, 8 + j]
        m[ch, 4 + j] = c2 * r1 + s2 * r2
        m[ch, 8 + j] = c2 * r2 - s2 * r1


@numba.njit(cache=True, error_model='numpy', inline='always')
def mueller_event(m, ch: int, a: float, b: float, c: float, s: float, f: float) -> None:
    """Apply a Fresnel event ``(a, b, c, s)`` (section comment) times ``f`` to channel ``ch`` of the
    accumulated Mueller matrices ``m`` (already in the event's frames)."""
    for j in range(4):
        r0 = m[ch, j]
        r1 = m[ch, 4 + j]
        r2 = m[ch, 8 + j]
        r3 = m[ch, 12 + j]
        m[ch, j] = f * (a * r0 + b * r1)
        m[ch, 4 + j] = f * (b * r0 + a * r1)
        m[ch, 8 + j] = f * (c * r2 + s * r3)
        m[ch, 12 + j] = f * (c * r3 - s * r2)


@numba.njit(cache=True, error_model='numpy', inline='always')
def mueller_depolarize(m, ch: int, f: float) -> None:
    """A depolarizing event of albedo ``f`` on channel ``ch`` (a Lambertian base, a
    Henyey-Greenstein scattering: the light leaves unpolarized, ``docs/polarization.md``)."""
    for j in range(4):
        m[ch, j] *= f
        m[ch, 4 + j] = 0.0
        m[ch, 8 + j] = 0.0
        m[ch, 12 + j] = 0.0


@numba.njit(cache=True, error_model='numpy', inline='always')
def normal_frame(kx: float, ky: float, kz: float, hx: float, hy: float):
    """The unit ``s = normalize(z x k)`` of a beam along ``k``: normal to the plane of ``k`` and the
    surface normal ``z`` (the goniometer's s/p frame, ``docs/polarization.md``). Along the normal,
    where that plane is not defined, the limit ``(-hy, hx, 0)`` of a beam whose horizontal part
    points along the unit ``(hx, hy)`` (``-(cos phi_l, sin phi_l)`` for the incident beam ``-l``,
    ``(cos phi_v, sin phi_v)`` for an exit ``v``)."""
    n2 = kx * kx + ky * ky
    if n2 < 1e-30:
        return -hy, hx, 0.0
    inv = 1.0 / math.sqrt(n2)
    return -ky * inv, kx * inv, 0.0


# --------------------------------------------------------------------------- GGX

@numba.njit(cache=True, error_model='numpy')
def ggx_d(mx: float, my: float, mz: float, ax: float, ay: float) -> float:
    """GGX normal distribution D(m) in 1/sr, normalised so that Int D(m) m_z dm = 1.

    ``m`` is a unit microfacet normal in the local frame; 0 below the horizon.
    Requires ``ax, ay > 0`` (a perfectly smooth interface has no density).
    """
    if mz <= 0.0:
        return 0.0
    x = mx / ax
    y = my / ay
    t = x * x + y * y + mz * mz
    return _INV_PI / (ax * ay * t * t)


@numba.njit(cache=True, error_model='numpy')
def ggx_lambda(vx: float, vy: float, vz: float, ax: float, ay: float) -> float:
    """Smith Lambda(v) of the GGX distribution (Heitz 2014, eq. 86); uses |v_z|."""
    z2 = vz * vz
    a2t2 = ax * ax * vx * vx + ay * ay * vy * vy
    if a2t2 <= 0.0:
        return 0.0
    if z2 <= 0.0:
        return math.inf
    return 0.5 * (math.sqrt(1.0 + a2t2 / z2) - 1.0)


@numba.njit(cache=True, error_model='numpy')
def smith_g1(vx: float, vy: float, vz: float, v_dot_m: float, ax: float, ay: float) -> float:
    """Smith masking G1(v, m) = chi+(v.m / v.n) / (1 + Lambda(v)).

    ``v`` may lie on either side of the macro-surface (transmission); the
    characteristic function requires v.m and v.n to have the same sign.
    """
    if v_dot_m * vz <= 0.0:
        return 0.0
    return smith_g1_dir(vx, vy, vz, ax, ay)


@numba.njit(cache=True, error_model='numpy', inline='always')
def smith_g1_dir(vx: float, vy: float, vz: float, ax: float, ay: float) -> float:
    """Smith masking of a direction, ``1 / (1 + Lambda(v))`` (GGX; uses ``|v_z|``, no microfacet
    test), written ``2 |v_z| / (|v_z| + sqrt(v_z^2 + ax^2 v_x^2 + ay^2 v_y^2))``: one division,
    no cancellation. 0 for a horizontal direction, 1 for the normal. Computed in the precision of
    its arguments (float32 arguments: float32, within a few float32 ulp)."""
    z = abs(vz)
    d = z + math.sqrt(abs(z * z + (ax * ax * vx * vx + ay * ay * vy * vy)))
    return (z + z) / d if z > 0.0 else z - z


@numba.njit(cache=True, error_model='numpy')
def log_beta(a: float, b: float) -> float:
    """log of the Euler Beta function B(a, b) for a, b > 0."""
    return math.lgamma(a) + math.lgamma(b) - math.lgamma(a + b)


_HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)


@numba.njit(cache=True, error_model='numpy', inline='always')
def log_gamma_ge1(x: float) -> float:
    """``log Gamma(x)`` for ``x >= 1`` without a libm call, so that loops using it vectorise
    (:func:`log_beta` calls libm's ``lgamma``): below 9 the recurrence ``Gamma(x) = Gamma(x + 8) /
    (x (x + 1) ... (x + 7))``, then Stirling's series to its ``x^-9`` term on :func:`log_pos` (the
    first omitted term is below 6.2e-14 at 9): within 1e-13 plus a few ulp of ``log Gamma(x)``
    (5e-13 up to x = 200, against ``math.lgamma``)."""
    small = x < 9.0
    y = x + 8.0 if small else x
    p = x * (x + 1.0) * (x + 2.0) * (x + 3.0) * (x + 4.0) * (x + 5.0) * (x + 6.0) * (x + 7.0) if small else 1.0
    r = 1.0 / y
    r2 = r * r
    series = r * (1.0 / 12.0 + r2 * (-1.0 / 360.0 + r2 * (1.0 / 1260.0 + r2 * (-1.0 / 1680.0 + r2 * (1.0 / 1188.0)))))
    return ((y - 0.5) * log_pos(y) - y + _HALF_LOG_2PI + series) - log_pos(p)


@numba.njit(cache=True, error_model='numpy', inline='always')
def smith_g2_height_correlated(lambda_i: float, lambda_o: float, transmission: bool) -> float:
    """:func:`smith_g2`'s height-correlated form without branches or libm (for the lane kernel):
    the Beta function from :func:`log_gamma_ge1` (relative error below 1e-12 for Lambdas up to 100;
    for larger ones the three terms cancel, as with ``lgamma``), 0 where a Lambda is infinite."""
    inf = lambda_i > 1e300 or lambda_o > 1e300
    li = min(lambda_i, 1e300)
    lo = min(lambda_o, 1e300)
    a = 1.0 + li
    b = 1.0 + lo
    lb = log_gamma_ge1(a) + log_gamma_ge1(b) - log_gamma_ge1(a + b)
    g = exp_neg(min(0.0, lb)) if transmission else 1.0 / (1.0 + li + lo)
    return 0.0 if inf else g


@numba.njit(cache=True, error_model='numpy')
def smith_g2(lambda_i: float, lambda_o: float, transmission: bool, height_correlated: bool) -> float:
    """Smith masking-shadowing G2 from the two Lambdas (visibility tests done by the caller).

    Separable: G1(i) G1(o). Height-correlated (Heitz 2014, section 6): reflection
    1 / (1 + Li + Lo); transmission B(1 + Li, 1 + Lo), the Beta function, because
    the two directions see the microsurface from opposite sides.
    """
    if height_correlated:
        if math.isinf(lambda_i) or math.isinf(lambda_o):
            return 0.0
        if transmission:
            return math.exp(log_beta(1.0 + lambda_i, 1.0 + lambda_o))
        return 1.0 / (1.0 + lambda_i + lambda_o)
    return 1.0 / ((1.0 + lambda_i) * (1.0 + lambda_o))


@numba.njit(cache=True, error_model='numpy', inline='always')
def sample_vndf(wx: float, wy: float, wz: float, ax: float, ay: float, u1: float, u2: float):
    """Sample a microfacet normal from the GGX visible-normal distribution.

    ``w`` is the direction the light arrives from (local frame, ``w_z > 0``);
    ``u1, u2`` uniform in [0, 1). The density of the returned normal m is
    ``G1(w) max(0, w.m) D(m) / w_z`` (Heitz 2018). ``(u1, u2)`` stands for the point
    ``sqrt(u2) (cos 2 pi u1, sin 2 pi u1)`` of the unit disk (:func:`sample_vndf_polar`).
    ``ax = ay = 0`` returns the macro normal.
    """
    cos_phi, sin_phi = cos_sin_2pi(u1)
    inv = 1.0 / math.sqrt(vndf_stretch_norm2(wx, wy, wz, ax, ay))
    return sample_vndf_polar(wx, wy, wz, ax, ay, cos_phi, sin_phi, u2, inv)


@numba.njit(cache=True, error_model='numpy', inline='always')
def sample_vndf_disk(wx: float, wy: float, wz: float, ax: float, ay: float, x: float, y: float):
    """:func:`sample_vndf` from a point ``(x, y)`` uniform in the unit disk (the walks draw it by
    rejection, :func:`goniometer.kernel.rng.next_disk`: no trigonometry).

    Spherical-cap construction of Dupuy & Benyoub 2023, which draws exactly the visible-normal
    density: in the stretched (alpha = 1) configuration the visible normals of ``w`` are
    ``normalize(s + c)`` with ``s`` the stretched unit ``w`` and ``c`` uniform on the unit-sphere
    cap ``z > -s_z``. With ``t = x^2 + y^2`` (uniform in [0, 1), independent of the disk point's
    azimuth) and ``b = 1 + s_z``, the cap point is ``z = 1 - t b`` and its horizontal part is the
    disk point scaled by ``sqrt(1 - z^2) / sqrt(t) = sqrt(b (2 - t b))``; ``s_z + z = b (1 - t)``.
    """
    inv = 1.0 / math.sqrt(vndf_stretch_norm2(wx, wy, wz, ax, ay))
    sx = ax * wx * inv
    sy = ay * wy * inv
    b = 1.0 + wz * inv
    t = x * x + y * y
    k = math.sqrt(max(0.0, b * (2.0 - t * b)))
    return _vndf_unstretch(k * x + sx, k * y + sy, b * (1.0 - t), ax, ay)


@numba.njit(cache=True, error_model='numpy', inline='always')
def sample_vndf_polar(wx: float, wy: float, wz: float, ax: float, ay: float, cos_phi: float, sin_phi: float,
                      t: float, inv: float):
    """:func:`sample_vndf_disk` of the disk point ``sqrt(t) (cos_phi, sin_phi)``, given
    ``inv = 1 / sqrt(vndf_stretch_norm2(w))`` (for callers that share its division): the cap
    point's horizontal part is ``sqrt(t b (2 - t b)) (cos_phi, sin_phi)``, one square root."""
    sx = ax * wx * inv
    sy = ay * wy * inv
    b = 1.0 + wz * inv
    kr = math.sqrt(max(0.0, t * b * (2.0 - t * b)))
    return _vndf_unstretch(kr * cos_phi + sx, kr * sin_phi + sy, b * (1.0 - t), ax, ay)


@numba.njit(cache=True, error_model='numpy', inline='always')
def vndf_stretch_norm2(wx: float, wy: float, wz: float, ax: float, ay: float) -> float:
    """The squared length of ``w`` stretched to the alpha = 1 configuration (at least 1e-300)."""
    sx = ax * wx
    sy = ay * wy
    return max(1e-300, sx * sx + sy * sy + wz * wz)


@numba.njit(cache=True, error_model='numpy', inline='always')
def _vndf_unstretch(hx: float, hy: float, hz: float, ax: float, ay: float):
    """The unit microfacet normal of the stretched-configuration normal ``h``."""
    mx = ax * hx
    my = ay * hy
    mz = max(1e-300, hz)
    inv = 1.0 / math.sqrt(max(1e-300, mx * mx + my * my + mz * mz))
    return mx * inv, my * inv, mz * inv


@numba.njit(cache=True, error_model='numpy')
def vndf_pdf(wx: float, wy: float, wz: float, mx: float, my: float, mz: float, ax: float, ay: float) -> float:
    """Density (1/sr, over m) of :func:`sample_vndf`: G1(w) max(0, w.m) D(m) / w_z."""
    if wx * mx + wy * my + wz * mz <= 0.0 or wz <= 0.0:
        return 0.0
    return vndf_pdf_given(wx, wy, wz, mx, my, mz, smith_g1_dir(wx, wy, wz, ax, ay), ggx_d(mx, my, mz, ax, ay))


@numba.njit(cache=True, error_model='numpy')
def vndf_pdf_given(wx: float, wy: float, wz: float, mx: float, my: float, mz: float, g1: float, d: float) -> float:
    """:func:`vndf_pdf` for callers that already hold ``g1`` = :func:`smith_g1_dir` of ``w`` and ``d`` =
    :func:`ggx_d` of ``m`` (a random walk reuses them): the same expressions, so the same number."""
    wm = wx * mx + wy * my + wz * mz
    if wm <= 0.0 or wz <= 0.0:
        return 0.0
    return (g1 if wm * wz > 0.0 else 0.0) * wm * d / wz


# --------------------------------------------------------------------------- geometry

@numba.njit(cache=True, error_model='numpy')
def reflect(wx: float, wy: float, wz: float, mx: float, my: float, mz: float):
    """Mirror ``w`` about ``m``: 2 (w.m) m - w (both pointing away from the surface)."""
    d = 2.0 * (wx * mx + wy * my + wz * mz)
    return d * mx - wx, d * my - wy, d * mz - wz


@numba.njit(cache=True, error_model='numpy')
def refract(wx: float, wy: float, wz: float, mx: float, my: float, mz: float, eta: float):
    """Refract ``w`` (pointing away, on the side of ``m``) through a facet of normal ``m``.

    ``eta`` = n_far / n_near. Returns ``(x, y, z, ok)``; the refracted direction
    points away on the far side (``t.m < 0``). ``ok`` is False on total internal reflection.
    """
    c = wx * mx + wy * my + wz * mz
    inv_eta = 1.0 / eta
    sin2_t = inv_eta * inv_eta * max(0.0, 1.0 - c * c)
    if sin2_t >= 1.0:
        return 0.0, 0.0, 0.0, False
    x, y, z = refract_known(wx, wy, wz, mx, my, mz, inv_eta, c, math.sqrt(1.0 - sin2_t))
    return x, y, z, True


@numba.njit(cache=True, error_model='numpy')
def refract_known(wx: float, wy: float, wz: float, mx: float, my: float, mz: float,
                  inv_eta: float, cos_i: float, cos_t: float):
    """:func:`refract` when ``cos_i = w.m`` and the refracted cosine ``cos_t`` (e.g. from
    :func:`fresnel_dielectric_cos_t`) are already known; ``inv_eta`` = n_near / n_far."""
    k = inv_eta * cos_i - cos_t
    return k * mx - inv_eta * wx, k * my - inv_eta * wy, k * mz - inv_eta * wz


# --------------------------------------------------------------------------- microfacet BSDFs (Walter 2007)

@numba.njit(cache=True, error_model='numpy', inline="always")
def half_vector(lx: float, ly: float, lz: float, vx: float, vy: float, vz: float) -> tuple:
    """The reflection half vector ``normalize(l + v)`` (``l``, ``v`` unit, not opposite)."""
    hx = lx + vx
    hy = ly + vy
    hz = lz + vz
    inv = 1.0 / math.sqrt(hx * hx + hy * hy + hz * hz)
    return hx * inv, hy * inv, hz * inv


@numba.njit(cache=True, error_model='numpy')
def microfacet_reflection(
    lx: float, ly: float, lz: float, vx: float, vy: float, vz: float,
    ax: float, ay: float, eta: float, kappa: float, height_correlated: bool,
) -> float:
    """GGX microfacet BRDF f(l, v) = F D G / (4 |l.n| |v.n|), without cosine, in 1/sr.

    ``l`` and ``v`` in the local frame, both with positive z for a non-zero value.
    ``eta + i kappa`` is the relative index below the interface (kappa = 0: dielectric).
    """
    if lz <= 0.0 or vz <= 0.0:
        return 0.0
    hx, hy, hz = half_vector(lx, ly, lz, vx, vy, vz)
    lh = lx * hx + ly * hy + lz * hz
    if kappa > 0.0:
        f = fresnel_conductor(lh, eta, kappa)
    else:
        f = fresnel_dielectric(lh, eta)
    d = ggx_d(hx, hy, hz, ax, ay)
    li = ggx_lambda(lx, ly, lz, ax, ay)
    lo = ggx_lambda(vx, vy, vz, ax, ay)
    g = smith_g2(li, lo, False, height_correlated)
    return f * d * g / (4.0 * lz * vz)


@numba.njit(cache=True, error_model='numpy')
def microfacet_transmission(
    lx: float, ly: float, lz: float, vx: float, vy: float, vz: float,
    ax: float, ay: float, eta: float, height_correlated: bool,
) -> float:
    """GGX microfacet BTDF (Walter 2007) in the flux-based convention, without cosine, in 1/sr.

    ``l`` has positive z (light side, index n_i), ``v`` negative z (far side,
    index n_o), ``eta = n_o / n_i``. Value:
    (1 - F) D G |l.h| |v.h| eta^2 / (|l.n| |v.n| (l.h + eta v.h)^2), h = -(l + eta v) normalised
    towards +z. The radiance BTDF is this value times ``eta**2``.
    """
    if lz <= 0.0 or vz >= 0.0 or eta == 1.0:
        # eta == 1: the interface is invisible, transmission is a Dirac delta
        return 0.0
    return microfacet_transmission_given(lx, ly, lz, vx, vy, vz, ax, ay, eta, 1.0 / eta,
                                         ggx_lambda(lx, ly, lz, ax, ay), ggx_lambda(vx, vy, vz, ax, ay),
                                         height_correlated)


@numba.njit(cache=True, error_model='numpy')
def microfacet_transmission_given(
    lx: float, ly: float, lz: float, vx: float, vy: float, vz: float,
    ax: float, ay: float, eta: float, inv_eta: float, lambda_l: float, lambda_v: float,
    height_correlated: bool,
) -> float:
    """:func:`microfacet_transmission` for callers that already hold ``inv_eta = 1 / eta`` and the
    Smith ``Lambda`` of ``l`` and of ``v`` (:func:`ggx_lambda`; a random walk reuses them for every
    pair a direction enters): the same expressions, so the same number."""
    if lz <= 0.0 or vz >= 0.0 or eta == 1.0:
        return 0.0
    hx = -(lx + eta * vx)
    hy = -(ly + eta * vy)
    hz = -(lz + eta * vz)
    n = math.sqrt(hx * hx + hy * hy + hz * hz)
    if n == 0.0:
        return 0.0
    if hz < 0.0:
        n = -n
    hx /= n
    hy /= n
    hz /= n
    lh = lx * hx + ly * hy + lz * hz
    vh = vx * hx + vy * hy + vz * hz
    # refraction geometry: l on the positive side of h, v on the negative side
    if lh <= 0.0 or vh >= 0.0:
        return 0.0
    f = fresnel_dielectric_cos_t_inv(lh, eta, inv_eta)[0]
    if f >= 1.0:
        return 0.0
    d = ggx_d(hx, hy, hz, ax, ay)
    g = smith_g2(lambda_l, lambda_v, True, height_correlated)
    denom = lh + eta * vh
    return (1.0 - f) * d * g * abs(lh * vh) * eta * eta / (lz * abs(vz) * denom * denom)


# --------------------------------------------------------------------------- multiple scattering (Heitz 2016)
#
# The microsurface random walk of Heitz, Hanika, d'Eon & Dachsbacher 2016 ("Multiple-scattering
# microfacet BSDFs with the Smith model"). Heights are carried as their Smith CDF value
# ``c = C1(h)`` in (0, 1] (the height distribution cancels out of the Smith model; with Heitz's
# uniform heights on [-1, 1], ``c = (h + 1) / 2``): a ray at height ``c`` travelling along ``w``
# leaves the microsurface without a hit with probability ``G1(w, c) = c ** Lambda(w)`` (upward),
# and seen from below the same surface has ``c' = 1 - c``. The walk loop itself is
# :func:`goniometer.kernel.steps.microsurface_walk` (it draws the random numbers).


@numba.njit(cache=True, error_model='numpy')
def ms_sample_height(wx: float, wy: float, wz: float, c: float, ax: float, ay: float, u: float) -> float:
    """Next intersection of a ray with the microsurface, in height-CDF space (Heitz 2016, sec. 4).

    ``w`` is the ray's direction of travel, ``c`` = C1 of its current height, ``u`` uniform in
    [0, 1). Returns the height CDF of the next hit, or ``-1.0`` when the ray leaves the
    microsurface (only upward rays can, with probability ``c ** Lambda(w)``). The probability of
    no hit between ``c`` and ``x`` is ``(c / x) ** Lambda(w)`` upward and
    ``(x / c) ** (1 + Lambda(-w))`` downward (Smith's Lambda of a downward direction being
    ``-1 - Lambda(-w)``); a horizontal ray hits at its own height.
    """
    if wz > 0.0:
        lam = ggx_lambda(wx, wy, wz, ax, ay)
        lv = math.log(1.0 - u)  # 1 - u in (0, 1]
        if lv <= lam * math.log(c):
            return -1.0
        return min(1.0, c * math.exp(-lv / lam))
    if wz < 0.0:
        lam = 1.0 + ggx_lambda(wx, wy, wz, ax, ay)
        return c * math.exp(math.log(1.0 - u) / lam)
    return c


# --------------------------------------------------------------------------- scattering media

_INV_4PI = 1.0 / (4.0 * math.pi)


@numba.njit(cache=True, error_model='numpy')
def hg_phase(cos_theta: float, g: float) -> float:
    """Henyey-Greenstein phase function in 1/sr, normalised over the sphere:
    ``(1 - g^2) / (4 pi (1 + g^2 - 2 g cos)^(3/2))``. ``cos_theta`` is the cosine between the
    propagation directions before and after scattering (``g > 0``: forward scattering)."""
    d = 1.0 + g * g - 2.0 * g * cos_theta
    return (1.0 - g * g) * _INV_4PI / (d * math.sqrt(d))


@numba.njit(cache=True, error_model='numpy')
def sample_hg_cos(g: float, u: float) -> float:
    """Cosine of the scattering angle drawn from the Henyey-Greenstein phase function, ``u`` in [0, 1).

    The textbook inversion ``(1 + g^2 - ((1 - g^2) / (1 + g xi))^2) / (2 g)`` with
    ``xi = 2 u - 1`` is rewritten without the division by g (which cancels catastrophically as
    g -> 0): ``(xi + g) / (1 + g xi) + g (1 - g^2) (1 - xi^2) / (2 (1 + g xi)^2)``. At g = 0 it
    is exactly ``xi``, the isotropic cosine; ``u = 0`` (``xi = -1``) gives exactly -1.
    """
    xi = 2.0 * u - 1.0
    den = 1.0 + g * xi
    c = (xi + g) / den + 0.5 * g * (1.0 - g * g) * (1.0 - xi * xi) / (den * den)
    return min(1.0, max(-1.0, c))


@numba.njit(cache=True, error_model='numpy', inline="always")
def hg_scatter(dx: float, dy: float, dz: float, g: float, u1: float, u2: float):
    """New propagation direction after a Henyey-Greenstein scattering of the unit direction ``d``:
    the scattering cosine from :func:`sample_hg_cos` (``u1``), the azimuth about ``d`` uniform
    (``u2``), in the orthonormal frame of Duff et al. 2017 (branch-free, continuous but for
    the sign of ``d_z``)."""
    cos_ph, sin_ph = cos_sin_2pi(u2)
    return hg_scatter_cs(dx, dy, dz, g, u1, cos_ph, sin_ph)


@numba.njit(cache=True, error_model='numpy', inline="always")
def hg_scatter_cs(dx: float, dy: float, dz: float, g: float, u1: float, cos_ph: float, sin_ph: float):
    """:func:`hg_scatter` with the azimuth given by its cosine and sine (a caller that has them)."""
    c = sample_hg_cos(g, u1)
    st = math.sqrt(max(0.0, 1.0 - c * c))
    sgn = 1.0 if dz >= 0.0 else -1.0
    a = -1.0 / (sgn + dz)
    b = dx * dy * a
    # t1 = (1 + sgn dx^2 a, sgn b, -sgn dx), t2 = (b, sgn + dy^2 a, -dy): with d, an orthonormal frame
    p = st * cos_ph
    q = st * sin_ph
    ox = p * (1.0 + sgn * dx * dx * a) + q * b + c * dx
    oy = p * (sgn * b) + q * (sgn + dy * dy * a) + c * dy
    oz = -p * (sgn * dx) - q * dy + c * dz
    inv = 1.0 / math.sqrt(ox * ox + oy * oy + oz * oz)
    return ox * inv, oy * inv, oz * inv


@numba.njit(cache=True, error_model='numpy')
def hero_free_flight(u: float, t_hero: float) -> float:
    """Free-flight length drawn with the extinction ``t_hero`` of the path's hero channel:
    ``-log(1 - u) / t_hero``; ``inf`` (no collision) when ``t_hero = 0``."""
    if t_hero <= 0.0:
        return math.inf
    return -math.log1p(-u) / t_hero


@numba.njit(cache=True, error_model='numpy')
def spectral_mis_update(p0: float, p1: float, p2: float, q0: float, q1: float, q2: float):
    """One flight of path-level one-sample spectral MIS (``docs/material-format.md``, media).

    Each path draws all its flight lengths with one hero channel, picked uniformly, so a path
    prefix has density ``(1/3) sum_k P_k`` with ``P_k`` the product of its flights' densities
    under channel k. ``q_k = P_k / sum_j P_j`` are the prefix's shares (1/3 each at the start);
    ``p_k`` this flight's density under channel k (``t_k exp(-t_k s)`` for a collision at s,
    ``exp(-t_k s)`` for a flight that reaches the boundary after s). Returns channel c's weight
    factor ``p_c / sum_k q_k p_k`` (multiply by the albedo for a collision) and the new shares.
    The resulting path weight ``f_c / ((1/3) sum_k P_k)`` never exceeds ``3 f_c / P_c``, i.e. 3
    times the product of the albedos met: bounded, whatever the number of collisions."""
    inv = 1.0 / (q0 * p0 + q1 * p1 + q2 * p2)
    r0 = p0 * inv
    r1 = p1 * inv
    r2 = p2 * inv
    return r0, r1, r2, q0 * r0, q1 * r1, q2 * r2


# --------------------------------------------------------------------------- vectorised forms
#
# Built on first use, not at import: ``numba.vectorize`` with signatures compiles (or loads from its
# cache) when it decorates, which cost every process that imports this module -- ``gonio --help``
# included -- about half a second. :class:`LazyUfunc` builds the very same ufunc (same signatures,
# same on-disk cache, same bits) the first time it is called.


class LazyUfunc:
    """A ``numba.vectorize(signatures, cache=True)`` ufunc of ``py_func``, built on its first call
    (or first attribute access, e.g. ``.types``) in the numba cache directory that was current when
    it was declared (``goniometer.cache``); then it is that ufunc: calls, broadcasting, casting and
    results are the ufunc's."""

    def __init__(self, signatures: list[str], py_func) -> None:
        self._signatures = list(signatures)
        self._py_func = py_func
        self._cache_dir = numba.config.CACHE_DIR
        self._ufunc = None
        self.__name__ = py_func.__name__
        self.__qualname__ = py_func.__qualname__
        self.__doc__ = py_func.__doc__
        self.__module__ = py_func.__module__
        self.__wrapped__ = py_func

    def ufunc(self) -> np.ufunc:
        """The compiled ufunc (compiled, or loaded from numba's cache, on the first call)."""
        if self._ufunc is None:
            previous = numba.config.CACHE_DIR
            numba.config.CACHE_DIR = self._cache_dir
            try:
                self._ufunc = numba.vectorize(self._signatures, cache=True)(self._py_func)
            finally:
                numba.config.CACHE_DIR = previous
        return self._ufunc

    def __call__(self, *args, **kwargs):
        return self.ufunc()(*args, **kwargs)

    def __getattr__(self, name: str):
        if name.startswith("__"):
            raise AttributeError(name)
        return getattr(self.ufunc(), name)

    def __repr__(self) -> str:
        state = "built" if self._ufunc is not None else "built on first use"
        return f"<LazyUfunc {self.__module__}.{self.__name__} ({state})>"


def lazy_vectorize(signatures: list[str]):
    """``numba.vectorize(signatures, cache=True)``, built on first use (:class:`LazyUfunc`)."""
    def decorate(py_func) -> LazyUfunc:
        return LazyUfunc(signatures, py_func)
    return decorate


@lazy_vectorize(["float64(float64, float64)"])
def np_hg_phase(cos_theta, g):
    """Vectorised :func:`hg_phase`."""
    return hg_phase(cos_theta, g)


@lazy_vectorize(["float64(float64, float64)"])
def np_fresnel_dielectric(cos_i, eta):
    """Vectorised :func:`fresnel_dielectric`."""
    return fresnel_dielectric(cos_i, eta)


@lazy_vectorize(["float64(float64, float64, float64)"])
def np_fresnel_conductor(cos_i, eta, kappa):
    """Vectorised :func:`fresnel_conductor`."""
    return fresnel_conductor(cos_i, eta, kappa)


@lazy_vectorize(["float64(float64, float64, float64, float64, float64)"])
def np_ggx_d(mx, my, mz, ax, ay):
    """Vectorised :func:`ggx_d`."""
    return ggx_d(mx, my, mz, ax, ay)


@lazy_vectorize(["float64(float64, float64, float64, float64, float64)"])
def np_ggx_lambda(vx, vy, vz, ax, ay):
    """Vectorised :func:`ggx_lambda`."""
    return ggx_lambda(vx, vy, vz, ax, ay)


@lazy_vectorize(
    ["float64(float64, float64, float64, float64, float64, float64, float64, float64, float64, float64, boolean)"],
)
def np_microfacet_reflection(lx, ly, lz, vx, vy, vz, ax, ay, eta, kappa, height_correlated):
    """Vectorised :func:`microfacet_reflection`."""
    return microfacet_reflection(lx, ly, lz, vx, vy, vz, ax, ay, eta, kappa, height_correlated)


@lazy_vectorize(
    ["float64(float64, float64, float64, float64, float64, float64, float64, float64, float64, boolean)"],
)
def np_microfacet_transmission(lx, ly, lz, vx, vy, vz, ax, ay, eta, height_correlated):
    """Vectorised :func:`microfacet_transmission`."""
    return microfacet_transmission(lx, ly, lz, vx, vy, vz, ax, ay, eta, height_correlated)
