"""The coat of the ``pbrt-layered`` rows: pbrt-v4's rough (or smooth) dielectric, as its layered
BSDF samples and evaluates it (``docs/pbrt-layered.md``; conventions of
:mod:`models.pbrt_layered.kernel`: pbrt's ``wo``/``wi``, both pointing away, no cosine).

:func:`diel_sample`, :func:`diel_f` and :func:`diel_pdf` compose :mod:`goniometer.optics`' formulas
the way pbrt's dielectric BxDF does (the masking ``G = 1 / (1 + Lambda_o + Lambda_i)`` in both
lobes). The walk's hot steps (:func:`coat_entries`, :func:`coat_reflect`, :func:`coat_exit`) are
fused versions of them with the same bits: the same expressions in the same order, with what depends
on one direction only (its Lambda, G1, the sampler's stretch) or is shared (a reflection's half
vector and D, the index's reciprocals, :func:`coat_indices`) computed once
(``tests/models/test_pbrt_layered.py`` holds each to the plain composition, bit for bit)."""

from __future__ import annotations

import math

import numpy as np

from goniometer.optics import (cos_sin_2pi, fresnel_dielectric, fresnel_dielectric_cos_t_inv, ggx_d, ggx_lambda,
                               microfacet_reflection, microfacet_transmission, microfacet_transmission_given, reflect,
                               refract, refract_known, sample_vndf, sample_vndf_polar, smith_g1_dir, smith_g2,
                               vndf_pdf, vndf_pdf_given, vndf_stretch_norm2)
from goniometer.kernel.rng import next_float
from models._jit import njit
from models.pbrt_layered.numeric import quotient


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


@njit(cache=True, inline="always")
def _lobe_weights(c: float, eta: float, refl: bool, trans: bool):
    """``(F, p_r, p_t)`` of the coat seen along a direction of cosine ``c`` to its (micro)normal
    (from outside where ``c > 0``, index ``eta``; from inside ``1 / eta``): the Fresnel reflectance
    and the weights pbrt chooses the reflection and the transmission lobe by, each 0 where its flag
    leaves the lobe out."""
    r = fresnel_dielectric(c, eta if c > 0.0 else 1.0 / eta)
    return r, (r if refl else 0.0), ((1.0 - r) if trans else 0.0)


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
    r, pr, pt = _lobe_weights(dmo, eta, refl, trans)
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
        r, pr, pt = _lobe_weights(oz, eta, refl, trans)
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
    r, pr, pt = _lobe_weights(dmo, eta, refl, trans)
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
    # vndf_pdf of o (of -o inside)
    d = ggx_d(mx, my, mz, a, a)
    if oz > 0.0:
        dw = vndf_pdf_given(ox, oy, oz, mx, my, mz, g1, d)
    else:
        dw = vndf_pdf_given(-ox, -oy, -oz, mx, my, mz, g1, d)
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
    next_float(s)   # the light's lobe choice, drawn as diel_sample draws it (transmission only: unused)
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
                 g1_w: float, st_w: float, exact: bool, uc: float, u1: float, u2: float):
    """:func:`diel_sample` of ``-w`` (``w_z > 0``: the walk at the coat from inside) for reflection
    only, radiance transport, given ``etas`` (:func:`coat_indices`) and ``lam_w``, ``g1_w``, ``st_w``
    (:func:`coat_terms` of ``w``). Returns ``(ok, wi_x, wi_y, wi_z, f, pdf)``."""
    eta = etas[0]
    if smooth or wz <= 0.0:
        return diel_sample(-wx, -wy, -wz, eta, a, smooth, True, True, False, exact, uc, u1, u2)
    ox = -wx
    oy = -wy
    oz = -wz
    cp, sp = cos_sin_2pi(u1)
    mx, my, mz = sample_vndf_polar(wx, wy, wz, a, a, cp, sp, u2, st_w)
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
    f = quotient(_fresnel_coat(lh, etas, False) * d * g, 4.0 * -iz * -oz)
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
    dw = vndf_pdf_given(wx, wy, wz, mx, my, mz, g1_w, d)
    return True, ix, iy, iz, f, dw / (4.0 * abs(dmo)) * pr / (pr + pt)
