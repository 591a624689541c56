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

Every microfacet, Fresnel, refraction and phase formula comes from :mod:`goniometer.optics`; the
coat (:mod:`models.pbrt_layered.coat`: pbrt's rough dielectric with the masking ``G = 1 / (1 +
Lambda_o + Lambda_i)`` in both lobes) and the base (:mod:`models.pbrt_layered.base`: Lambertian,
rough or smooth conductor) compose them the way pbrt's component BxDFs do, each with the fused
steps the walk takes (the same bits as the plain compositions; ``benchmarks/README.md``, issue 34,
the time they save). This module holds the walk (:func:`walk`: the Henyey-Greenstein medium, the
connections, pbrt's MIS weights) and the evaluation per direction pair (:func:`evaluate_one`,
:func:`evaluate_many`).

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
from goniometer.optics import ggx_lambda, hg_phase, microfacet_reflection, smith_g1_dir
from goniometer.kernel.rng import next_float, seed_state, splitmix64
from goniometer.kernel.packing import BASE_CONDUCTOR
from models._jit import njit
from models.pbrt_layered.base import base_f, base_pdf, base_sample, conductor_pair, conductor_sample
from models.pbrt_layered.coat import coat_entries, coat_exit, coat_indices, coat_reflect, coat_terms

#: indices of ``conf``
C_MAX_DEPTH, C_SAMPLES, C_FIXED, C_EXACT, C_GROUPS, C_BASE, C_TOP_SMOOTH, C_BASE_SMOOTH, C_SEED = range(9)
#: indices of ``real``
R_ETA, R_ALPHA0, R_ALPHA1, R_G = range(4)
#: rows of ``chan``
K_TAU, K_ALBEDO, K_RHO, K_ETA, K_K = range(5)

#: pbrt's threshold under which a GGX distribution is a perfect mirror/refractor
SMOOTH_ALPHA = 1e-3


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
    # the slab along w (w_tr), the coat's Lambda, G1 and the sampler's stretch of w (w_coat); along d, once per walk
    d_tr = False
    t_d0 = t_d1 = t_d2 = 1.0
    w_tr = False
    t_w0 = t_w1 = t_w2 = 1.0
    w_coat = False
    lam_w = g1_w = st_w = 0.0
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
                    lam_w, g1_w, st_w = coat_terms(wx, wy, wz, a0)
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
                lam_w, g1_w, st_w = coat_terms(wx, wy, wz, a0)
                w_coat = True
            ok, nx, ny, nz, bf, bpdf = coat_reflect(wx, wy, wz, etas, a0, top_smooth, lam_w, g1_w, st_w, exact,
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
                lam_w, g1_w, st_w = coat_terms(wx, wy, wz, a0)
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
