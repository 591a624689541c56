"""The numba kernel of the ``pbrt-layered`` rows: pbrt-v4's stochastic evaluation of a layered BSDF,
written in our own words and code from its description (Pharr, Jakob & Humphreys, *Physically
Based Rendering*, 4th ed., section 14.3 "Scattering from Layered Materials"; the estimator is
Guo, Hasan, Yan & Zhao 2018, "Position-free Monte Carlo simulation for arbitrary layered BSDFs").
``docs/pbrt-layered.md`` states the algorithm, its defaults and its known biases.

Conventions of this module are pbrt's, in the local frame of the macro surface (normal +z):
``wo`` is the viewer's direction (our ``v``) and ``wi`` the light's (our ``l``), both pointing away
from the surface. ``f(wo, wi)`` never contains a cosine. "Radiance" transport carries radiance from
``wi`` to ``wo`` (the walk starts at the viewer); its adjoint ("importance") swaps the two, which
for a dielectric transmission only changes where the ``eta^2`` factor goes. The coat index ``eta``
is the index inside the coat relative to the air above it.

The layer is the slab ``0 <= z <= thickness`` (thickness = optical depth, extinction 1 per unit):
``z = thickness`` is the coat (the exit interface of a reflection) and ``z = 0`` the base.

Every microfacet, Fresnel, refraction and phase formula comes from :mod:`goniometer.optics`; this
module only composes them the way pbrt's component BxDFs do (rough dielectric with the masking
``G = 1 / (1 + Lambda_o + Lambda_i)`` in both lobes, rough or smooth conductor, Lambertian, HG):
:func:`diel_sample`, :func:`diel_f`, :func:`diel_pdf`, :func:`base_f`, :func:`base_pdf`,
:func:`base_sample`. The walk's hot steps (the rough coat's entries, reflection from inside and
exits, the rough conductor's connection and sample) are fused versions of these that give the
same bits: the same expressions in the same order, where a value that depends on one direction
only (its Lambda, G1, the sampler's stretch, the slab's transmittance along it) or a shared part
(a reflection's half vector and D, a reciprocal) is computed once and reused
(``tests/models/test_pbrt_layered.py`` checks each against the general functions bit for bit;
``benchmarks/README.md``, issue 34, the time they save). Where optics' expressions are restated
here (the microfacet values' last products and quotients), they divide as optics does
(:func:`_quotient`, no exception on a zero divisor).

The parameters of one evaluation are packed by :func:`models.pbrt_layered.model.pack`:

* ``conf`` (int64): ``[max_depth, n_samples, fixed_mis, exact_transmission_masking, n_groups,
  base_kind, top_smooth, base_smooth, seed]``;
* ``real`` (float64): ``[coat eta, coat alpha, base alpha, g]``;
* ``chan`` (float64, ``(n_groups, 5, 3)``): per walk group, rows optical depth, scattering albedo,
  Lambertian reflectance, conductor eta and k (both relative to the coat), one column per slot;
* ``source`` (int64, ``(3,)``): where each output channel's result comes from, ``3 group + slot``.

One group carries the three channels together (as pbrt's walk carries its wavelengths); a
scattering medium whose optical depth differs between channels needs one walk per channel
(three groups, each with the channel's values in every slot): pbrt's thickness is one number.
"""

from __future__ import annotations

import math
import types

import numba
import numpy as np

from goniometer import optics
from goniometer.bits import double_as_uint64
from goniometer.optics import (cos_sin_2pi, cosine_from_disk, fresnel_conductor, fresnel_dielectric,
                               fresnel_dielectric_cos_t_inv, ggx_d, ggx_lambda, half_vector, hg_phase,
                               microfacet_reflection, microfacet_transmission, microfacet_transmission_given, reflect,
                               refract, refract_known, sample_vndf, sample_vndf_polar, smith_g1_dir, smith_g2,
                               vndf_pdf, vndf_stretch_norm2)
from goniometer.kernel.rng import next_float, seed_state, splitmix64
from goniometer.kernel.packing import BASE_CONDUCTOR, BASE_LAMBERTIAN
from models._jit import njit

#: the base below the coat

#: indices of ``conf``
C_MAX_DEPTH, C_SAMPLES, C_FIXED, C_EXACT, C_GROUPS, C_BASE, C_TOP_SMOOTH, C_BASE_SMOOTH, C_SEED = range(9)
#: indices of ``real``
R_ETA, R_ALPHA0, R_ALPHA1, R_G = range(4)
#: rows of ``chan``
K_TAU, K_ALBEDO, K_RHO, K_ETA, K_K = range(5)

#: pbrt's threshold under which a GGX distribution is a perfect mirror/refractor
SMOOTH_ALPHA = 1e-3
_INV_PI = 1.0 / math.pi


# ---------------------------------------------------------------------- Henyey-Greenstein sampling

def _models_copy(fn, inline: str = "never", **replace):
    """``goniometer.optics``' function ``fn`` compiled again, from the same source, in the models'
    cache (``models._jit``), with the optics functions it calls replaced by ``replace``.

    The simulator's lane kernel inlines :func:`goniometer.optics.hg_scatter_cs`, which calls
    ``sample_hg_cos``; if any other code compiled ``sample_hg_cos`` into the simulator's cache first,
    a fresh compilation of the lane kernel would link that cached object instead of inlining it,
    and its scattering step would no longer vectorise (``docs/kernel.md`` §4, which names the test).
    So this module never compiles those dispatchers: it uses copies (the formula stays in
    ``goniometer.optics``)."""
    py = fn.py_func
    env = dict(py.__globals__)
    env.update(replace)
    copy = types.FunctionType(py.__code__, env, py.__name__, py.__defaults__, py.__closure__)
    copy.__qualname__ = py.__qualname__
    copy.__doc__ = py.__doc__
    return njit(cache=True, inline=inline)(copy)


_sample_hg_cos = _models_copy(optics.sample_hg_cos)
_hg_scatter_cs = _models_copy(optics.hg_scatter_cs, inline="always", sample_hg_cos=_sample_hg_cos)
hg_scatter = _models_copy(optics.hg_scatter, inline="always", hg_scatter_cs=_hg_scatter_cs)


# ---------------------------------------------------------------------- small helpers

@njit(cache=True, error_model="numpy")
def _quotient(a: float, b: float) -> float:
    """``a / b`` as :mod:`goniometer.optics` divides (no exception for ``b = 0``): for optics'
    expressions that this module computes itself, which keep optics' arithmetic."""
    return a / b


@njit(cache=True, inline="always")
def _power_heuristic(a: float, b: float) -> float:
    """The power heuristic with exponent 2 for one sample of each strategy, ``a^2 / (a^2 + b^2)``
    (1 if ``a^2`` overflows)."""
    a2 = a * a
    if math.isinf(a2):
        return 1.0
    s = a2 + b * b
    return a2 / s if s > 0.0 else 0.0


@njit(cache=True, inline="always")
def _tr(dz: float, wz: float) -> float:
    """Transmittance of the layer over the height difference ``dz`` along a direction of cosine
    ``wz`` (extinction 1 per unit height): ``exp(-|dz / wz|)``, 1 for a vanishing ``dz``."""
    if abs(dz) <= 1.1754943508222875e-38:
        return 1.0
    return math.exp(-abs(dz / wz))


@njit(cache=True, inline="always")
def _tr3(tau0: float, tau1: float, tau2: float, wz: float):
    """:func:`_tr` of the three slots' optical depths along ``wz``; a slot whose depth equals an
    earlier slot's takes its value (the same number)."""
    t0 = _tr(tau0, wz)
    t1 = t0 if tau1 == tau0 else _tr(tau1, wz)
    if tau2 == tau1:
        t2 = t1
    elif tau2 == tau0:
        t2 = t0
    else:
        t2 = _tr(tau2, wz)
    return t0, t1, t2


@njit(cache=True)
def direction_key(seed: int, vx: float, vy: float, vz: float, lx: float, ly: float, lz: float) -> np.uint64:
    """The random stream's key of one (viewer, light) pair: SplitMix64 steps over the bits of the
    six coordinates and the seed (the same pair always draws the same numbers)."""
    h = splitmix64(np.uint64(seed))
    h = splitmix64(h ^ double_as_uint64(vx))
    h = splitmix64(h ^ double_as_uint64(vy))
    h = splitmix64(h ^ double_as_uint64(vz))
    h = splitmix64(h ^ double_as_uint64(lx))
    h = splitmix64(h ^ double_as_uint64(ly))
    return splitmix64(h ^ double_as_uint64(lz))


# ---------------------------------------------------------------------- the coat: a GGX dielectric

@njit(cache=True)
def diel_f(ox: float, oy: float, oz: float, ix: float, iy: float, iz: float, eta: float, a: float,
           radiance: bool, exact: bool) -> float:
    """pbrt's rough dielectric ``f(wo, wi)`` (no cosine): the GGX reflection with
    ``G = 1 / (1 + Lambda_o + Lambda_i)`` if both directions lie on one side, else the Walter
    transmission. Transmission in radiance transport carries light from ``wi`` to ``wo``
    (:func:`goniometer.optics.microfacet_transmission` with the light at ``wi``); in importance
    transport from ``wo`` to ``wi``. Its masking is pbrt's ``1 / (1 + Lambda_o + Lambda_i)`` (the
    separable value rescaled), or with ``exact`` the height-correlated Beta function of our
    simulator."""
    if oz == 0.0 or iz == 0.0:
        return 0.0
    if oz * iz > 0.0:
        if oz > 0.0:
            return microfacet_reflection(ix, iy, iz, ox, oy, oz, a, a, eta, 0.0, True)
        return microfacet_reflection(ix, iy, -iz, ox, oy, -oz, a, a, 1.0 / eta, 0.0, True)
    if radiance:
        lx, ly, lz, vx, vy, vz = ix, iy, iz, ox, oy, oz
    else:
        lx, ly, lz, vx, vy, vz = ox, oy, oz, ix, iy, iz
    e = eta
    if lz < 0.0:  # the light side is inside the coat: flip the frame
        lz = -lz
        vz = -vz
        e = 1.0 / eta
    if exact:
        return microfacet_transmission(lx, ly, lz, vx, vy, vz, a, a, e, True)
    f = microfacet_transmission(lx, ly, lz, vx, vy, vz, a, a, e, False)
    if f == 0.0:
        return 0.0
    li = ggx_lambda(lx, ly, lz, a, a)
    lo = ggx_lambda(vx, vy, vz, a, a)
    return f * ((1.0 + li) * (1.0 + lo) / (1.0 + li + lo))


@njit(cache=True, inline="always")
def _generalized_half(ox: float, oy: float, oz: float, ix: float, iy: float, iz: float, etap: float):
    """The microfacet normal of the pair ``(o, i)`` for the index ratio ``etap`` (1 for a
    reflection): ``etap i + o`` normalised towards +z, with ``i.m`` and ``o.m``. Returns ``(ok, m_x,
    m_y, m_z, i.m, o.m)``, ``ok`` False where the pair has no such normal (a zero sum, or a
    direction on the wrong side of ``m``)."""
    mx = etap * ix + ox
    my = etap * iy + oy
    mz = etap * iz + oz
    n2 = mx * mx + my * my + mz * mz
    if n2 == 0.0:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0
    inv = 1.0 / math.sqrt(n2)
    if mz < 0.0:
        inv = -inv
    mx *= inv
    my *= inv
    mz *= inv
    dmi = mx * ix + my * iy + mz * iz
    dmo = mx * ox + my * oy + mz * oz
    if dmi * iz < 0.0 or dmo * oz < 0.0:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0
    return True, mx, my, mz, dmi, dmo


@njit(cache=True)
def diel_pdf(ox: float, oy: float, oz: float, ix: float, iy: float, iz: float, eta: float, a: float,
             refl: bool, trans: bool) -> float:
    """pbrt's rough dielectric sampling density of ``wi`` given ``wo`` (1/sr), with the lobes the
    flags allow: the visible-normal density of ``wo`` times the Jacobian of the reflection or of
    the generalised-half-vector refraction, times the lobe's Fresnel choice probability."""
    if oz == 0.0 or iz == 0.0:
        return 0.0
    reflection = oz * iz > 0.0
    etap = 1.0
    if not reflection:
        etap = eta if oz > 0.0 else 1.0 / eta
    ok, mx, my, mz, dmi, dmo = _generalized_half(ox, oy, oz, ix, iy, iz, etap)
    if not ok:
        return 0.0
    r = fresnel_dielectric(dmo, eta if dmo > 0.0 else 1.0 / eta)
    pr = r if refl else 0.0
    pt = (1.0 - r) if trans else 0.0
    if pr + pt <= 0.0:
        return 0.0
    if oz > 0.0:
        dw = vndf_pdf(ox, oy, oz, mx, my, mz, a, a)
    else:
        dw = vndf_pdf(-ox, -oy, -oz, mx, my, mz, a, a)
    if reflection:
        return dw / (4.0 * abs(dmo)) * pr / (pr + pt)
    den = dmi + dmo / etap
    if den == 0.0:
        return 0.0
    return dw * abs(dmi) / (den * den) * pt / (pr + pt)


@njit(cache=True)
def diel_sample(ox: float, oy: float, oz: float, eta: float, a: float, smooth: bool, radiance: bool, refl: bool,
                trans: bool, exact: bool, uc: float, u1: float, u2: float):
    """Sample pbrt's dielectric from ``wo`` with the lobes the flags allow. Returns
    ``(ok, wi_x, wi_y, wi_z, f, pdf)``; ``ok`` is False where pbrt returns no sample (no lobe
    allowed, total internal reflection, a direction on the wrong side)."""
    if smooth:
        r = fresnel_dielectric(oz, eta if oz > 0.0 else 1.0 / eta)
        pr = r if refl else 0.0
        pt = (1.0 - r) if trans else 0.0
        if pr + pt <= 0.0:
            return False, 0.0, 0.0, 0.0, 0.0, 0.0
        if uc < pr / (pr + pt):
            if oz == 0.0:
                return False, 0.0, 0.0, 0.0, 0.0, 0.0
            return True, -ox, -oy, oz, r / abs(oz), pr / (pr + pt)
        if oz > 0.0:
            etap = eta
            tx, ty, tz, ok = refract(ox, oy, oz, 0.0, 0.0, 1.0, eta)
        else:
            etap = 1.0 / eta
            tx, ty, tz, ok = refract(ox, oy, oz, 0.0, 0.0, -1.0, 1.0 / eta)
        if not ok or tz == 0.0:
            return False, 0.0, 0.0, 0.0, 0.0, 0.0
        f = (1.0 - r) / abs(tz)
        if radiance:
            f /= etap * etap
        return True, tx, ty, tz, f, pt / (pr + pt)
    # rough: a visible normal of wo (of -wo when wo is inside the coat)
    if oz > 0.0:
        mx, my, mz = sample_vndf(ox, oy, oz, a, a, u1, u2)
    else:
        mx, my, mz = sample_vndf(-ox, -oy, -oz, a, a, u1, u2)
    dmo = ox * mx + oy * my + oz * mz
    r = fresnel_dielectric(dmo, eta if dmo > 0.0 else 1.0 / eta)
    pr = r if refl else 0.0
    pt = (1.0 - r) if trans else 0.0
    if pr + pt <= 0.0:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0
    if uc < pr / (pr + pt):
        ix, iy, iz = reflect(ox, oy, oz, mx, my, mz)
        if iz * oz <= 0.0:
            return False, 0.0, 0.0, 0.0, 0.0, 0.0
    else:
        if dmo > 0.0:
            ix, iy, iz, ok = refract(ox, oy, oz, mx, my, mz, eta)
        else:
            ix, iy, iz, ok = refract(ox, oy, oz, -mx, -my, -mz, 1.0 / eta)
        if not ok or iz * oz >= 0.0:
            return False, 0.0, 0.0, 0.0, 0.0, 0.0
    f = diel_f(ox, oy, oz, ix, iy, iz, eta, a, radiance, exact)
    pdf = diel_pdf(ox, oy, oz, ix, iy, iz, eta, a, refl, trans)
    return True, ix, iy, iz, f, pdf


# ---------------------------------------------------------------------- the rough coat, fused
#
# The walk evaluates the coat through the functions below: each gives the bits of the
# straightforward composition above (diel_sample, diel_f, diel_pdf) with the same expressions in
# the same order, but takes the terms that depend on one direction only (Lambda, G1 and the
# visible-normal sampler's stretch of v, l and the walk's current direction w) from the walk,
# which computes them once per direction instead of once per use, computes the half vector and D
# of a reflection once for its value and density, and takes the reciprocals of the coat's index
# that fresnel_dielectric and refract would divide again from coat_indices. ggx_lambda,
# smith_g1_dir and vndf_stretch_norm2 depend on the squares of a direction's coordinates (and
# |z|): the same number for w and -w. Anything off their common path is left to the general
# functions. Independent computations are placed side by side (the two entries, an exit's value
# and density): the processor overlaps them, which is most of what remains to gain, the walk's
# arithmetic being long chains of divisions and square roots.

@njit(cache=True, inline="always")
def coat_indices(eta: float):
    """``(eta, 1 / eta, 1 / (1 / eta))``: the coat's relative index seen from outside and from
    inside, each followed by the reciprocal that ``fresnel_dielectric`` computes of it."""
    inv = 1.0 / eta
    return eta, inv, 1.0 / inv


@njit(cache=True, inline="always")
def _fresnel_coat(c: float, etas: tuple, outside: bool) -> float:
    """``fresnel_dielectric(c, eta if outside else 1 / eta)`` for ``etas`` from :func:`coat_indices`:
    ``fresnel_dielectric(c, e)`` is ``fresnel_dielectric_cos_t_inv(c, e, 1 / e)``, whose reciprocal
    is taken from ``etas`` instead of divided again (the same number)."""
    eta, inv, inv_inv = etas
    if outside:
        return fresnel_dielectric_cos_t_inv(c, eta, inv)[0]
    return fresnel_dielectric_cos_t_inv(c, inv, inv_inv)[0]


@njit(cache=True, inline="always")
def _refract_coat(wx: float, wy: float, wz: float, mx: float, my: float, mz: float, etas: tuple, outside: bool):
    """``refract(w, m, eta if outside else 1 / eta)`` for ``etas`` from :func:`coat_indices`:
    ``optics.refract``'s expressions, with the reciprocal it computes of its index taken from
    ``etas`` (the same number)."""
    inv_e = etas[1] if outside else etas[2]
    c = wx * mx + wy * my + wz * mz
    sin2_t = inv_e * inv_e * max(0.0, 1.0 - c * c)
    if sin2_t >= 1.0:
        return 0.0, 0.0, 0.0, False
    x, y, z = refract_known(wx, wy, wz, mx, my, mz, inv_e, c, math.sqrt(1.0 - sin2_t))
    return x, y, z, True


@njit(cache=True, inline="always")
def coat_terms(x: float, y: float, z: float, a: float):
    """``(Lambda, G1, 1 / |w stretched|)`` of the direction ``w`` for the coat's alpha: what
    ``ggx_lambda``, ``smith_g1_dir`` and ``sample_vndf`` compute of it."""
    return (ggx_lambda(x, y, z, a, a), smith_g1_dir(x, y, z, a, a),
            1.0 / math.sqrt(vndf_stretch_norm2(x, y, z, a, a)))


@njit(cache=True)
def coat_transmission(lx: float, ly: float, lz: float, vx: float, vy: float, vz: float, etas: tuple,
                      outside: bool, a: float, lam_l: float, lam_v: float, exact: bool) -> float:
    """:func:`diel_f`'s transmission in its frame (light side ``l`` with ``l_z > 0``, ``v_z < 0``;
    the light outside the coat, relative index ``eta``, or inside, ``1 / eta``), given ``lam_l`` and
    ``lam_v`` (``ggx_lambda`` of ``l`` and ``v``): ``optics.microfacet_transmission_given`` with the
    reciprocal of the index from ``etas``, then pbrt's masking (or, with ``exact``, the
    height-correlated one)."""
    e, inv_e = (etas[0], etas[1]) if outside else (etas[1], etas[2])
    f = microfacet_transmission_given(lx, ly, lz, vx, vy, vz, a, a, e, inv_e, lam_l, lam_v, exact)
    if exact:
        return f
    if f == 0.0:
        return 0.0
    return f * ((1.0 + lam_l) * (1.0 + lam_v) / (1.0 + lam_l + lam_v))


@njit(cache=True)
def coat_transmission_pdf(ox: float, oy: float, oz: float, ix: float, iy: float, iz: float, etas: tuple,
                          a: float, g1: float) -> float:
    """:func:`diel_pdf` of the transmission lobe alone for a transmission pair (``o_z i_z < 0``),
    given ``etas`` (:func:`coat_indices`) and ``g1`` (``smith_g1_dir`` of ``o``)."""
    eta, inv_eta, _ = etas
    if oz == 0.0 or iz == 0.0:
        return 0.0
    if oz * iz > 0.0:
        return diel_pdf(ox, oy, oz, ix, iy, iz, eta, a, False, True)
    etap = eta if oz > 0.0 else inv_eta
    ok, mx, my, mz, dmi, dmo = _generalized_half(ox, oy, oz, ix, iy, iz, etap)
    if not ok:
        return 0.0
    r = _fresnel_coat(dmo, etas, dmo > 0.0)
    pr = 0.0
    pt = 1.0 - r
    if pr + pt <= 0.0:
        return 0.0
    # vndf_pdf of o (of -o inside), its smith_g1 being G1 where (w.m) w_z > 0
    if oz > 0.0:
        wx, wy, wz = ox, oy, oz
    else:
        wx, wy, wz = -ox, -oy, -oz
    wm = wx * mx + wy * my + wz * mz
    if wm <= 0.0 or wz <= 0.0:
        dw = 0.0
    else:
        dw = (g1 if wm * wz > 0.0 else 0.0) * wm * ggx_d(mx, my, mz, a, a) / wz
    den = dmi + dmo / etap
    if den == 0.0:
        return 0.0
    return dw * abs(dmi) / (den * den) * pt / (pr + pt)


@njit(cache=True, inline="always")
def _enter_direction(ox: float, oy: float, oz: float, etas: tuple, a: float, st_o: float, u1: float, u2: float):
    """The direction :func:`diel_sample` draws from outside (``o_z > 0``, rough coat, transmission
    only) with the sampler's ``st_o`` of ``o`` (:func:`coat_terms`): ``(ok, wi_x, wi_y, wi_z)``.
    Its lobe choice needs no number: the reflection lobe's probability ``0 / (0 + (1 - r))`` never
    exceeds ``uc``."""
    cp, sp = cos_sin_2pi(u1)
    mx, my, mz = sample_vndf_polar(ox, oy, oz, a, a, cp, sp, u2, st_o)
    dmo = ox * mx + oy * my + oz * mz
    r = _fresnel_coat(dmo, etas, dmo > 0.0)
    if 0.0 + (1.0 - r) <= 0.0:
        return False, 0.0, 0.0, 0.0
    if dmo > 0.0:
        ix, iy, iz, ok = _refract_coat(ox, oy, oz, mx, my, mz, etas, True)
    else:
        ix, iy, iz, ok = _refract_coat(ox, oy, oz, -mx, -my, -mz, etas, False)
    if not ok or iz * oz >= 0.0:
        return False, 0.0, 0.0, 0.0
    return True, ix, iy, iz


@njit(cache=True, inline="always")
def _enter_value(ox: float, oy: float, oz: float, ix: float, iy: float, iz: float, etas: tuple, a: float,
                 terms: tuple, radiance: bool, exact: bool):
    """:func:`diel_sample`'s ``(f, pdf)`` of the entry from ``o`` (outside) to ``i`` (inside)
    given :func:`coat_terms` of ``o``: diel_f's frame has the light on the inside (flipped up) in
    radiance transport, outside in importance transport."""
    lam_o, g1_o, _ = terms
    lam_i = ggx_lambda(ix, iy, iz, a, a)
    if radiance:
        f = coat_transmission(ix, iy, -iz, ox, oy, -oz, etas, False, a, lam_i, lam_o, exact)
    else:
        f = coat_transmission(ox, oy, oz, ix, iy, iz, etas, True, a, lam_o, lam_i, exact)
    return f, coat_transmission_pdf(ox, oy, oz, ix, iy, iz, etas, a, g1_o)


@njit(cache=True)
def coat_entries(vx: float, vy: float, vz: float, lx: float, ly: float, lz: float, etas: tuple, a: float,
                 smooth: bool, tv: tuple, tl: tuple, exact: bool, s: np.ndarray):
    """The walk's first two samples of the coat, each as :func:`diel_sample` draws it from outside
    for transmission only: from ``v`` (radiance transport), then from ``l`` (importance transport),
    given :func:`coat_terms` of ``v`` and ``l``. Returns ``(ok, w_x, w_y, w_z, f_w, pdf_w, d_x, d_y,
    d_z, f_d, pdf_d)``; ``ok`` is False where the walk ends there (a failed sample, or a zero value,
    density or cosine). The stream ``s`` advances as if the two were drawn one after the other: by
    three numbers where the viewer's entry ends the walk, by six otherwise.

    On a rough coat the two entries are computed side by side (they are independent, and the
    processor overlaps them): the light's numbers are drawn before the viewer's entry is known to
    succeed, and the state is put back when it does not."""
    ucv = next_float(s)
    u1v = next_float(s)
    u2v = next_float(s)
    if smooth or vz <= 0.0 or lz <= 0.0:
        ok, wx, wy, wz, wf, wpdf = diel_sample(vx, vy, vz, etas[0], a, smooth, True, False, True, exact, ucv, u1v,
                                               u2v)
        if not ok or wf == 0.0 or wpdf == 0.0 or wz == 0.0:
            return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        ok, dx, dy, dz, df, dpdf = diel_sample(lx, ly, lz, etas[0], a, smooth, False, False, True, exact,
                                               next_float(s), next_float(s), next_float(s))
        return ok and df != 0.0 and dpdf != 0.0 and dz != 0.0, wx, wy, wz, wf, wpdf, dx, dy, dz, df, dpdf
    s0, s1, s2, s3 = s[0], s[1], s[2], s[3]
    ucl = next_float(s)
    u1l = next_float(s)
    u2l = next_float(s)
    okv, wx, wy, wz = _enter_direction(vx, vy, vz, etas, a, tv[2], u1v, u2v)
    okl, dx, dy, dz = _enter_direction(lx, ly, lz, etas, a, tl[2], u1l, u2l)
    # (a failed direction is (0, 0, 0), whose value and density are 0)
    wf, wpdf = _enter_value(vx, vy, vz, wx, wy, wz, etas, a, tv, True, exact)
    df, dpdf = _enter_value(lx, ly, lz, dx, dy, dz, etas, a, tl, False, exact)
    if not okv or wf == 0.0 or wpdf == 0.0 or wz == 0.0:
        # the walk ends at the viewer's entry: the light's numbers were not drawn
        s[0] = s0
        s[1] = s1
        s[2] = s2
        s[3] = s3
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    return okl and df != 0.0 and dpdf != 0.0 and dz != 0.0, wx, wy, wz, wf, wpdf, dx, dy, dz, df, dpdf


@njit(cache=True, inline="always")
def coat_exit(wx: float, wy: float, wz: float, lx: float, ly: float, lz: float, etas: tuple, a: float, tl: tuple,
              lam_w: float, g1_w: float, fixed: bool, exact: bool):
    """A walk's connection of its direction ``w`` (``w_z > 0``) to the light through the coat:
    ``(diel_f(-w, l), density)`` (radiance transport), the density being the one pbrt weighs it
    with, ``diel_pdf(-w, l)`` (``fixed``: ``diel_pdf(l, -w)``), given :func:`coat_terms` of ``l``
    (``tl``) and ``lam_w``, ``g1_w`` of ``w``. The walk uses the density only where the value is
    not 0; it is computed alongside, the two being independent (cheaper than waiting for the
    value)."""
    lam_l, g1_l, _ = tl
    fe = coat_transmission(lx, ly, lz, -wx, -wy, -wz, etas, True, a, lam_l, lam_w, exact)
    if fixed:
        pe = coat_transmission_pdf(lx, ly, lz, -wx, -wy, -wz, etas, a, g1_l)
    else:
        pe = coat_transmission_pdf(-wx, -wy, -wz, lx, ly, lz, etas, a, g1_w)
    return fe, pe


@njit(cache=True)
def coat_reflect(wx: float, wy: float, wz: float, etas: tuple, a: float, smooth: bool, lam_w: float,
                 g1_w: float, exact: bool, uc: float, u1: float, u2: float):
    """:func:`diel_sample` of ``-w`` (``w_z > 0``: the walk at the coat from inside) for reflection
    only, radiance transport, given ``etas`` (:func:`coat_indices`) and ``lam_w``, ``g1_w``
    (:func:`coat_terms` of ``w``). Returns ``(ok, wi_x, wi_y, wi_z, f, pdf)``."""
    eta = etas[0]
    if smooth or wz <= 0.0:
        return diel_sample(-wx, -wy, -wz, eta, a, smooth, True, True, False, exact, uc, u1, u2)
    ox = -wx
    oy = -wy
    oz = -wz
    cp, sp = cos_sin_2pi(u1)
    mx, my, mz = sample_vndf_polar(wx, wy, wz, a, a, cp, sp, u2, 1.0 / math.sqrt(vndf_stretch_norm2(wx, wy, wz, a, a)))
    dmo = ox * mx + oy * my + oz * mz
    r = _fresnel_coat(dmo, etas, dmo > 0.0)
    pr = r
    pt = 0.0
    if pr + pt <= 0.0:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0
    # the lobe choice uc < pr / (pr + pt) = r / r: 1 > uc for any r > 0 (a NaN r: the general function)
    if r != r:
        return diel_sample(-wx, -wy, -wz, eta, a, smooth, True, True, False, exact, uc, u1, u2)
    ix, iy, iz = reflect(ox, oy, oz, mx, my, mz)
    if iz * oz <= 0.0:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0
    # diel_f: microfacet_reflection(i, o flipped up, a, a, 1 / eta, 0, True), its half vector
    # normalize(i + o) flipped up (optics.half_vector's expressions)
    hx = ix + ox
    hy = iy + oy
    hz = -iz + -oz
    n2 = hx * hx + hy * hy + hz * hz
    if not (n2 != 0.0 and iz + oz < 0.0):
        return diel_sample(-wx, -wy, -wz, eta, a, smooth, True, True, False, exact, uc, u1, u2)
    inv = 1.0 / math.sqrt(n2)
    hx *= inv
    hy *= inv
    hz *= inv
    lh = ix * hx + iy * hy + -iz * hz
    d = ggx_d(hx, hy, hz, a, a)
    g = smith_g2(ggx_lambda(ix, iy, -iz, a, a), lam_w, False, True)
    f = _quotient(_fresnel_coat(lh, etas, False) * d * g, 4.0 * -iz * -oz)
    # diel_pdf(o, i, reflection only): its normal is (-h_x, -h_y, h_z) (the same sum, turned up),
    # whose D is h's
    mx = -hx
    my = -hy
    mz = hz
    dmi = mx * ix + my * iy + mz * iz
    dmo = mx * ox + my * oy + mz * oz
    if dmi * iz < 0.0 or dmo * oz < 0.0:
        return True, ix, iy, iz, f, 0.0
    r = _fresnel_coat(dmo, etas, dmo > 0.0)
    pr = r
    if pr + pt <= 0.0:
        return True, ix, iy, iz, f, 0.0
    wm = wx * mx + wy * my + wz * mz
    if wm <= 0.0:
        dw = 0.0
    else:
        dw = (g1_w if wm * wz > 0.0 else 0.0) * wm * d / wz
    return True, ix, iy, iz, f, dw / (4.0 * abs(dmo)) * pr / (pr + pt)


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
    order, the density ``vndf_pdf``'s ``G1 (o.h) D / o_z`` over ``4 |o.h|``."""
    if oz <= 0.0 or iz <= 0.0:
        return 0.0, 0.0, 0.0, 0.0
    hx, hy, hz = half_vector(ox, oy, oz, ix, iy, iz)
    d = ggx_d(hx, hy, hz, a, a)
    # the density: vndf_pdf(o, h) / (4 |o.h|), smith_g1 being 0 unless (o.h) o_z > 0
    wm = ox * hx + oy * hy + oz * hz
    if wm <= 0.0 or oz <= 0.0:
        dw = 0.0
    else:
        dw = (g1_o if wm * oz > 0.0 else 0.0) * wm * d / oz
    pdf = dw / (4.0 * abs(wm))
    # the values: microfacet_reflection(i, o, a, a, e, k, True) per slot, equal indices sharing one
    lh = ix * hx + iy * hy + iz * hz
    g = smith_g2(lam_i, lam_o, False, True)
    den = 4.0 * iz * oz
    f0 = _quotient(_base_fresnel(lh, e0, k0) * d * g, den)
    if e1 == e0 and k1 == k0:
        f1 = f0
    else:
        f1 = _quotient(_base_fresnel(lh, e1, k1) * d * g, den)
    if e2 == e1 and k2 == k1:
        f2 = f1
    else:
        f2 = _quotient(_base_fresnel(lh, e2, k2) * d * g, den)
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


# ---------------------------------------------------------------------- one sample of pbrt's estimator

@njit(cache=True)
def walk(vx: float, vy: float, vz: float, lx: float, ly: float, lz: float, tv: tuple, tl: tuple, conf: np.ndarray,
         real: np.ndarray, ch: np.ndarray, s: np.ndarray):
    """One sample of pbrt-v4's stochastic layered ``f(wo = v, wi = l)`` without the coat's own
    reflection (which the caller evaluates exactly): the walk from the viewer into the layer, with
    next-event connections to the light through the coat at every base and medium vertex, weighted
    as pbrt weights them (``docs/pbrt-layered.md``). ``tv``, ``tl``: :func:`coat_terms` of ``v``
    and ``l`` (the same for every walk of the pair). Draws from the stream ``s``. Returns the
    contribution per slot."""
    max_depth = conf[C_MAX_DEPTH]
    fixed = conf[C_FIXED] != 0
    exact = conf[C_EXACT] != 0
    kind = conf[C_BASE]
    top_smooth = conf[C_TOP_SMOOTH] != 0
    base_smooth = conf[C_BASE_SMOOTH] != 0
    etas = coat_indices(real[R_ETA])
    a0 = real[R_ALPHA0]
    a1 = real[R_ALPHA1]
    g = real[R_G]
    # the optical depth per slot (Beer-Lambert crossings); a scattering walk's slots share one
    tau0 = ch[K_TAU, 0]
    tau1 = ch[K_TAU, 1]
    tau2 = ch[K_TAU, 2]
    thick = tau0
    alb0 = ch[K_ALBEDO, 0]
    alb1 = ch[K_ALBEDO, 1]
    alb2 = ch[K_ALBEDO, 2]
    scattering = (alb0 != 0.0 or alb1 != 0.0 or alb2 != 0.0) and thick > 0.0
    # the base's values per slot, read once (scalars: no array reference counts in the calls)
    base = (ch[K_RHO, 0], ch[K_RHO, 1], ch[K_RHO, 2], ch[K_ETA, 0], ch[K_K, 0], ch[K_ETA, 1], ch[K_K, 1],
            ch[K_ETA, 2], ch[K_K, 2])
    cond = base[3:]
    rough_conductor = kind == BASE_CONDUCTOR and not base_smooth
    mirror = kind == BASE_CONDUCTOR and base_smooth
    f0 = 0.0
    f1 = 0.0
    f2 = 0.0
    # the path from the viewer enters the coat (radiance transport, transmission only), and the
    # direction the light arrives with inside the coat is drawn once (importance transport)
    ok, wx, wy, wz, wf, wpdf, dx, dy, dz, df, dpdf = coat_entries(vx, vy, vz, lx, ly, lz, etas, a0, top_smooth,
                                                                   tv, tl, exact, s)
    if not ok:
        return f0, f1, f2
    # the rough conductor's Lambda of -d, once per walk
    lam_d = ggx_lambda(-dx, -dy, -dz, a1, a1) if rough_conductor else 0.0
    b = wf * abs(wz) / wpdf
    b0 = b
    b1 = b
    b2 = b
    z = thick
    at_top = True
    # what depends on the current direction w alone, computed when first needed and kept until w
    # changes (the same numbers as computing them at each use): the slots' transmittances through
    # the slab along w (w_tr), the coat's Lambda and G1 of w (w_coat); along d, once per walk
    d_tr = False
    t_d0 = t_d1 = t_d2 = 1.0
    w_tr = False
    t_w0 = t_w1 = t_w2 = 1.0
    w_coat = False
    lam_w = g1_w = 0.0
    for depth in range(max_depth):
        # Russian roulette on the largest channel
        bm = max(b0, max(b1, b2))
        if depth > 3 and bm < 0.25:
            q = max(0.0, 1.0 - bm)
            if next_float(s) < q:
                break
            b0 /= 1.0 - q
            b1 /= 1.0 - q
            b2 /= 1.0 - q
        if not scattering:
            # cross the absorbing layer to the other interface
            at_top = not at_top
            z = thick if at_top else 0.0
            if not w_tr:
                t_w0, t_w1, t_w2 = _tr3(tau0, tau1, tau2, wz)
                w_tr = True
            b0 *= t_w0
            b1 *= t_w1
            b2 *= t_w2
        else:
            dist = -math.log1p(-next_float(s)) * abs(wz)
            zp = z + dist if wz > 0.0 else z - dist
            if zp == z:
                continue
            if 0.0 < zp < thick:
                # a scattering vertex: connect to the light through the coat along d
                p = hg_phase(-(wx * dx + wy * dy + wz * dz), g)
                wt = 1.0
                if not top_smooth:
                    wt = _power_heuristic(dpdf, p)
                c = p * wt * _tr(zp - thick, dz) * df / dpdf
                f0 += b0 * alb0 * c
                f1 += b1 * alb1 * c
                f2 += b2 * alb2 * c
                # continue the walk along a direction drawn from the phase function
                nx, ny, nz = hg_scatter(wx, wy, wz, g, next_float(s), next_float(s))
                pp = hg_phase(wx * nx + wy * ny + wz * nz, g)
                b0 *= alb0
                b1 *= alb1
                b2 *= alb2
                wx, wy, wz = nx, ny, nz
                w_tr = w_coat = False
                z = zp
                if wz > 0.0 and not top_smooth:
                    lam_w, g1_w, _ = coat_terms(wx, wy, wz, a0)
                    w_coat = True
                    fe, pe = coat_exit(wx, wy, wz, lx, ly, lz, etas, a0, tl, lam_w, g1_w, fixed, exact)
                    if fe != 0.0:
                        c = _tr(zp - thick, wz) * fe * _power_heuristic(pp, pe)
                        f0 += b0 * c
                        f1 += b1 * c
                        f2 += b2 * c
                continue
            # the flight reached an interface
            z = min(max(zp, 0.0), thick)
            at_top = z == thick
        if at_top:
            # at the coat from inside: reflect back into the layer (leaving is only counted by the
            # connections)
            if not w_coat and not top_smooth:
                lam_w, g1_w, _ = coat_terms(wx, wy, wz, a0)
                w_coat = True
            ok, nx, ny, nz, bf, bpdf = coat_reflect(wx, wy, wz, etas, a0, top_smooth, lam_w, g1_w, exact,
                                                    next_float(s), next_float(s), next_float(s))
            if not ok or bf == 0.0 or bpdf == 0.0 or nz == 0.0:
                break
            k = bf * abs(nz) / bpdf
            b0 *= k
            b1 *= k
            b2 *= k
            wx, wy, wz = nx, ny, nz
            w_tr = w_coat = False
        else:
            # at the base: connect along d unless the base is a mirror, then sample the base
            if not mirror:
                if rough_conductor:
                    # the base's Lambda and G1 of -w, shared by the connection and the sample
                    lam_b = ggx_lambda(-wx, -wy, -wz, a1, a1)
                    g1_b = smith_g1_dir(-wx, -wy, -wz, a1, a1)
                    e0, e1, e2, bp = conductor_pair(-wx, -wy, -wz, -dx, -dy, -dz, a1, lam_b, lam_d, g1_b, *cond)
                else:
                    e0, e1, e2 = base_f(-wx, -wy, -wz, -dx, -dy, -dz, kind, a1, base_smooth, *base)
                wt = 1.0
                if not top_smooth:
                    if not rough_conductor:
                        bp = base_pdf(-wx, -wy, -wz, -dx, -dy, -dz, kind, a1, base_smooth)
                    wt = _power_heuristic(dpdf, bp)
                c = abs(dz) * wt * df / dpdf
                if not d_tr:
                    t_d0, t_d1, t_d2 = _tr3(tau0, tau1, tau2, dz)
                    d_tr = True
                f0 += b0 * e0 * c * t_d0
                f1 += b1 * e1 * c * t_d1
                f2 += b2 * e2 * c * t_d2
            if rough_conductor:
                ok, nx, ny, nz, k0, k1, k2, bpdf = conductor_sample(-wx, -wy, -wz, a1, lam_b, g1_b, *cond,
                                                                    next_float(s), next_float(s))
            else:
                ok, nx, ny, nz, k0, k1, k2, bpdf = base_sample(-wx, -wy, -wz, kind, a1, base_smooth, *base,
                                                               next_float(s), next_float(s))
            if not ok or bpdf == 0.0:
                break
            b0 *= k0
            b1 *= k1
            b2 *= k2
            wx, wy, wz = nx, ny, nz
            w_tr = w_coat = False
            if not top_smooth:
                # connect the sampled direction (w_z > 0) to the light through the coat
                lam_w, g1_w, _ = coat_terms(wx, wy, wz, a0)
                w_coat = True
                t_w0, t_w1, t_w2 = _tr3(tau0, tau1, tau2, wz)
                w_tr = True
                fe, pe = coat_exit(wx, wy, wz, lx, ly, lz, etas, a0, tl, lam_w, g1_w, fixed, exact)
                if fe != 0.0:
                    wt = 1.0
                    if not mirror:
                        wt = _power_heuristic(bpdf, pe)
                    c = fe * wt
                    f0 += b0 * c * t_w0
                    f1 += b1 * c * t_w1
                    f2 += b2 * c * t_w2
        if b0 == 0.0 and b1 == 0.0 and b2 == 0.0:
            break
    return f0, f1, f2


@njit(cache=True)
def evaluate_one(vx: float, vy: float, vz: float, lx: float, ly: float, lz: float, conf: np.ndarray,
                 real: np.ndarray, chan: np.ndarray, source: np.ndarray, s: np.ndarray, mean: np.ndarray,
                 var: np.ndarray, out: np.ndarray) -> None:
    """``out[0:3]`` = the coat's reflection, ``out[3:6]`` = pbrt's estimate of the rest (the mean of
    ``n_samples`` walks), ``out[6:9]`` = its standard error (from the walks' sample variance; with
    one walk, from one more independent walk that the estimate does not use). ``s`` (4 uint64),
    ``mean`` and ``var`` (3, 3) are workspace."""
    for k in range(9):
        out[k] = 0.0
    if not (vz > 0.0 and lz > 0.0) or not math.isfinite(vx + vy + vz):
        return
    if conf[C_TOP_SMOOTH] == 0:
        top = microfacet_reflection(lx, ly, lz, vx, vy, vz, real[R_ALPHA0], real[R_ALPHA0], real[R_ETA], 0.0, True)
        out[0] = top
        out[1] = top
        out[2] = top
    ns = conf[C_SAMPLES]
    runs = max(ns, 2)
    key = direction_key(conf[C_SEED], vx, vy, vz, lx, ly, lz)
    tv = coat_terms(vx, vy, vz, real[R_ALPHA0])
    tl = coat_terms(lx, ly, lz, real[R_ALPHA0])
    n_groups = chan.shape[0]
    for gr in range(n_groups):
        if n_groups > 1 and gr > 0:
            same = True
            for r in range(5):
                if chan[gr, r, 0] != chan[gr - 1, r, 0]:
                    same = False
            if same:
                for c in range(3):
                    mean[gr, c] = mean[gr - 1, c]
                    var[gr, c] = var[gr - 1, c]
                continue
        seed_state(s, key)
        ch = chan[gr]
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        q0 = 0.0
        q1 = 0.0
        q2 = 0.0
        first0 = 0.0
        first1 = 0.0
        first2 = 0.0
        x0 = 0.0
        x1 = 0.0
        x2 = 0.0
        for j in range(runs):
            x0, x1, x2 = walk(vx, vy, vz, lx, ly, lz, tv, tl, conf, real, ch, s)
            if j == 0:
                first0, first1, first2 = x0, x1, x2
            if ns == 1:
                continue
            s0 += x0
            s1 += x1
            s2 += x2
            q0 += x0 * x0
            q1 += x1 * x1
            q2 += x2 * x2
        if ns == 1:
            # the estimate is the first walk; the second one only estimates its variance
            mean[gr, 0], mean[gr, 1], mean[gr, 2] = first0, first1, first2
            var[gr, 0] = 0.5 * (first0 - x0) ** 2
            var[gr, 1] = 0.5 * (first1 - x1) ** 2
            var[gr, 2] = 0.5 * (first2 - x2) ** 2
        else:
            inv = 1.0 / ns
            mean[gr, 0] = s0 * inv
            mean[gr, 1] = s1 * inv
            mean[gr, 2] = s2 * inv
            # variance of the mean: the sample variance over ns
            var[gr, 0] = max(0.0, q0 - s0 * s0 * inv) / (ns - 1) * inv
            var[gr, 1] = max(0.0, q1 - s1 * s1 * inv) / (ns - 1) * inv
            var[gr, 2] = max(0.0, q2 - s2 * s2 * inv) / (ns - 1) * inv
    for c in range(3):
        gr = source[c] // 3
        slot = source[c] % 3
        out[3 + c] = mean[gr, slot]
        out[6 + c] = math.sqrt(var[gr, slot])


@njit(cache=True, inline="always")
def _chunks(n: int) -> int:
    """Number of parallel chunks for ``n`` directions."""
    return max(1, min(n // 64, 1024))


@njit(parallel=True, cache=True)
def evaluate_many(l: np.ndarray, v: np.ndarray, conf: np.ndarray, real: np.ndarray, chan: np.ndarray,
                  source: np.ndarray, out: np.ndarray) -> None:
    """:func:`evaluate_one` for the light ``l`` (3,) and every view ``v[n]`` into ``out[n, :9]``; the
    result of a direction depends only on the pair (its random stream is keyed by it), so any
    thread count gives the same bits."""
    n_dir = v.shape[0]
    nc = _chunks(n_dir)
    for chunk in numba.prange(nc):
        s = np.empty(4, dtype=np.uint64)
        mean = np.zeros((3, 3))
        var = np.zeros((3, 3))
        for n in range(chunk * n_dir // nc, (chunk + 1) * n_dir // nc):
            evaluate_one(v[n, 0], v[n, 1], v[n, 2], l[0], l[1], l[2], conf, real, chan, source, s, mean, var, out[n])
