"""The real-time multi-layered microfacet model (``multilayer-lut``, S. Steinberg 2016, "Light
Transport in a Multi-Layered Microfacet Model", sections "Light transport through a microfacet layer"
and "Evaluating a multi-layered BRDF") with our own mean-transmission / mean-refraction tables
(:mod:`models.tables.multilayer`, no curve fits).

Conventions (as :mod:`models.base` and :mod:`goniometer.optics`): ``z`` is the macro normal; ``l``
(light) and ``v`` (viewer) point away from the surface. Inside the stack, the pair ``(l_k, v_k)``
lives in region ``k`` (region 0 = air, region ``k + 1`` lies below interface ``k``) and points
**up**, away from the layers below (``z > 0``). Values are BRDF values without the cosine factor, in
1/sr, RGB last; ``top`` is the GGX reflection of the top interface (the whole value for a single
conductor interface or a bare Lambertian, matching the simulator's bounce order 1), ``internal``
everything else. Masking is separable Smith ``G2 = G1 G1`` throughout.

Supported stacks: dielectric interfaces (relative indices within ``[ETA_MIN, ETA_MAX] = [1/3, 3]``)
with optional absorbing media between them, ending in a conductor interface or a Lambertian base;
also a bare conductor interface or a bare Lambertian. BRDF only. The model step by step, the choices
where the article is vague or wrong (which G, exit transmission by reciprocity, the radiance
Jacobian, ...) and its known limitations: ``docs/multilayer-lut.md``.
"""

from __future__ import annotations

import math
import os

import numba
import numpy as np

from goniometer.optics import ggx_lambda, microfacet_reflection, smith_g2
from goniometer.stack import Stack
from goniometer.kernel.packing import BASE_CONDUCTOR, BASE_LAMBERTIAN, pack
from models._jit import njit
from models.tables import multilayer as mt
from models.base import Model, ModelError, ModelValue

_INV_PI = 1.0 / math.pi


# ---------------------------------------------------------------------- kernel

@njit(cache=True, inline="always")
def _inner(wx: float, wy: float, c: float):
    """The unit inner direction (pointing up) of cosine ``c`` in the azimuth of ``w``."""
    s = math.sqrt(max(0.0, 1.0 - c * c))
    h = math.sqrt(wx * wx + wy * wy)
    if h > 0.0:
        return s * wx / h, s * wy / h, c
    return s, 0.0, c


@njit(cache=True)
def _transmit(wx: float, wy: float, wz: float, alpha: float, eta: float, up: np.ndarray,
              down: np.ndarray, split: float, coords: np.ndarray, k: int):
    """Cross dielectric interface ``k`` downwards from ``w`` (region above, pointing up).

    ``coords[k]`` holds the interface's :func:`models.tables.multilayer.prepare` result
    ``(j, fj, k, fk, w0)``. Returns ``(T, x, y, z, lam)``: the mean transmission, the mean refracted
    direction (pointing up, in the region below) and its Smith Lambda for the interface's
    roughness. ``eta == 1``: ``(1, w, 0)`` (the interface is absent). ``T = 0`` when nothing gets
    through (or the mean direction is grazing).
    """
    if eta == 1.0:
        return 1.0, wx, wy, wz, 0.0
    t, c = mt.lookup_prepared(up, down, split, int(coords[k, 0]), coords[k, 1], int(coords[k, 2]),
                              coords[k, 3], coords[k, 4], wz, eta)
    if t <= 0.0 or c <= 0.0:
        return 0.0, 0.0, 0.0, 1.0, 0.0
    x, y, z = _inner(wx, wy, c)
    return t, x, y, z, ggx_lambda(x, y, z, alpha, alpha)


@njit(cache=True, inline="always")
def _absorb(q: float, tau: float, a_l: float, z: float) -> float:
    """``q`` times the Beer-Lambert factors of the light (``a_l``) and of the view (``exp(-tau/z)``)."""
    if tau > 0.0:
        return q * a_l * math.exp(-tau / z)
    return q


@njit(cache=True, parallel=True)
def _kernel(l: np.ndarray, v: np.ndarray, up: np.ndarray, down: np.ndarray, split: float,
            d_alpha: np.ndarray, d_eta: np.ndarray, region_tau: np.ndarray, base_kind: int,
            rho: np.ndarray, c_alpha: float, c_eta: np.ndarray, c_kappa: np.ndarray, jacobian: bool,
            top: np.ndarray, internal: np.ndarray) -> None:
    """Fill ``top`` and ``internal`` (N, 3) for light ``l`` (3,) and views ``v`` (N, 3).

    ``d_alpha``/``d_eta`` (K,): roughness and relative index of the K dielectric interfaces;
    ``region_tau`` (K + 1 or more, 3): optical depth of region r (r = k + 1 lies below interface k);
    ``base_kind``: ``BASE_LAMBERTIAN`` (albedo ``rho``) or ``BASE_CONDUCTOR`` (roughness ``c_alpha``,
    complex index ``c_eta + i c_kappa`` relative to region K, RGB).
    """
    n_d = d_alpha.shape[0]
    top[:, :] = 0.0
    internal[:, :] = 0.0
    if not l[2] > 0.0:
        return
    # ---- the light path is the same for every view: follow it once
    lch = np.zeros((n_d + 1, 3))
    t_l = np.zeros(n_d)
    lam_l = np.zeros(n_d)
    a_l = np.ones((n_d + 1, 3))
    coords = np.zeros((n_d, 5))
    for k in range(n_d):
        j, fj, kk, fk, w0 = mt.prepare(up, down, d_alpha[k], d_eta[k])
        coords[k, 0], coords[k, 1], coords[k, 2], coords[k, 3], coords[k, 4] = j, fj, kk, fk, w0
    lch[0, 0], lch[0, 1], lch[0, 2] = l[0], l[1], l[2]
    depth = n_d  # deepest region the light reaches
    for k in range(n_d):
        t, x, y, z, lam = _transmit(lch[k, 0], lch[k, 1], lch[k, 2], d_alpha[k], d_eta[k], up, down, split,
                                    coords, k)
        if t <= 0.0:
            depth = k
            break
        t_l[k] = t
        lam_l[k] = lam
        lch[k + 1, 0], lch[k + 1, 1], lch[k + 1, 2] = x, y, z
        for c in range(3):
            if region_tau[k + 1, c] > 0.0:
                a_l[k + 1, c] = math.exp(-region_tau[k + 1, c] / z)
    # achromatic regions: q stays grey there if it is grey above (it is: only media colour it)
    grey = np.zeros(n_d + 1, dtype=np.bool_)
    colour = False
    for r in range(n_d + 1):
        colour = colour or not (region_tau[r, 0] == region_tau[r, 1] == region_tau[r, 2])
        grey[r] = not colour
    same12 = c_eta[1] == c_eta[0] and c_kappa[1] == c_kappa[0]
    same23 = c_eta[2] == c_eta[1] and c_kappa[2] == c_kappa[1]
    for n in numba.prange(v.shape[0]):   # a view's values depend on it alone: any thread count, same bits
        vx, vy, vz = v[n, 0], v[n, 1], v[n, 2]
        if not (vz > 0.0) or not math.isfinite(vx + vy + vz):
            continue
        q0 = 1.0
        q1 = 1.0
        q2 = 1.0
        reached = True
        for k in range(n_d):
            lx, ly, lz = lch[k, 0], lch[k, 1], lch[k, 2]
            alpha = d_alpha[k]
            eta = d_eta[k]
            # step 5: the interface's own reflection lobe
            if alpha > 0.0 and eta != 1.0:
                f = microfacet_reflection(lx, ly, lz, vx, vy, vz, alpha, alpha, eta, 0.0, False)
                if k == 0:
                    top[n, 0] = f
                    top[n, 1] = f
                    top[n, 2] = f
                else:
                    internal[n, 0] += q0 * f
                    internal[n, 1] += q1 * f
                    internal[n, 2] += q2 * f
            if k >= depth:
                reached = False
                break
            # steps 1-2, 7: transmission in and out, masking of the refracted pair, Jacobian
            t, vx, vy, vz, lam = _transmit(vx, vy, vz, alpha, eta, up, down, split, coords, k)
            if t <= 0.0:
                reached = False
                break
            if eta != 1.0:
                g = t_l[k] * t * smith_g2(lam_l[k], lam, False, False)
                if jacobian:
                    g /= eta * eta
                q0 *= g
                q1 *= g
                q2 *= g
            # steps 3-4: absorption in the region below
            r = k + 1
            if grey[r]:
                q0 = _absorb(q0, region_tau[r, 0], a_l[r, 0], vz)
                q1 = q0
                q2 = q0
            else:
                q0 = _absorb(q0, region_tau[r, 0], a_l[r, 0], vz)
                q1 = _absorb(q1, region_tau[r, 1], a_l[r, 1], vz)
                q2 = _absorb(q2, region_tau[r, 2], a_l[r, 2], vz)
        if not reached:
            continue
        # the base, seen along the deepest pair
        out = top if n_d == 0 else internal
        if base_kind == BASE_LAMBERTIAN:
            out[n, 0] += q0 * rho[0] * _INV_PI
            out[n, 1] += q1 * rho[1] * _INV_PI
            out[n, 2] += q2 * rho[2] * _INV_PI
        elif c_alpha > 0.0:
            lx, ly, lz = lch[n_d, 0], lch[n_d, 1], lch[n_d, 2]
            f0 = microfacet_reflection(lx, ly, lz, vx, vy, vz, c_alpha, c_alpha, c_eta[0], c_kappa[0], False)
            f1 = f0 if same12 else microfacet_reflection(lx, ly, lz, vx, vy, vz, c_alpha, c_alpha,
                                                         c_eta[1], c_kappa[1], False)
            f2 = f1 if same23 else microfacet_reflection(lx, ly, lz, vx, vy, vz, c_alpha, c_alpha,
                                                         c_eta[2], c_kappa[2], False)
            out[n, 0] += q0 * f0
            out[n, 1] += q1 * f1
            out[n, 2] += q2 * f2


# ---------------------------------------------------------------------- stacks

def unsupported_reason(stack: Stack) -> str | None:
    """Why :class:`MultilayerLUT` cannot represent ``stack`` (None if it can)."""
    if stack.transmits:
        return ("the stack ends in a dielectric interface and transmits light (a slab); this BRDF "
                "model needs an opaque base (conductor interface or Lambertian)")
    p = pack(stack)
    n_d = len(stack.interfaces) - (1 if p.base_kind == BASE_CONDUCTOR else 0)
    for k in range(n_d):
        eta = p.region_eta[k + 1] / p.region_eta[k]
        if not mt.ETA_MIN <= eta <= mt.ETA_MAX:
            return (f"interface {k} has relative index {eta:.4g}, outside the tables' range "
                    f"[{mt.ETA_MIN:.4g}, {mt.ETA_MAX:.4g}]")
    return None


def kernel_arguments(stack: Stack) -> tuple:
    """``(d_alpha, d_eta, region_tau, base_kind, rho, c_alpha, c_eta, c_kappa)`` of a supported stack."""
    p = pack(stack)
    n_d = len(stack.interfaces) - (1 if p.base_kind == BASE_CONDUCTOR else 0)
    d_alpha = np.ascontiguousarray(p.if_alpha[:n_d, 0], dtype=np.float64)
    d_eta = np.ascontiguousarray(p.region_eta[1:n_d + 1] / p.region_eta[:n_d], dtype=np.float64)
    region_tau = np.ascontiguousarray(p.region_tau, dtype=np.float64)
    rho = np.ascontiguousarray(p.rho, dtype=np.float64)
    if p.base_kind == BASE_CONDUCTOR:
        c_alpha = float(p.if_alpha[n_d, 0])
        c_eta = np.ascontiguousarray(p.cond[0:3], dtype=np.float64)
        c_kappa = np.ascontiguousarray(p.cond[3:6], dtype=np.float64)
    else:
        c_alpha = 0.0
        c_eta = np.ones(3)
        c_kappa = np.zeros(3)
    return d_alpha, d_eta, region_tau, int(p.base_kind), rho, c_alpha, c_eta, c_kappa


# ---------------------------------------------------------------------- models

class MultilayerLUT(Model):
    """Steinberg's real-time multi-layered microfacet model with our numerical T / C tables.

    The equations and every choice: ``docs/multilayer-lut.md``. ``cache_dir``: where the tables
    are cached (default ``$GONIOMETER_CACHE`` or ``~/.cache/goniometer``); they are built on first
    use (a few seconds).
    """

    name = "multilayer-lut"
    description = ("Multi-layered microfacet model (Steinberg 2016): top-down, mean transmission and "
                   "mean refraction tables, G of the refracted pair, radiance Jacobian")
    sides = ("brdf",)
    #: multiply by 1 / eta_k^2 per interface (radiance compression); ``docs/multilayer-lut.md``
    jacobian = True
    #: tables in cosines, GGX and Fresnel of l, v and h only (Model.mirror_symmetric)
    mirror_symmetric = True

    def __init__(self, cache_dir: str | os.PathLike | None = None) -> None:
        self.cache_dir = cache_dir

    def support_reason(self, stack: Stack) -> str | None:
        return unsupported_reason(stack)

    def _evaluate(self, stack: Stack, l: np.ndarray, v: np.ndarray, side: str) -> ModelValue:
        if side != "brdf":  # unreachable: Model.evaluate checks sides
            raise ModelError(f"{self.name}: cannot evaluate the {side.upper()}")
        tables = mt.load_multilayer_tables(self.cache_dir)
        shape = v.shape[:-1]
        vv = np.ascontiguousarray(v, dtype=np.float64).reshape(-1, 3)
        top = np.empty((vv.shape[0], 3))
        internal = np.empty((vv.shape[0], 3))
        d_alpha, d_eta, region_tau, base_kind, rho, c_alpha, c_eta, c_kappa = kernel_arguments(stack)
        _kernel(np.ascontiguousarray(l, dtype=np.float64), vv, *tables.args, d_alpha, d_eta, region_tau,
                base_kind, rho, c_alpha, c_eta, c_kappa, bool(self.jacobian), top, internal)
        return ModelValue(top=top.reshape(shape + (3,)), internal=internal.reshape(shape + (3,)))


class MultilayerLUTArticle(MultilayerLUT):
    """:class:`MultilayerLUT` without the radiance Jacobian ``1 / eta^2``, which the article omits.

    Only that factor differs: the tables' weights, the masking term and the exit transmission are
    ours (``docs/multilayer-lut.md`` lists where the article reads otherwise). Not registered by
    default; kept to show the effect of the article's omission.
    """

    name = "multilayer-lut-article"
    description = "Multi-layered microfacet model (Steinberg 2016) without the radiance Jacobian, as published"
    jacobian = False
