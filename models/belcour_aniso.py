"""Anisotropic Belcour model (``belcour-aniso``): Belcour 2018's forward model with a 2 x 2
covariance per statistic instead of a scalar variance, after Yamaguchi et al. 2019
(``shared/papers/anisotropic-belcour-extension.txt``, cited as Y19) -- Belcour's adding-doubling
otherwise unchanged (``shared/spec/belcour2018.md``, cited as §n; isotropic code in
:mod:`models.belcour`).

Conventions
-----------
As :mod:`models.base`: ``l`` towards the light (``l_z > 0``), ``v`` towards the viewer, values
without cosine in 1/sr, RGB last, ``top`` = lobe 0 (the top interface), ``internal`` = the other
lobes. Covariances live in the **macro tangent plane** (x towards phi = 0, y towards phi = 90 deg)
and are stored as their three distinct entries ``(xx, xy, yy)``. An interface's tangent frame is
rotated by ``psi = rotation_deg`` about z (as the simulator, :mod:`goniometer.tracer`): its axes are
``t_x = (cos psi, sin psi)`` and ``t_y = (-sin psi, cos psi)``, so a vector ``w`` has tangent-frame
coordinates ``x' = c w_x + s w_y``, ``y' = -s w_x + c w_y``.

Equations
---------
* **Interface covariance** (Y19 section 3.1 and appendix A.2):
  ``Sigma = [t_x t_y] diag(sigma_x, sigma_y) [t_x t_y]^T``, i.e.
  ``xx = sigma_x c^2 + sigma_y s^2``, ``xy = (sigma_x - sigma_y) c s``, ``yy = sigma_x s^2 + sigma_y c^2``,
  with ``sigma_{x,y} = h(alpha_{x,y})`` for reflection and ``h(s alpha_{x,y})`` for refraction (down and
  up), ``h(a) = a^1.1 / (1 - a^1.1)`` (:func:`models.belcour.roughness_to_variance`, §2) and the
  transmission scales ``s`` of the isotropic model (normal-incidence form by default, angular form
  with ``transmission_scale="angular"``, §3). An isotropic interface gives ``h(alpha) I`` exactly.
* **Jacobians** (Y19 eqs. 4-5): the maps from half-vector slopes to projected reflected
  (``J_r ~ 2 cos theta_i I``) and refracted (``J_t ~ (cos theta_i - cos theta_t) / eta I``) directions are
  multiples of the identity, so the principal axes of an interface's lobe are its tangent axes
  (the covariance above) and only *scalar* factors act on accumulated covariances. Their magnitudes
  are already in ``h(alpha)`` and ``h(s alpha)`` (``J_t / J_r`` at normal incidence is the transmission
  scale ``s``), and the accumulated covariances are scaled by the same scalar variance Jacobians
  ``j_12 = eta c_2 / c``, ``j_21 = 1 / j_12`` as the isotropic model ("exactly the same procedure",
  Y19 section 3.1).
* **Adding-doubling** (§6, Bati 2021 eqs. 2, 4, 5; Y19 A.2): every variance of §6 becomes a
  covariance; all operations on variances are linear with scalar coefficients (Jacobians, the
  inter-reflection factor ``m = Ri0 R / (1 - Ri0 R)``, energy weights), so the matrix recurrences are
  the scalar ones applied to each entry:
  ``Sigma_k = Sigma_Ti0 + J0i (Sigma_T0i + Sigma_r + m (Sigma_r + Sigma_Ri0))`` etc. Energies and mean
  directions are unchanged (Y19 section 3.1: "the same representations as the previous study").
* **Lobes** (Y19 eq. 3 with an anisotropic GGX): ``f = sum_k E_k D(h'; a_1, a_2) G(l', v'; a_1, a_2) /
  (4 l_z v_z)``, ``h = normalize(l + v)``, primes = coordinates in the lobe's principal frame, D and
  Smith Lambda from :mod:`goniometer.optics` (separable G by default, height-correlated on request).

Choices where Y19 is vague (each tested in ``tests/models/test_belcour_aniso.py``)
--------------------------------------------------------------------------------
* **Lobe GGX from a covariance**: the principal axes of ``Sigma_k`` are the lobe's tangent axes and
  the roughness along each is ``h^-1`` of the eigenvalue -- the exact inverse of the interface
  covariance above (an interface alone gives back its own ``alpha_x, alpha_y, psi``). ``a_1 >= a_2``,
  the frame's x axis is the eigenvector of the larger eigenvalue; each roughness is clamped to
  ``>= ALPHA_EVAL_MIN`` for evaluation (as the isotropic model). An isotropic covariance
  (``xy = 0``, ``xx = yy``) gives ``a_1 = a_2 = h^-1(xx)`` without any rotation.
* **FGD (and TIR) lookup roughness of an anisotropic interface.** The isotropic model looks up
  ``FGD(c, a~)`` with ``a~ = h^-1(vT0i + h(alpha_i))`` (§4). Here ``Sigma~ = Sigma_T0i + Sigma_r`` is
  decomposed as above into ``(a_1, a_2, e_1)`` and the isotropic table is looked up with
  ``a~^2 = c^2 (a_1^2 + a_2^2) / 2 + (1 - c^2) a_d^2``, ``a_d^2 = a_1^2 (d.e_1)^2 + a_2^2 (d.e_2)^2``, where
  ``c`` is the mean cosine in the interface's medium (the table's mu) and ``d`` the unit azimuth of the
  incident direction (unchanged by Snell). Rationale: the anisotropic Smith Lambda of a direction is
  the isotropic one with the projected roughness ``a_d`` along its azimuth, which dominates at
  grazing incidence, while at normal incidence the albedo sees both axes (quadratic mean). Measured
  against a direct quadrature of the single-scattering anisotropic albedo (500 random cases,
  alpha_{x,y} in [0.01, 0.7], five materials): mean absolute error 0.009 against 0.013 for the
  quadratic mean alone, 0.014 for ``h^-1(tr Sigma / 2)`` and 0.014 for ``a_d`` alone; for the
  coloured conductor ``1.45 + 1i`` 0.004 against 0.009. (A silver-like ``0.2 + 3i``, whose FGD is not
  monotonic in alpha at grazing angles, prefers the quadratic mean: 0.010 against 0.028.) Isotropic
  ``Sigma~`` gives ``h^-1(xx)`` (and ``alpha`` itself when nothing is accumulated above), as §4.
* **Channels**: with ``per_channel=True`` (default, as MODELS.md asks) each channel has its own
  covariance. ``per_channel=False`` is the isotropic model's averaged mode applied entrywise, our
  reading of Y19 section 4 ("an average covariance matrix ... for three color channels following
  the public implementation"): the channel-averaged scalar weights (``m`` and the energy weights of
  the accumulated covariances) multiply every entry, so each lobe has one covariance shared by the
  channels. Every weight is non-negative, so covariances stay symmetric positive semi-definite.
* **FGD itself**: Y19 section 4 replaces FGD by Unity's ``F G`` at the mirror direction; here the
  isotropic model's FGD/TIR material slices (single scattering) are kept, so that the model reduces
  to ``belcour-fwd``.
* ``incident="view"``: the statistics then depend on the view direction's cosine *and* azimuth (through
  the lookup roughness). They are tabulated per stack at ``direction_grid`` cosines (as the isotropic
  model) times ``azimuth_grid`` azimuths on [0, pi) (the lookup rule depends on ``d d^T`` only, so it
  is pi-periodic); the table stores lobe energies and the clamped *roughness matrices*
  ``A = a_1 e_1 e_1^T + a_2 e_2 e_2^T``, interpolated linearly in ``(sqrt c, phi)``, whose eigen-
  decomposition gives the lobe per direction. An isotropic stack uses one azimuth and reproduces
  ``belcour-fwd``'s interpolation exactly. Measured against per-direction statistics with the default
  128 azimuths: median relative difference < 1e-5, at most 4.5e-3 (views ~1 deg above the horizon,
  anisotropic coat; it falls as 1 / azimuths^2: 1.5e-3 with 256). Building the table costs ~0.35 s
  per stack on one core (memoised per model instance). ``direction_grid=0`` runs the adding-doubling
  per direction instead.

Reduction: for a stack whose interfaces are all isotropic every covariance is ``sigma I`` with the
very floating-point operations of :func:`models.belcour.adding_doubling` on its diagonal, so
``belcour-aniso`` equals ``belcour-fwd`` (same options) to the last bit.

Reuse: packing, FGD/TIR slices and options come from :mod:`models.belcour` (whose
:func:`~models.belcour.pack_stack` refuses anisotropic interfaces, so it is given an isotropic
*proxy* of the stack -- the same indices with roughness ``alpha_x`` -- and the covariances are added
here; the slices do not depend on roughness). The kernel :func:`adding_doubling_aniso` mirrors
:func:`models.belcour.adding_doubling` line by line (that kernel computes the FGD roughness
internally from scalar variances, so it cannot be called with covariances).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numba
import numpy as np

from goniometer import optics
from goniometer.stack import Interface, Stack
from models import tables
from models.base import Model, ModelValue
from models.belcour import (_S_MISC, _S_R0, _S_RI, _S_T0, _S_TI, _W_DINV, _W_E, _W_M, _W_RDN, _W_RUP, _W_RUP2,
                            _W_TDN, _W_TUP, ALPHA_EVAL_MIN, COS_MIN, DIRECTION_GRID, KIND_CONDUCTOR, KIND_MEDIUM,
                            BelcourOptions, PackedStack, _chunks, _mean_row, pack_stack, roughness_to_variance,
                            unsupported_reason, variance_to_roughness)

#: azimuth nodes on [0, pi) of the ``incident="view"`` statistics table (anisotropic stacks)
AZIMUTH_GRID = 128

#: rows of the covariance state: Sigma_R0i, Sigma_T0i, Sigma_Ri0, Sigma_Ti0 (Bati 2021 notation)
_C_R0, _C_T0, _C_RI, _C_TI = range(4)
#: rows of the per-entry covariance scratch: reflection, transmission down, transmission up
_E_R, _E_TD, _E_TU = range(3)
#: columns of the lobe parameters: a_1, a_2, principal axis (e_x, e_y), Smith Lambda of l
_P_A1, _P_A2, _P_EX, _P_EY, _P_LAM = range(5)


# --------------------------------------------------------------------------- 2 x 2 algebra

@numba.njit(cache=True, inline="always")
def interface_covariance(sx: float, sy: float, c: float, s: float) -> tuple:
    """``[t_x t_y] diag(sx, sy) [t_x t_y]^T`` with ``t_x = (c, s)``, ``t_y = (-s, c)`` (Y19 section 3.1):
    ``(xx, xy, yy)``."""
    return sx * c * c + sy * s * s, (sx - sy) * c * s, sx * s * s + sy * c * c


@numba.njit(cache=True, inline="always")
def principal(xx: float, xy: float, yy: float) -> tuple:
    """Eigen-decomposition of a symmetric 2 x 2 matrix: ``(l1, l2, ex, ey)`` with ``l1 >= l2`` and
    ``(ex, ey)`` the unit eigenvector of ``l1`` (``(1, 0)`` when the matrix is a multiple of I)."""
    m = 0.5 * (xx + yy)
    h = 0.5 * (xx - yy)
    r = math.sqrt(h * h + xy * xy)
    if r == 0.0:
        return m, m, 1.0, 0.0
    if h >= 0.0:
        ex, ey = h + r, xy
    else:
        ex, ey = xy, r - h
    inv = 1.0 / math.sqrt(ex * ex + ey * ey)
    return m + r, m - r, ex * inv, ey * inv


@numba.njit(cache=True, inline="always")
def blended_alpha(a1: float, a2: float, ex: float, ey: float, c: float, dx: float, dy: float) -> float:
    """FGD lookup roughness of an anisotropic GGX ``(a1 along (ex, ey), a2 across)`` seen at mean
    cosine ``c`` from azimuth ``d = (dx, dy)``:
    ``sqrt(c^2 (a1^2 + a2^2) / 2 + (1 - c^2) a_d^2)``, ``a_d^2 = a1^2 (d.e1)^2 + a2^2 (d.e2)^2``."""
    p = dx * ex + dy * ey
    q = dy * ex - dx * ey
    ad2 = a1 * a1 * p * p + a2 * a2 * q * q
    c2 = c * c
    return math.sqrt(c2 * 0.5 * (a1 * a1 + a2 * a2) + (1.0 - c2) * ad2)


@numba.njit(cache=True)
def lookup_alpha(xx: float, xy: float, yy: float, c: float, dx: float, dy: float) -> float:
    """FGD/TIR lookup roughness of the covariance ``(xx, xy, yy)`` (module docstring): ``h^-1(xx)`` if
    isotropic, else :func:`blended_alpha` of its principal roughnesses ``h^-1(eigenvalue)``."""
    if xy == 0.0 and xx == yy:
        return variance_to_roughness(xx)
    l1, l2, ex, ey = principal(xx, xy, yy)
    return blended_alpha(variance_to_roughness(l1), variance_to_roughness(l2), ex, ey, c, dx, dy)


@numba.njit(cache=True, inline="always")
def _set_interface_cov(out, row: int, ax: float, ay: float, c: float, s: float, iso: bool) -> None:
    """``out[row] = Sigma`` of roughnesses (ax, ay) in the frame (c, s) (``h(ax) I`` if ``iso``)."""
    if iso:
        v = roughness_to_variance(ax)
        out[row, 0] = v
        out[row, 1] = 0.0
        out[row, 2] = v
    else:
        xx, xy, yy = interface_covariance(roughness_to_variance(ax), roughness_to_variance(ay), c, s)
        out[row, 0] = xx
        out[row, 1] = xy
        out[row, 2] = yy


# --------------------------------------------------------------------------- packing

@dataclass(frozen=True)
class PackedAniso:
    """:class:`models.belcour.PackedStack` of the isotropic proxy plus the anisotropic data.

    Per entry (interfaces and media, top first): ``alpha_x``, ``alpha_y`` (tangent-frame roughnesses),
    ``rot`` = (cos, sin) of the tangent-frame rotation, ``iso`` (isotropic interface or medium), and
    the covariances ``(xx, xy, yy)`` of reflection ``cov_r`` and of the normal-incidence transmission
    down/up ``cov_td``/``cov_tu``. ``isotropic``: every interface is isotropic.
    """

    base: PackedStack
    alpha_x: np.ndarray
    alpha_y: np.ndarray
    rot: np.ndarray
    iso: np.ndarray
    cov_r: np.ndarray
    cov_td: np.ndarray
    cov_tu: np.ndarray
    isotropic: bool

    @property
    def n_lobes(self) -> int:
        return self.base.n_lobes

    def kernel_args(self) -> tuple:
        """The stack arguments of :func:`adding_doubling_aniso`, in order."""
        b = self.base
        return (b.kind, self.alpha_x, self.alpha_y, self.rot, self.iso, self.cov_r, self.cov_td, self.cov_tu,
                b.n_mean, b.tau, b.eta_up, b.achromatic, b.fgd_split, b.fgd_lower, b.fgd_upper, b.tir_split,
                b.tir_lower, b.tir_upper)


def isotropic_proxy(stack: Stack, roughness: str = "x") -> Stack:
    """``stack`` with every interface made isotropic: roughness ``alpha_x`` (``"x"``) or the mean
    ``(alpha_x + alpha_y) / 2`` (``"mean"``); indices and everything else unchanged."""
    layers = []
    for layer in stack.layers:
        if isinstance(layer, Interface):
            ax, ay = layer.alpha_xy
            a = ax if roughness == "x" else 0.5 * (ax + ay)
            layer = Interface(a, layer.ior, layer.extinction)
        layers.append(layer)
    return Stack(stack.name, tuple(layers), stack.category)


def pack_aniso(stack: Stack, options: BelcourOptions = BelcourOptions()) -> PackedAniso:
    """Flatten a supported (possibly anisotropic) stack: proxy packing + covariances."""
    base = pack_stack(isotropic_proxy(stack), options)
    ne = len(stack.layers)
    alpha_x = np.array(base.alpha, dtype=float)
    alpha_y = alpha_x.copy()
    rot = np.zeros((ne, 2))
    rot[:, 0] = 1.0
    iso = np.ones(ne, dtype=np.bool_)
    cov_r = np.zeros((ne, 3))
    cov_td = np.zeros((ne, 3))
    cov_tu = np.zeros((ne, 3))
    for e, layer in enumerate(stack.layers):
        if not isinstance(layer, Interface):
            continue
        # isotropic entries: exactly the scalar variances of pack_stack, on the diagonal
        cov_r[e] = (base.var_r[e], 0.0, base.var_r[e])
        cov_td[e] = (base.var_t_down[e], 0.0, base.var_t_down[e])
        cov_tu[e] = (base.var_t_up[e], 0.0, base.var_t_up[e])
        if not layer.is_anisotropic:
            continue
        ax, ay = layer.alpha_xy
        psi = math.radians(layer.rotation_deg)
        c, s = math.cos(psi), math.sin(psi)
        n = base.n_mean[e]
        alpha_y[e] = ay
        rot[e] = (c, s)
        iso[e] = False
        # normal-incidence transmission scales as pack_stack: s_down = |n - 1| / (2 n), s_up = |1 - n| / 2
        for out, sx, sy in ((cov_r, roughness_to_variance(ax), roughness_to_variance(ay)),
                            (cov_td, roughness_to_variance(ax * 0.5 * abs(n - 1.0) / n),
                             roughness_to_variance(ay * 0.5 * abs(n - 1.0) / n)),
                            (cov_tu, roughness_to_variance(ax * 0.5 * abs(1.0 - n)),
                             roughness_to_variance(ay * 0.5 * abs(1.0 - n)))):
            out[e] = interface_covariance(sx, sy, c, s)
    return PackedAniso(base, alpha_x, alpha_y, rot, iso, cov_r, cov_td, cov_tu, bool(np.all(iso)))


# --------------------------------------------------------------------------- adding-doubling kernel

@numba.njit(cache=True)
def adding_doubling_aniso(c_in, dx, dy, kind, alpha_x, alpha_y, rot, iso, cov_r, cov_td, cov_tu, n_mean, tau,
                          eta_up, achromatic, fgd_split, fgd_lower, fgd_upper, tir_split, tir_lower, tir_upper,
                          per_channel, use_tir, angular_s, E, C, st, cs, wk, wc, ent):
    """§6 with covariances, for incidence cosine ``c_in`` and unit incidence azimuth ``(dx, dy)``.

    Mirrors :func:`models.belcour.adding_doubling` (same energies, same order of floating-point
    operations on every covariance entry). Writes lobe energies ``E[k, ch]`` and covariances
    ``C[k, ch, (xx, xy, yy)]``, the energy state ``st`` (9, 3) (rows R0N, T0N, RN0, TN0 and
    ``st[8] = (J0N, JN0, c_N)``; the scalar variance rows are unused) and the covariance state
    ``cs[(R0, T0, Ri, Ti), ch, 3]``. ``wk`` (9, 3), ``wc`` (3, 3) and ``ent`` (3, 3) are scratch.
    """
    n_e = kind.shape[0]
    for k in range(E.shape[0]):
        for ch in range(3):
            E[k, ch] = 0.0
            for q in range(3):
                C[k, ch, q] = 0.0
    for ch in range(3):
        st[_S_R0, ch] = 0.0
        st[_S_RI, ch] = 0.0
        st[_S_T0, ch] = 1.0
        st[_S_TI, ch] = 1.0
        for r in range(4):
            for q in range(3):
                cs[r, ch, q] = 0.0
    J0 = 1.0
    Ji = 1.0
    c = min(max(c_in, COS_MIN), 1.0)
    lobe = 0
    for e in range(n_e):
        for r in range(3):
            for q in range(3):
                ent[r, q] = 0.0
        jd = 1.0
        ju = 1.0
        is_cond = kind[e] == KIND_CONDUCTOR
        if kind[e] == KIND_MEDIUM:
            c2 = c
            for ch in range(3):
                t = math.exp(-tau[e, ch] / c)
                wk[_W_RDN, ch] = 0.0
                wk[_W_RUP, ch] = 0.0
                wk[_W_TDN, ch] = t
                wk[_W_TUP, ch] = t
        else:
            n = n_mean[e]
            s2 = (1.0 - c * c) / (n * n)
            c2 = math.sqrt(1.0 - s2) if s2 <= 1.0 else -1.0
            passes = c2 > 0.0 and not is_cond
            a = alpha_x[e]
            for q in range(3):
                ent[_E_R, q] = cov_r[e, q]
            if passes:
                c2 = max(c2, COS_MIN)
                if angular_s:
                    _set_interface_cov(ent, _E_TD, a * 0.5 * abs(1.0 - c / (n * c2)),
                                       alpha_y[e] * 0.5 * abs(1.0 - c / (n * c2)), rot[e, 0], rot[e, 1], iso[e])
                    _set_interface_cov(ent, _E_TU, a * 0.5 * abs(1.0 - n * c2 / c),
                                       alpha_y[e] * 0.5 * abs(1.0 - n * c2 / c), rot[e, 0], rot[e, 1], iso[e])
                else:
                    for q in range(3):
                        ent[_E_TD, q] = cov_td[e, q]
                        ent[_E_TU, q] = cov_tu[e, q]
                jd = (c2 / c) * n
                ju = 1.0 / jd
            do_tir = use_tir and e > 0 and eta_up[e] < 1.0
            at = a
            for ch in range(3):
                same = (ch > 0 and cs[_C_T0, ch, 0] == cs[_C_T0, ch - 1, 0]
                        and cs[_C_T0, ch, 1] == cs[_C_T0, ch - 1, 1] and cs[_C_T0, ch, 2] == cs[_C_T0, ch - 1, 2])
                if not same:
                    if cs[_C_T0, ch, 0] > 0.0 or cs[_C_T0, ch, 2] > 0.0:
                        at = lookup_alpha(cs[_C_T0, ch, 0] + ent[_E_R, 0], cs[_C_T0, ch, 1] + ent[_E_R, 1],
                                          cs[_C_T0, ch, 2] + ent[_E_R, 2], c, dx, dy)
                    elif iso[e]:
                        at = a
                    else:
                        at = blended_alpha(a, alpha_y[e], rot[e, 0], rot[e, 1], c, dx, dy)
                if same and achromatic[e]:
                    r = wk[_W_RDN, ch - 1]
                else:
                    r = tables.stacked_slice_lookup(fgd_split, fgd_lower, fgd_upper, e, ch, c, at)
                wk[_W_RDN, ch] = r
                if passes:
                    wk[_W_TDN, ch] = 1.0 - r
                    wk[_W_RUP, ch] = r
                    wk[_W_TUP, ch] = 1.0 - r
                else:
                    wk[_W_TDN, ch] = 0.0
                    wk[_W_RUP, ch] = 0.0
                    wk[_W_TUP, ch] = 0.0
                if do_tir:
                    esc = tables.stacked_slice_lookup(tir_split, tir_lower, tir_upper, e, 0, c, at)
                    st[_S_RI, ch] = min(max(st[_S_RI, ch] + (1.0 - esc) * st[_S_TI, ch], 0.0), 1.0)
                    st[_S_TI, ch] = esc * st[_S_TI, ch]
        # adding step (per channel), every right-hand side from the old state
        for ch in range(3):
            d = 1.0 - st[_S_RI, ch] * wk[_W_RDN, ch]
            if d > 0.0:
                inv = 1.0 / d
                wk[_W_DINV, ch] = inv
                wk[_W_E, ch] = st[_S_T0, ch] * wk[_W_RDN, ch] * st[_S_TI, ch] * inv
                wk[_W_RUP2, ch] = wk[_W_TUP, ch] * st[_S_RI, ch] * wk[_W_TDN, ch] * inv
                wk[_W_M, ch] = st[_S_RI, ch] * wk[_W_RDN, ch] * inv
            else:
                wk[_W_DINV, ch] = 0.0
                wk[_W_E, ch] = 0.0
                wk[_W_RUP2, ch] = 0.0
                wk[_W_M, ch] = 0.0
        m_avg = _mean_row(wk, _W_M)
        for ch in range(3):
            m = wk[_W_M, ch] if per_channel else m_avg
            for q in range(3):
                wc[ch, q] = cs[_C_TI, ch, q] + J0 * (cs[_C_T0, ch, q] + ent[_E_R, q]
                                                     + m * (ent[_E_R, q] + cs[_C_RI, ch, q]))
        if kind[e] != KIND_MEDIUM:
            for ch in range(3):
                E[lobe, ch] = wk[_W_E, ch]
                for q in range(3):
                    C[lobe, ch, q] = wc[ch, q]
            lobe += 1
        wR0_avg = _mean_row(st, _S_R0)
        wE_avg = _mean_row(wk, _W_E)
        wRup_avg = _mean_row(wk, _W_RUP)
        wRup2_avg = _mean_row(wk, _W_RUP2)
        for ch in range(3):
            if per_channel:
                m = wk[_W_M, ch]
                wR0 = st[_S_R0, ch]
                wE = wk[_W_E, ch]
                wRup = wk[_W_RUP, ch]
                wRup2 = wk[_W_RUP2, ch]
            else:
                m = m_avg
                wR0 = wR0_avg
                wE = wE_avg
                wRup = wRup_avg
                wRup2 = wRup2_avg
            wsum_r = wR0 + wE
            wsum_u = wRup + wRup2
            for q in range(3):
                vr = ent[_E_R, q]
                vtd = ent[_E_TD, q]
                vtu = ent[_E_TU, q]
                vri = cs[_C_RI, ch, q]
                new_vR0 = (wR0 * cs[_C_R0, ch, q] + wE * wc[ch, q]) / wsum_r if wsum_r > 0.0 else 0.0
                new_vT0 = jd * cs[_C_T0, ch, q] + vtd + jd * (vr + vri) * m
                new_vRi = ((wRup * vr + wRup2 * (vtd + jd * (vtu + vri + m * (vr + vri)))) / wsum_u
                           if wsum_u > 0.0 else 0.0)
                new_vTi = Ji * vtu + cs[_C_TI, ch, q] + Ji * (vr + vri) * m
                cs[_C_R0, ch, q] = new_vR0
                cs[_C_T0, ch, q] = new_vT0
                cs[_C_RI, ch, q] = new_vRi
                cs[_C_TI, ch, q] = new_vTi
            st[_S_R0, ch] = st[_S_R0, ch] + wk[_W_E, ch]
            st[_S_T0, ch] = st[_S_T0, ch] * wk[_W_TDN, ch] * wk[_W_DINV, ch]
            st[_S_RI, ch] = wk[_W_RUP, ch] + wk[_W_RUP2, ch]
            st[_S_TI, ch] = wk[_W_TUP, ch] * st[_S_TI, ch] * wk[_W_DINV, ch]
        J0 *= jd
        Ji *= ju
        if is_cond:
            break
        c = c2
        if c <= 0.0:
            for ch in range(3):
                st[_S_T0, ch] = 0.0
                st[_S_TI, ch] = 0.0
            break
    st[_S_MISC, 0] = J0
    st[_S_MISC, 1] = Ji
    st[_S_MISC, 2] = c


# --------------------------------------------------------------------------- lobes

@numba.njit(cache=True)
def _lobe_params(E, C, P) -> None:
    """Evaluation GGX of every lobe with energy: ``P[k, ch] = (a1, a2, ex, ey, .)`` from the
    eigen-decomposition of ``C[k, ch]``, ``a_i = max(h^-1(eigenvalue), ALPHA_EVAL_MIN)``."""
    for k in range(E.shape[0]):
        if E[k, 0] == 0.0 and E[k, 1] == 0.0 and E[k, 2] == 0.0:
            continue
        for ch in range(3):
            if ch > 0 and C[k, ch, 0] == C[k, ch - 1, 0] and C[k, ch, 1] == C[k, ch - 1, 1] \
                    and C[k, ch, 2] == C[k, ch - 1, 2]:
                for q in range(4):
                    P[k, ch, q] = P[k, ch - 1, q]
                continue
            xx, xy, yy = C[k, ch, 0], C[k, ch, 1], C[k, ch, 2]
            if xy == 0.0 and xx == yy:
                a = max(variance_to_roughness(xx), ALPHA_EVAL_MIN)
                P[k, ch, _P_A1] = a
                P[k, ch, _P_A2] = a
                P[k, ch, _P_EX] = 1.0
                P[k, ch, _P_EY] = 0.0
            else:
                l1, l2, ex, ey = principal(xx, xy, yy)
                P[k, ch, _P_A1] = max(variance_to_roughness(l1), ALPHA_EVAL_MIN)
                P[k, ch, _P_A2] = max(variance_to_roughness(l2), ALPHA_EVAL_MIN)
                P[k, ch, _P_EX] = ex
                P[k, ch, _P_EY] = ey


@numba.njit(cache=True, inline="always")
def _lambda_in_frame(wx, wy, wz, a1, a2, ex, ey) -> float:
    """Smith Lambda of ``w`` for the GGX ``(a1 along (ex, ey), a2 across)``."""
    if a1 == a2:
        return optics.ggx_lambda(wx, wy, wz, a1, a2)
    return optics.ggx_lambda(ex * wx + ey * wy, ex * wy - ey * wx, wz, a1, a2)


@numba.njit(cache=True, inline="always")
def _same_params(P, k, ch) -> bool:
    """Lobe ``k`` has the same GGX in channels ``ch`` and ``ch - 1``."""
    return (P[k, ch, _P_A1] == P[k, ch - 1, _P_A1] and P[k, ch, _P_A2] == P[k, ch - 1, _P_A2]
            and P[k, ch, _P_EX] == P[k, ch - 1, _P_EX] and P[k, ch, _P_EY] == P[k, ch - 1, _P_EY])


@numba.njit(cache=True)
def _set_lambda_l(E, P, lx, ly, lz) -> None:
    """``P[k, ch, _P_LAM] = Lambda(l)`` in each lobe's frame (lobes with energy)."""
    for k in range(E.shape[0]):
        if E[k, 0] == 0.0 and E[k, 1] == 0.0 and E[k, 2] == 0.0:
            continue
        for ch in range(3):
            if ch > 0 and _same_params(P, k, ch):
                P[k, ch, _P_LAM] = P[k, ch - 1, _P_LAM]
            else:
                P[k, ch, _P_LAM] = _lambda_in_frame(lx, ly, lz, P[k, ch, _P_A1], P[k, ch, _P_A2], P[k, ch, _P_EX],
                                                    P[k, ch, _P_EY])


@numba.njit(cache=True, inline="always")
def _lobe_aniso(lz, vx, vy, vz, hx, hy, hz, a1, a2, ex, ey, lam_l, height_correlated) -> float:
    """Anisotropic GGX lobe without Fresnel: D(h'; a1, a2) G(l', v') / (4 l_z v_z), primes in the
    lobe's principal frame (no rotation when ``a1 == a2``); ``lam_l`` = Lambda(l') precomputed."""
    if a1 == a2:
        d = optics.ggx_d(hx, hy, hz, a1, a2)
        if d == 0.0:
            return 0.0
        lo = optics.ggx_lambda(vx, vy, vz, a1, a2)
    else:
        d = optics.ggx_d(ex * hx + ey * hy, ex * hy - ey * hx, hz, a1, a2)
        if d == 0.0:
            return 0.0
        lo = optics.ggx_lambda(ex * vx + ey * vy, ex * vy - ey * vx, vz, a1, a2)
    return d * optics.smith_g2(lam_l, lo, False, height_correlated) / (4.0 * lz * vz)


@numba.njit(cache=True)
def _sum_lobes_aniso(lx, ly, lz, vx, vy, vz, E, P, n_lobes, height_correlated, out_top, out_int, n) -> None:
    """Add every lobe at (l, v) into ``out_top[n]`` (lobe 0) and ``out_int[n]`` (the others)."""
    hx = lx + vx
    hy = ly + vy
    hz = lz + vz
    inv = 1.0 / math.sqrt(hx * hx + hy * hy + hz * hz)
    hx *= inv
    hy *= inv
    hz *= inv
    for ch in range(3):
        out_top[n, ch] = 0.0
        out_int[n, ch] = 0.0
    for k in range(n_lobes):
        if E[k, 0] == 0.0 and E[k, 1] == 0.0 and E[k, 2] == 0.0:
            continue
        r = 0.0
        for ch in range(3):
            if ch == 0 or not _same_params(P, k, ch):
                r = _lobe_aniso(lz, vx, vy, vz, hx, hy, hz, P[k, ch, _P_A1], P[k, ch, _P_A2], P[k, ch, _P_EX],
                                P[k, ch, _P_EY], P[k, ch, _P_LAM], height_correlated)
            if k == 0:
                out_top[n, ch] += E[k, ch] * r
            else:
                out_int[n, ch] += E[k, ch] * r


@numba.njit(parallel=True, cache=True)
def _eval_fixed_aniso(l, v, E, P, height_correlated, out_top, out_int):
    """Lobes fixed for all directions (``incident="light"``)."""
    lx, ly, lz = l[0], l[1], l[2]
    n_dir = v.shape[0]
    nc = _chunks(n_dir)
    for chunk in numba.prange(nc):
        for n in range(chunk * n_dir // nc, (chunk + 1) * n_dir // nc):
            vx, vy, vz = v[n, 0], v[n, 1], v[n, 2]
            if vz <= 0.0 or lz <= 0.0:
                for ch in range(3):
                    out_top[n, ch] = 0.0
                    out_int[n, ch] = 0.0
                continue
            _sum_lobes_aniso(lx, ly, lz, vx, vy, vz, E, P, E.shape[0], height_correlated, out_top, out_int, n)


@numba.njit(cache=True, inline="always")
def _azimuth(x: float, y: float) -> tuple:
    """Unit azimuth of (x, y); ``(1, 0)`` at the pole."""
    r = math.sqrt(x * x + y * y)
    if r > 0.0:
        return x / r, y / r
    return 1.0, 0.0


@numba.njit(parallel=True, cache=True)
def _eval_dynamic_aniso(l, v, n_lobes, kind, alpha_x, alpha_y, rot, iso, cov_r, cov_td, cov_tu, n_mean, tau,
                        eta_up, achromatic, fgd_split, fgd_lower, fgd_upper, tir_split, tir_lower, tir_upper,
                        per_channel, use_tir, angular_s, height_correlated, out_top, out_int):
    """Statistics recomputed for every view direction (``incident="view"``, ``direction_grid=0``)."""
    lx, ly, lz = l[0], l[1], l[2]
    n_dir = v.shape[0]
    nc = _chunks(n_dir)
    for chunk in numba.prange(nc):
        E = np.zeros((n_lobes, 3))
        C = np.zeros((n_lobes, 3, 3))
        P = np.zeros((n_lobes, 3, 5))
        st = np.zeros((9, 3))
        cs = np.zeros((4, 3, 3))
        wk = np.zeros((9, 3))
        wc = np.zeros((3, 3))
        ent = np.zeros((3, 3))
        for n in range(chunk * n_dir // nc, (chunk + 1) * n_dir // nc):
            vx, vy, vz = v[n, 0], v[n, 1], v[n, 2]
            if vz <= 0.0 or lz <= 0.0:
                for ch in range(3):
                    out_top[n, ch] = 0.0
                    out_int[n, ch] = 0.0
                continue
            dx, dy = _azimuth(vx, vy)
            adding_doubling_aniso(vz, dx, dy, kind, alpha_x, alpha_y, rot, iso, cov_r, cov_td, cov_tu, n_mean,
                                  tau, eta_up, achromatic, fgd_split, fgd_lower, fgd_upper, tir_split, tir_lower,
                                  tir_upper, per_channel, use_tir, angular_s, E, C, st, cs, wk, wc, ent)
            _lobe_params(E, C, P)
            _set_lambda_l(E, P, lx, ly, lz)
            _sum_lobes_aniso(lx, ly, lz, vx, vy, vz, E, P, n_lobes, height_correlated, out_top, out_int, n)


#: columns of the view table: lobe energy, then the roughness matrix (xx, xy, yy)
_G_E, _G_XX, _G_XY, _G_YY = range(4)


@numba.njit(parallel=True, cache=True)
def _stats_grid_aniso(n_nodes, n_phi, n_lobes, kind, alpha_x, alpha_y, rot, iso, cov_r, cov_td, cov_tu, n_mean,
                      tau, eta_up, achromatic, fgd_split, fgd_lower, fgd_upper, tir_split, tir_lower, tir_upper,
                      per_channel, use_tir, angular_s):
    """View table ``G[i, j, k, ch, :]`` = (lobe energy, clamped roughness matrix ``(xx, xy, yy)``) at the
    azimuths ``phi_i = i pi / n_phi`` and cosines ``c_j = (j / (n_nodes - 1))^2``. Azimuth-major, so
    that the two cosine neighbours of a direction are adjacent in memory."""
    G = np.zeros((n_phi, n_nodes, n_lobes, 3, 4))
    for j in numba.prange(n_nodes):
        E = np.zeros((n_lobes, 3))
        C = np.zeros((n_lobes, 3, 3))
        P = np.zeros((n_lobes, 3, 5))
        st = np.zeros((9, 3))
        cs = np.zeros((4, 3, 3))
        wk = np.zeros((9, 3))
        wc = np.zeros((3, 3))
        ent = np.zeros((3, 3))
        t = j / (n_nodes - 1)
        for i in range(n_phi):
            phi = i * math.pi / n_phi
            adding_doubling_aniso(t * t, math.cos(phi), math.sin(phi), kind, alpha_x, alpha_y, rot, iso, cov_r,
                                  cov_td, cov_tu, n_mean, tau, eta_up, achromatic, fgd_split, fgd_lower, fgd_upper,
                                  tir_split, tir_lower, tir_upper, per_channel, use_tir, angular_s, E, C, st,
                                  cs, wk, wc, ent)
            for k in range(n_lobes):
                for ch in range(3):
                    P[k, ch, _P_A1] = ALPHA_EVAL_MIN
                    P[k, ch, _P_A2] = ALPHA_EVAL_MIN
                    P[k, ch, _P_EX] = 1.0
                    P[k, ch, _P_EY] = 0.0
            _lobe_params(E, C, P)
            for k in range(n_lobes):
                for ch in range(3):
                    G[i, j, k, ch, _G_E] = E[k, ch]
                    a1, a2, ex, ey = P[k, ch, _P_A1], P[k, ch, _P_A2], P[k, ch, _P_EX], P[k, ch, _P_EY]
                    if a1 == a2:
                        G[i, j, k, ch, _G_XX] = a1
                        G[i, j, k, ch, _G_XY] = 0.0
                        G[i, j, k, ch, _G_YY] = a1
                    else:
                        xx, xy, yy = interface_covariance(a1, a2, ex, ey)
                        G[i, j, k, ch, _G_XX] = xx
                        G[i, j, k, ch, _G_XY] = xy
                        G[i, j, k, ch, _G_YY] = yy
    return G


@numba.njit(parallel=True, cache=True)
def _eval_grid_aniso(l, v, G, height_correlated, out_top, out_int):
    """View-dependent statistics interpolated from :func:`_stats_grid_aniso`: linearly in
    ``sqrt(v_z)`` (exactly as :func:`models.belcour._eval_grid`) and, with more than one azimuth
    node, periodically in the azimuth of ``v`` modulo pi; the interpolated roughness matrix is
    eigen-decomposed into the lobe's GGX."""
    lx, ly, lz = l[0], l[1], l[2]
    n_dir = v.shape[0]
    n_phi = G.shape[0]
    n_nodes = G.shape[1]
    n_lobes = G.shape[2]
    nc = _chunks(n_dir)
    for chunk in numba.prange(nc):
        E = np.zeros((n_lobes, 3))
        P = np.zeros((n_lobes, 3, 5))
        A = np.zeros(4)
        Ap = np.zeros(4)
        for n in range(chunk * n_dir // nc, (chunk + 1) * n_dir // nc):
            vx, vy, vz = v[n, 0], v[n, 1], v[n, 2]
            if vz <= 0.0 or lz <= 0.0:
                for ch in range(3):
                    out_top[n, ch] = 0.0
                    out_int[n, ch] = 0.0
                continue
            s = math.sqrt(min(max(vz, 0.0), 1.0)) * (n_nodes - 1)
            j = min(int(s), n_nodes - 2)
            f = s - j
            i0 = 0
            i1 = 0
            g = 0.0
            if n_phi > 1:
                phi = math.atan2(vy, vx)
                u = (phi - math.pi * math.floor(phi / math.pi)) / math.pi * n_phi
                i0 = min(int(u), n_phi - 1)
                g = u - i0
                i1 = (i0 + 1) % n_phi
            for k in range(n_lobes):
                for ch in range(3):
                    for q in range(4):
                        A[q] = G[i0, j, k, ch, q] * (1.0 - f) + G[i0, j + 1, k, ch, q] * f
                    if n_phi > 1:
                        for q in range(4):
                            a1 = G[i1, j, k, ch, q] * (1.0 - f) + G[i1, j + 1, k, ch, q] * f
                            A[q] = A[q] * (1.0 - g) + a1 * g
                    E[k, ch] = A[_G_E]
                    xx, xy, yy = A[_G_XX], A[_G_XY], A[_G_YY]
                    if ch > 0 and xx == Ap[_G_XX] and xy == Ap[_G_XY] and yy == Ap[_G_YY]:
                        for q in range(4):
                            P[k, ch, q] = P[k, ch - 1, q]
                    elif xy == 0.0 and xx == yy:
                        P[k, ch, _P_A1] = xx
                        P[k, ch, _P_A2] = xx
                        P[k, ch, _P_EX] = 1.0
                        P[k, ch, _P_EY] = 0.0
                    else:
                        a_1, a_2, ex, ey = principal(xx, xy, yy)
                        P[k, ch, _P_A1] = max(a_1, ALPHA_EVAL_MIN)
                        P[k, ch, _P_A2] = max(a_2, ALPHA_EVAL_MIN)
                        P[k, ch, _P_EX] = ex
                        P[k, ch, _P_EY] = ey
                    for q in range(4):
                        Ap[q] = A[q]
            _set_lambda_l(E, P, lx, ly, lz)
            _sum_lobes_aniso(lx, ly, lz, vx, vy, vz, E, P, n_lobes, height_correlated, out_top, out_int, n)


# --------------------------------------------------------------------------- public statistics

@dataclass(frozen=True)
class AnisoOptions(BelcourOptions):
    """:class:`models.belcour.BelcourOptions` plus the azimuth nodes of the ``incident="view"`` table."""

    azimuth_grid: int = AZIMUTH_GRID

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.azimuth_grid < 1:
            raise ValueError(f"azimuth_grid must be >= 1, got {self.azimuth_grid!r}")


@dataclass(frozen=True)
class AnisoLobe:
    """One anisotropic GGX lobe (per RGB channel): ``energy`` (3,), ``covariance`` (3, 2, 2) in the
    macro tangent plane, principal roughnesses ``alpha`` (3, 2) = ``h^-1`` of the eigenvalues (larger
    first, not clamped) and ``axis`` (3, 2) the unit principal direction of ``alpha[:, 0]``."""

    energy: np.ndarray
    covariance: np.ndarray
    alpha: np.ndarray
    axis: np.ndarray


@dataclass(frozen=True)
class AnisoStatistics:
    """Result of the adding-doubling for one incident direction: lobes (one per interface, top
    first), the stack's energies ``R0N``, ``T0N``, ``RN0``, ``TN0`` (RGB) and covariances ``SR0N``,
    ``ST0N``, ``SRN0``, ``STN0`` (3, 2, 2) (Bati 2021 notation), the Jacobian products and the mean
    cosine in the last medium reached (as :class:`models.belcour.StackStatistics`)."""

    lobes: list[AnisoLobe]
    R0N: np.ndarray
    T0N: np.ndarray
    RN0: np.ndarray
    TN0: np.ndarray
    SR0N: np.ndarray
    ST0N: np.ndarray
    SRN0: np.ndarray
    STN0: np.ndarray
    J0N: float
    JN0: float
    cos_bottom: float


def _matrices(c3: np.ndarray) -> np.ndarray:
    """(..., 3) entries (xx, xy, yy) -> (..., 2, 2) symmetric matrices."""
    out = np.empty(c3.shape[:-1] + (2, 2))
    out[..., 0, 0] = c3[..., 0]
    out[..., 0, 1] = c3[..., 1]
    out[..., 1, 0] = c3[..., 1]
    out[..., 1, 1] = c3[..., 2]
    return out


def _run_aniso(packed: PackedAniso, omega_i: np.ndarray, options: BelcourOptions):
    n = packed.n_lobes
    E = np.zeros((n, 3))
    C = np.zeros((n, 3, 3))
    st = np.zeros((9, 3))
    cs = np.zeros((4, 3, 3))
    dx, dy = _azimuth(float(omega_i[0]), float(omega_i[1]))
    adding_doubling_aniso(float(omega_i[2]), dx, dy, *packed.kernel_args(), options.per_channel, options.use_tir,
                          options.transmission_scale == "angular", E, C, st, cs, np.zeros((9, 3)), np.zeros((3, 3)),
                          np.zeros((3, 3)))
    return E, C, st, cs


def _principal_rgb(c3: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    alpha = np.zeros((3, 2))
    axis = np.zeros((3, 2))
    for ch in range(3):
        xx, xy, yy = (float(x) for x in c3[ch])
        l1, l2, ex, ey = principal(xx, xy, yy)
        alpha[ch] = (variance_to_roughness(l1), variance_to_roughness(l2))
        axis[ch] = (ex, ey)
    return alpha, axis


def aniso_statistics(stack: Stack, omega_i, options: BelcourOptions | None = None, **kwargs) -> AnisoStatistics:
    """Lobe energies and covariances for the incident direction ``omega_i`` (unit, upper hemisphere;
    its azimuth matters for anisotropic stacks). Options as :class:`AnisoOptions` or keywords."""
    if options is not None and kwargs:
        raise TypeError("give either an options object or keyword options, not both")
    opts = options if options is not None else AnisoOptions(**kwargs)
    packed = pack_aniso(stack, opts)
    w = np.asarray(omega_i, dtype=float).reshape(3)
    E, C, st, cs = _run_aniso(packed, w, opts)
    lobes = []
    for k in range(packed.n_lobes):
        alpha, axis = _principal_rgb(C[k])
        lobes.append(AnisoLobe(E[k].copy(), _matrices(C[k]), alpha, axis))
    return AnisoStatistics(lobes, st[_S_R0].copy(), st[_S_T0].copy(), st[_S_RI].copy(), st[_S_TI].copy(),
                           _matrices(cs[_C_R0]), _matrices(cs[_C_T0]), _matrices(cs[_C_RI]), _matrices(cs[_C_TI]),
                           float(st[_S_MISC, 0]), float(st[_S_MISC, 1]), float(st[_S_MISC, 2]))


# --------------------------------------------------------------------------- model

class BelcourAniso(Model):
    """Belcour 2018 forward model with 2 x 2 covariances and anisotropic GGX lobes (Yamaguchi et al.
    2019). Options as :class:`models.belcour.BelcourForward` plus ``azimuth_grid``."""

    name = "belcour-aniso"
    description = ("Anisotropic Belcour (Yamaguchi 2019): forward adding-doubling of 2x2 lobe covariances, "
                   "anisotropic GGX lobes")
    sides = ("brdf",)
    anisotropic = True

    def __init__(self, incident: str = "light", use_tir: bool = False, transmission_scale: str = "normal",
                 per_channel: bool = True, height_correlated: bool = False, fgd_source: str = "material",
                 cache_dir: str | os.PathLike | None = None, direction_grid: int = DIRECTION_GRID,
                 azimuth_grid: int = AZIMUTH_GRID) -> None:
        self.options = AnisoOptions(incident=incident, use_tir=use_tir, transmission_scale=transmission_scale,
                                    per_channel=per_channel, height_correlated=height_correlated,
                                    fgd_source=fgd_source,
                                    cache_dir=None if cache_dir is None else os.fspath(cache_dir),
                                    direction_grid=direction_grid, azimuth_grid=azimuth_grid)
        self._packed: dict[Stack, PackedAniso] = {}
        self._grids: dict[Stack, np.ndarray] = {}

    def support_reason(self, stack: Stack) -> str | None:
        return unsupported_reason(isotropic_proxy(stack))

    def packed(self, stack: Stack) -> PackedAniso:
        """The packed form of ``stack`` (memoised per model instance)."""
        p = self._packed.get(stack)
        if p is None:
            p = pack_aniso(stack, self.options)
            self._packed[stack] = p
        return p

    def statistics(self, stack: Stack, omega_i) -> AnisoStatistics:
        """:func:`aniso_statistics` with this model's options."""
        return aniso_statistics(stack, omega_i, self.options)

    def _grid(self, stack: Stack) -> np.ndarray:
        """The ``incident="view"`` table of :func:`_stats_grid_aniso` (memoised per stack)."""
        g = self._grids.get(stack)
        if g is None:
            p = self.packed(stack)
            o = self.options
            n_phi = 1 if p.isotropic else o.azimuth_grid
            g = _stats_grid_aniso(o.direction_grid, n_phi, p.n_lobes, *p.kernel_args(), o.per_channel, o.use_tir,
                                  o.transmission_scale == "angular")
            self._grids[stack] = g
        return g

    def _evaluate(self, stack: Stack, l: np.ndarray, v: np.ndarray, side: str) -> ModelValue:
        p = self.packed(stack)
        o = self.options
        l = np.ascontiguousarray(l, dtype=np.float64)
        shape = v.shape[:-1]
        vv = np.ascontiguousarray(v.reshape(-1, 3), dtype=np.float64)
        top = np.empty((vv.shape[0], 3))
        internal = np.empty((vv.shape[0], 3))
        hc = o.height_correlated
        if l[2] <= 0.0:
            top[:] = 0.0
            internal[:] = 0.0
        elif o.incident == "light":
            E, C, _, _ = _run_aniso(p, l, o)
            P = np.zeros((p.n_lobes, 3, 5))
            _lobe_params(E, C, P)
            _set_lambda_l(E, P, float(l[0]), float(l[1]), float(l[2]))
            _eval_fixed_aniso(l, vv, E, P, hc, top, internal)
        elif o.direction_grid > 0:
            _eval_grid_aniso(l, vv, self._grid(stack), hc, top, internal)
        else:
            _eval_dynamic_aniso(l, vv, p.n_lobes, *p.kernel_args(), o.per_channel, o.use_tir,
                                o.transmission_scale == "angular", hc, top, internal)
        return ModelValue(top.reshape(shape + (3,)), internal.reshape(shape + (3,)))


__all__ = ["AZIMUTH_GRID", "AnisoLobe", "AnisoOptions", "AnisoStatistics", "BelcourAniso", "PackedAniso",
           "adding_doubling_aniso", "aniso_statistics", "blended_alpha", "interface_covariance", "isotropic_proxy",
           "lookup_alpha", "pack_aniso", "principal"]
