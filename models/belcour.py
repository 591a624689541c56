"""Belcour 2018's layered BSDF: a sum of GGX lobes whose energies and roughnesses come from an
adding-doubling of per-lobe statistics (energy, variance) through the stack.

Spec: ``shared/spec/belcour2018.md`` (sections referenced as §n). Four models:

* ``belcour-fwd`` (:class:`BelcourForward`) -- the forward model: statistics computed once for
  the incident direction ``omega_i`` (default: the light ``l``, as in Bati 2021; ``incident="view"``
  uses ``v`` like every code port). Not reciprocal.
* ``belcour-sym`` (:class:`BelcourSymmetric`) -- the symmetric model: statistics computed for
  ``c = |l.h|`` with ``h = normalize(l + v)``, per direction; reciprocal.
* ``belcour-bati19`` (:class:`BelcourBati19`) -- Bati 2019 eq. 6: lobe 0 replaced by the exact
  microfacet BRDF of the top interface (``optics.microfacet_reflection``), lobes k >= 1 forward.
* ``belcour-btdf`` (:class:`BelcourBTDF`) -- the forward BTDF of slabs (Belcour's
  ``layered_dielectric``, §8): one transmission lobe of energy ``T0N`` and roughness
  ``f^-1(vT0N)`` about the Snell direction.

Conventions (as :mod:`models.base`): ``l`` towards the light (``l_z > 0``); ``v`` towards the
viewer; values without cosine, in 1/sr, RGB last; ``top`` = lobe 0, ``internal`` = the others;
BTDF values are flux based (fraction of incident power per unit projected solid angle), so no
``(eta_0/eta_N)^2`` factor is applied (it is 1 for slabs in air anyway; §8 UNCERTAIN).

Lobes (§7): ``f = sum_k E_k D(h; a_k) G(l, v; a_k) / (4 l_z v_z)``, ``h = normalize(l + v)``, D and
G about the macro normal (every lobe points at the mirror direction of the original direction),
no Fresnel factor (it is in ``E_k``). G is separable Smith ``G1(l) G1(v)`` by default
(``height_correlated=True`` switches G *and* the FGD/TIR tables to the height-correlated form).
Lobe ``k`` belongs to interface ``k`` (top = 0); media create no lobe. Roughness <-> variance:
``f(a) = a^1.1 / (1 - a^1.1)`` (a clamped to [0, 0.9999]), ``f^-1(s) = (s / (1 + s))^(1/1.1)`` (§2).
Lobe roughness is clamped to >= ``ALPHA_EVAL_MIN = 1e-4`` for evaluation only (so a perfectly
smooth stack, alpha = 0, evaluates as alpha = 1e-4 lobes); mean cosines are clamped to
``>= COS_MIN = 1e-4`` (§9 guard: ``j = c2 / c`` blows up at grazing angles).

Adding-doubling (§6 pseudo-code, implemented as written, every update from the old state):
per interface ``R = FGD(c, a~, eta, kappa)`` with ``a~ = f^-1(vT0i + f(alpha_i))``, ``T = 1 - R`` for a
dielectric the mean direction passes (``T = 0`` for a conductor or total internal reflection at
the mean, after which the loop stops); per medium ``T = exp(-tau / c)``, ``R = 0``. Lobe energy
``E_k = T0i R Ti0 / (1 - Ri0 R)``, lobe variance
``v_k = vTi0 + J0i (vT0i + vr + m (vr + vRi0))``, ``m = Ri0 R / (1 - Ri0 R)`` -- Bati 2021 eqs. 2, 4, 5.

Choices where the spec is UNCERTAIN or offers a switch (constructor parameters):

* ``per_channel=True`` (default): every statistic is kept per RGB channel -- energies *and*
  variances, hence one roughness per channel and lobe -- as Bati 2021 does (its footnote 1) and
  MODELS.md asks. ``per_channel=False`` reproduces Belcour's optimised code: the inter-reflection
  factor m and the energy weights of the averaged variances are channel means, so every lobe
  has one roughness (§9).
* ``incident="light"`` (default) or ``"view"``: which direction is ``omega_i`` of the forward
  model (§7).
* ``use_tir=False`` (default, as Bati 2019/2021): the optional TIR step of §5. When on,
  ``eta_up`` is the index ratio across the nearest *interface* above the current medium (media in
  between are skipped, avoiding the §5 pitfall that silently disables it).
* ``transmission_scale="normal"`` (default, the reference code and Bati 2021 eq. 6):
  ``s_down = |1 - 1/n| / 2``, ``s_up = |1 - n| / 2``; ``"angular"``: ``s = |1 - eta_1 cos_i /
  (eta_2 cos_t)| / 2`` (§3).
* Variance bookkeeping for >= 3 interfaces follows §6 literally (vT0i scaled by j_down, the new
  vt_up by Ji0) although it is not obviously consistent (§6 UNCERTAIN).
* ``fgd_source="material"`` (default): FGD/TIR from material slices exact in (eta, kappa) (as
  Bati 2019 precomputed per material, :func:`models.tables.fgd_slice`); ``"table"`` interpolates
  the 4D FGD / 3D TIR tables (Belcour's approach). FGD is single scattering (the FGD-infinity
  multiple-scattering table is not implemented; Bati 2019 disabled it too).
* Stacks ending in a dielectric (slabs) are accepted by the BRDF models: their lobes are the
  per-interface reflection lobes of §6 (as C6), not the single aggregated reflection lobe of
  Belcour's ``layered_dielectric`` (§8 UNCERTAIN). Lambertian bases are refused.
* BTDF: light from above only; ``T0N`` and ``vT0N`` from §6 over the whole stack; the lobe is a
  GGX lobe of roughness ``f^-1(vT0N)`` (per channel) about ``omega_t`` with
  ``sin theta_N = sin theta_0 / eta_N`` (mean index), evaluated by the mirror trick of §8.

Speed: the symmetric model (and the forward model with ``incident="view"``) needs statistics
for a different cosine in every direction. They depend on that cosine only, so by default they
are tabulated per stack at ``direction_grid = 2048`` cosines ``c_j = (j / 2047)^2`` (one
adding-doubling each, memoised per model instance) and interpolated linearly in ``sqrt(c)``
(relative difference to per-direction adding-doubling below 1e-4, tested; reciprocity is kept
exactly since the interpolation sees the same cosine). ``direction_grid=0`` runs
:func:`adding_doubling` for every direction instead (about 5x slower). The forward model with
``incident="light"`` runs it once per call.

The statistics themselves are exposed for the inverse method: :func:`lobe_statistics` (energy
and roughness per lobe, RGB) and :func:`stack_statistics` (also the variances and the
accumulated R0N, T0N, RN0, TN0 statistics of the stack, Bati 2021 notation).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numba
import numpy as np

from goniometer import optics
from goniometer.stack import Interface, Lambertian, Medium, Stack
from models import tables
from models.base import Model, ModelValue

ALPHA_EVAL_MIN = 1e-4
COS_MIN = 1e-4
ALPHA_MAX = 0.9999

KIND_DIELECTRIC = 0
KIND_CONDUCTOR = 1
KIND_MEDIUM = 2

#: cosine nodes at which direction-dependent statistics are tabulated (see the module docstring)
DIRECTION_GRID = 2048

MODE_LIGHT = 0
MODE_VIEW = 1
MODE_HALF = 2

#: rows of the final-state array of the adding-doubling kernel
_S_R0, _S_T0, _S_RI, _S_TI, _S_VR0, _S_VT0, _S_VRI, _S_VTI, _S_MISC = range(9)
#: rows of the per-entry scratch array: R and T of the entry down and up, inter-reflection factor
#: m, lobe energy and variance, second upward reflection term, 1 / (1 - Ri0 R)
_W_RDN, _W_TDN, _W_RUP, _W_TUP, _W_M, _W_E, _W_V, _W_RUP2, _W_DINV = range(9)


# --------------------------------------------------------------------------- variance mapping

@numba.njit(cache=True)
def roughness_to_variance(alpha: float) -> float:
    """``f(a) = a^1.1 / (1 - a^1.1)`` with ``a`` clamped to [0, 0.9999] (§2)."""
    a = min(max(alpha, 0.0), ALPHA_MAX)
    p = a ** 1.1
    return p / (1.0 - p)


@numba.njit(cache=True)
def variance_to_roughness(var: float) -> float:
    """``f^-1(s) = (s / (1 + s))^(1/1.1)``; ``s <= 0`` (or NaN) gives 0, ``s = inf`` gives 1."""
    if not var > 0.0:
        return 0.0
    if math.isinf(var):
        return 1.0
    return (1.0 / (1.0 + 1.0 / var)) ** (1.0 / 1.1)


# --------------------------------------------------------------------------- options and packing

@dataclass(frozen=True)
class BelcourOptions:
    """The switches of the model (see the module docstring for their meaning and defaults)."""

    incident: str = "light"
    use_tir: bool = False
    transmission_scale: str = "normal"
    per_channel: bool = True
    height_correlated: bool = False
    fgd_source: str = "material"
    cache_dir: str | None = None
    direction_grid: int = DIRECTION_GRID

    def __post_init__(self) -> None:
        if self.incident not in ("light", "view"):
            raise ValueError(f"incident must be 'light' or 'view', got {self.incident!r}")
        if self.transmission_scale not in ("normal", "angular"):
            raise ValueError(f"transmission_scale must be 'normal' or 'angular', got {self.transmission_scale!r}")
        if self.direction_grid != 0 and self.direction_grid < 2:
            raise ValueError(f"direction_grid must be 0 or >= 2, got {self.direction_grid!r}")
        if self.fgd_source not in ("material", "table"):
            raise ValueError(f"fgd_source must be 'material' or 'table', got {self.fgd_source!r}")


@dataclass(frozen=True)
class PackedStack:
    """Flat arrays the kernels read; one entry per interface or medium, top first.

    * ``kind`` (KIND_*), ``alpha`` (interface roughness);
    * ``var_r``, ``var_t_down``, ``var_t_up``: ``f(alpha)``, ``f(s_down alpha)``, ``f(s_up alpha)``
      with the normal-incidence transmission scales s;
    * ``n_mean``: mean relative index (Snell, s and J; 1 for conductors and media);
    * ``tau``: RGB optical depth of media; ``eta_up``: TIR index ratio across the interface above
      the entry's upper medium (1 = none);
    * ``achromatic``: the three channels share one FGD slice;
    * FGD slices per entry and channel (``fgd_split``, ``fgd_lower``, ``fgd_upper``: stacked
      :class:`models.tables.TableSlice`), TIR slices per entry (channel axis of length 1);
    * ``n_lobes`` (number of interfaces), ``eta_exit`` (absolute index of the last medium reached:
      below a transmitting stack, above a conductor), ``top_eta``/``top_kappa`` (relative index of
      the top interface, RGB).
    """

    kind: np.ndarray
    alpha: np.ndarray
    var_r: np.ndarray
    var_t_down: np.ndarray
    var_t_up: np.ndarray
    n_mean: np.ndarray
    tau: np.ndarray
    eta_up: np.ndarray
    achromatic: np.ndarray
    fgd_split: np.ndarray
    fgd_lower: np.ndarray
    fgd_upper: np.ndarray
    tir_split: np.ndarray
    tir_lower: np.ndarray
    tir_upper: np.ndarray
    n_lobes: int
    eta_exit: float
    top_eta: np.ndarray = field(default_factory=lambda: np.ones(3))
    top_kappa: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def kernel_args(self) -> tuple:
        """The stack arguments of :func:`adding_doubling`, in order."""
        return (self.kind, self.alpha, self.var_r, self.var_t_down, self.var_t_up, self.n_mean, self.tau,
                self.eta_up, self.achromatic, self.fgd_split, self.fgd_lower, self.fgd_upper, self.tir_split,
                self.tir_lower, self.tir_upper)


def unsupported_reason(stack: Stack) -> str | None:
    """Why Belcour's model cannot represent ``stack`` (None if it can)."""
    if any(isinstance(x, Lambertian) for x in stack.layers):
        return "Belcour's model cannot represent a Lambertian base (it only sums GGX lobes)"
    if not stack.interfaces:
        return "the stack has no interface"
    if any(getattr(x, "is_anisotropic", False) for x in stack.interfaces):
        return "Belcour's model is isotropic: it cannot represent an anisotropic interface"
    return None


def _pad(a: np.ndarray, rows: int) -> np.ndarray:
    out = np.zeros((rows, a.shape[1]))
    out[: a.shape[0]] = a
    return out


def pack_stack(stack: Stack, options: BelcourOptions = BelcourOptions()) -> PackedStack:
    """Flatten a supported stack and gather its FGD (and TIR) slices."""
    reason = unsupported_reason(stack)
    if reason is not None:
        raise ValueError(reason)
    if tables.N_MU_UPPER != tables.N_MU:
        raise AssertionError("material and table slices must share the upper mu node count")
    n_lo = max(tables.N_MU_LOWER, 2)
    n_hi = tables.N_MU
    na = tables.N_ALPHA
    hc = options.height_correlated
    tabs = tables.load_tables(options.cache_dir, hc) if options.fgd_source == "table" else None

    def fgd_sl(eta: float, kappa: float, mu_min: float) -> tables.TableSlice:
        if tabs is not None:
            return tables.fgd_slice_from_table(tabs, eta, kappa)
        return tables.fgd_slice(eta, kappa, hc, options.cache_dir, mu_min)

    def tir_sl(eta_up: float, mu_min: float) -> tables.TableSlice:
        if tabs is not None:
            return tables.tir_slice_from_table(tabs, eta_up)
        return tables.tir_slice(eta_up, hc, options.cache_dir, mu_min)

    layers = stack.layers
    ne = len(layers)
    kind = np.zeros(ne, dtype=np.int64)
    alpha = np.zeros(ne)
    n_mean = np.ones(ne)
    tau = np.zeros((ne, 3))
    eta_up = np.ones(ne)
    achromatic = np.zeros(ne, dtype=np.bool_)
    fgd_split = np.zeros((ne, 3))
    fgd_lower = np.zeros((ne, 3, n_lo, na))
    fgd_upper = np.zeros((ne, 3, n_hi, na))
    tir_split = np.zeros((ne, 1))
    tir_lower = np.zeros((ne, 1, n_lo, na))
    tir_upper = np.ones((ne, 1, n_hi, na))
    n_cur = 1.0          # absolute index of the medium the entry lies in
    n_prev: float | None = None   # absolute index above the last interface
    top_eta = np.ones(3)
    top_kappa = np.zeros(3)
    n_if = 0
    for e, layer in enumerate(layers):
        if isinstance(layer, Medium):
            kind[e] = KIND_MEDIUM
            tau[e] = layer.optical_depth
            continue
        assert isinstance(layer, Interface)
        eta = np.asarray(layer.ior, dtype=float) / n_cur
        kap = np.asarray(layer.extinction, dtype=float) / n_cur
        kind[e] = KIND_CONDUCTOR if layer.is_conductor else KIND_DIELECTRIC
        alpha[e] = layer.roughness
        if not layer.is_conductor:
            n_mean[e] = float(eta[0])
        achromatic[e] = bool(np.all(eta == eta[0]) and np.all(kap == kap[0]))
        if n_if == 0:
            top_eta, top_kappa = eta.copy(), kap.copy()
        # light from air reaches this medium with sin(theta) <= 1 / n_cur
        mu_min = math.sqrt(max(0.0, 1.0 - 1.0 / (n_cur * n_cur)))
        for ch in range(3):
            sl = fgd_sl(float(eta[ch]), float(kap[ch]), mu_min)
            fgd_split[e, ch] = sl.mu_split
            fgd_lower[e, ch] = _pad(sl.lower, n_lo)
            fgd_upper[e, ch] = sl.upper
        if n_prev is not None:
            eta_up[e] = n_prev / n_cur
            if options.use_tir and eta_up[e] < 1.0:
                tl = tir_sl(float(eta_up[e]), mu_min)
                tir_split[e, 0] = tl.mu_split
                tir_lower[e, 0] = _pad(tl.lower, n_lo)
                tir_upper[e, 0] = tl.upper
        n_if += 1
        if not layer.is_conductor:
            n_prev = n_cur
            n_cur = float(layer.ior[0])
    var_r = np.array([roughness_to_variance(a) for a in alpha])
    # normal-incidence transmission scales: s_down = |1 - 1/n| / 2, s_up = |1 - n| / 2 (Bati 2021 eq. 6)
    var_t_down = np.array([roughness_to_variance(a * 0.5 * abs(n - 1.0) / n) for a, n in zip(alpha, n_mean)])
    var_t_up = np.array([roughness_to_variance(a * 0.5 * abs(1.0 - n)) for a, n in zip(alpha, n_mean)])
    return PackedStack(kind, alpha, var_r, var_t_down, var_t_up, n_mean, tau, eta_up, achromatic, fgd_split,
                       fgd_lower, fgd_upper, tir_split, tir_lower, tir_upper, n_if, n_cur, top_eta, top_kappa)


# --------------------------------------------------------------------------- adding-doubling kernel

@numba.njit(cache=True, inline="always")
def _mean_row(a, row) -> float:
    return (a[row, 0] + a[row, 1] + a[row, 2]) / 3.0


@numba.njit(cache=True)
def adding_doubling(c_in, kind, alpha, var_r, var_t_down, var_t_up, n_mean, tau, eta_up, achromatic, fgd_split,
                    fgd_lower, fgd_upper, tir_split, tir_lower, tir_upper, per_channel, use_tir, angular_s, E, V,
                    st, wk):
    """The statistics of §6 for incidence cosine ``c_in`` (in the top medium).

    Writes lobe energies ``E[k, ch]`` and variances ``V[k, ch]`` (k = interface index; zeros for
    interfaces below a conductor or below total internal reflection at the mean) and the final
    state ``st`` (9, 3): rows R0N, T0N, RN0, TN0, vR0N, vT0N, vRN0, vTN0 (per channel), and
    ``st[8] = (J0N, JN0, c_N)`` with ``c_N`` the mean cosine in the last medium reached (below a
    transmitting stack, above a conductor; -1 after total internal reflection at the mean).
    ``wk`` is (9, 3) scratch. No allocation.
    """
    n_e = kind.shape[0]
    for k in range(E.shape[0]):
        for ch in range(3):
            E[k, ch] = 0.0
            V[k, ch] = 0.0
    for ch in range(3):
        st[_S_R0, ch] = 0.0
        st[_S_RI, ch] = 0.0
        st[_S_T0, ch] = 1.0
        st[_S_TI, ch] = 1.0
        st[_S_VR0, ch] = 0.0
        st[_S_VT0, ch] = 0.0
        st[_S_VRI, ch] = 0.0
        st[_S_VTI, ch] = 0.0
    J0 = 1.0
    Ji = 1.0
    c = min(max(c_in, COS_MIN), 1.0)
    lobe = 0
    for e in range(n_e):
        vr = 0.0
        vtd = 0.0
        vtu = 0.0
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
            a = alpha[e]
            vr = var_r[e]
            if passes:
                c2 = max(c2, COS_MIN)
                if angular_s:
                    vtd = roughness_to_variance(a * 0.5 * abs(1.0 - c / (n * c2)))
                    vtu = roughness_to_variance(a * 0.5 * abs(1.0 - n * c2 / c))
                else:
                    vtd = var_t_down[e]
                    vtu = var_t_up[e]
                jd = (c2 / c) * n
                ju = 1.0 / jd
            do_tir = use_tir and e > 0 and eta_up[e] < 1.0
            at = a
            for ch in range(3):
                same = ch > 0 and st[_S_VT0, ch] == st[_S_VT0, ch - 1]
                if not same:
                    # a~ = f^-1(vT0i + f(alpha)); exactly alpha when nothing is accumulated above
                    at = variance_to_roughness(st[_S_VT0, ch] + vr) if st[_S_VT0, ch] > 0.0 else a
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
        if per_channel:
            for ch in range(3):
                m = wk[_W_M, ch]
                wk[_W_V, ch] = st[_S_VTI, ch] + J0 * (st[_S_VT0, ch] + vr + m * (vr + st[_S_VRI, ch]))
        else:
            m_avg = _mean_row(wk, _W_M)
            for ch in range(3):
                wk[_W_V, ch] = st[_S_VTI, ch] + J0 * (st[_S_VT0, ch] + vr + m_avg * (vr + st[_S_VRI, ch]))
        if kind[e] != KIND_MEDIUM:
            for ch in range(3):
                E[lobe, ch] = wk[_W_E, ch]
                V[lobe, ch] = wk[_W_V, ch]
            lobe += 1
        m_avg = _mean_row(wk, _W_M)
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
            wsum = wR0 + wE
            new_vR0 = (wR0 * st[_S_VR0, ch] + wE * wk[_W_V, ch]) / wsum if wsum > 0.0 else 0.0
            new_vT0 = jd * st[_S_VT0, ch] + vtd + jd * (vr + st[_S_VRI, ch]) * m
            wsum = wRup + wRup2
            new_vRi = ((wRup * vr + wRup2 * (vtd + jd * (vtu + st[_S_VRI, ch] + m * (vr + st[_S_VRI, ch])))) / wsum
                       if wsum > 0.0 else 0.0)
            new_vTi = Ji * vtu + st[_S_VTI, ch] + Ji * (vr + st[_S_VRI, ch]) * m
            st[_S_R0, ch] = st[_S_R0, ch] + wk[_W_E, ch]
            st[_S_T0, ch] = st[_S_T0, ch] * wk[_W_TDN, ch] * wk[_W_DINV, ch]
            st[_S_RI, ch] = wk[_W_RUP, ch] + wk[_W_RUP2, ch]
            st[_S_TI, ch] = wk[_W_TUP, ch] * st[_S_TI, ch] * wk[_W_DINV, ch]
            st[_S_VR0, ch] = new_vR0
            st[_S_VT0, ch] = new_vT0
            st[_S_VRI, ch] = new_vRi
            st[_S_VTI, ch] = new_vTi
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


# --------------------------------------------------------------------------- lobe evaluation

@numba.njit(cache=True, inline="always")
def _lobe(lx, ly, lz, vx, vy, vz, hx, hy, hz, a, height_correlated) -> float:
    """GGX lobe without Fresnel: D(h; a) G(l, v; a) / (4 l_z v_z), in 1/sr."""
    d = optics.ggx_d(hx, hy, hz, a, a)
    if d == 0.0:
        return 0.0
    li = optics.ggx_lambda(lx, ly, lz, a, a)
    lo = optics.ggx_lambda(vx, vy, vz, a, a)
    return d * optics.smith_g2(li, lo, False, height_correlated) / (4.0 * lz * vz)


@numba.njit(cache=True)
def _sum_lobes(lx, ly, lz, vx, vy, vz, E, A, n_lobes, height_correlated, top_exact, top_alpha,
               top_eta, top_kappa, out_top, out_int, n) -> None:
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
        if k == 0 and top_exact:
            for ch in range(3):
                if ch > 0 and top_eta[ch] == top_eta[ch - 1] and top_kappa[ch] == top_kappa[ch - 1]:
                    out_top[n, ch] = out_top[n, ch - 1]
                else:
                    out_top[n, ch] = optics.microfacet_reflection(lx, ly, lz, vx, vy, vz, top_alpha, top_alpha,
                                                                  top_eta[ch], top_kappa[ch], height_correlated)
            continue
        r = 0.0
        for ch in range(3):
            if ch == 0 or A[k, ch] != A[k, ch - 1]:
                r = _lobe(lx, ly, lz, vx, vy, vz, hx, hy, hz, A[k, ch], height_correlated)
            if k == 0:
                out_top[n, ch] += E[k, ch] * r
            else:
                out_int[n, ch] += E[k, ch] * r


@numba.njit(cache=True)
def _lobe_alphas(E, V, A) -> None:
    """Evaluation roughness of every lobe with energy (clamped to >= ALPHA_EVAL_MIN)."""
    for k in range(E.shape[0]):
        if E[k, 0] == 0.0 and E[k, 1] == 0.0 and E[k, 2] == 0.0:
            continue
        for ch in range(3):
            if ch > 0 and V[k, ch] == V[k, ch - 1]:
                A[k, ch] = A[k, ch - 1]
            else:
                A[k, ch] = max(variance_to_roughness(V[k, ch]), ALPHA_EVAL_MIN)


@numba.njit(cache=True, inline="always")
def _chunks(n: int) -> int:
    return max(1, min(n // 2048, 512))


@numba.njit(parallel=True, cache=True)
def _eval_fixed(l, v, E, A, height_correlated, top_exact, top_alpha, top_eta, top_kappa, out_top, out_int):
    """Lobes fixed for all directions (forward model with omega_i = l)."""
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
            _sum_lobes(lx, ly, lz, vx, vy, vz, E, A, E.shape[0], height_correlated, top_exact, top_alpha,
                       top_eta, top_kappa, out_top, out_int, n)


@numba.njit(parallel=True, cache=True)
def _eval_dynamic(l, v, mode, n_lobes, kind, alpha, var_r, var_t_down, var_t_up, n_mean, tau, eta_up, achromatic,
                  fgd_split, fgd_lower, fgd_upper, tir_split, tir_lower, tir_upper, per_channel, use_tir, angular_s,
                  height_correlated, top_exact, top_alpha, top_eta, top_kappa, out_top, out_int):
    """Statistics recomputed per direction: ``mode`` MODE_VIEW (c = v_z) or MODE_HALF (c = |l.h|)."""
    lx, ly, lz = l[0], l[1], l[2]
    n_dir = v.shape[0]
    nc = _chunks(n_dir)
    for chunk in numba.prange(nc):
        E = np.zeros((n_lobes, 3))
        V = np.zeros((n_lobes, 3))
        A = np.zeros((n_lobes, 3))
        st = np.zeros((9, 3))
        wk = np.zeros((9, 3))
        for n in range(chunk * n_dir // nc, (chunk + 1) * n_dir // nc):
            vx, vy, vz = v[n, 0], v[n, 1], v[n, 2]
            if vz <= 0.0 or lz <= 0.0:
                for ch in range(3):
                    out_top[n, ch] = 0.0
                    out_int[n, ch] = 0.0
                continue
            if mode == MODE_VIEW:
                c = vz
            else:
                hx = lx + vx
                hy = ly + vy
                hz = lz + vz
                c = abs(lx * hx + ly * hy + lz * hz) / math.sqrt(hx * hx + hy * hy + hz * hz)
            adding_doubling(c, kind, alpha, var_r, var_t_down, var_t_up, n_mean, tau, eta_up, achromatic,
                            fgd_split, fgd_lower, fgd_upper, tir_split, tir_lower, tir_upper, per_channel, use_tir,
                            angular_s, E, V, st, wk)
            _lobe_alphas(E, V, A)
            _sum_lobes(lx, ly, lz, vx, vy, vz, E, A, n_lobes, height_correlated, top_exact, top_alpha,
                       top_eta, top_kappa, out_top, out_int, n)


@numba.njit(parallel=True, cache=True)
def _stats_grid(n_nodes, n_lobes, kind, alpha, var_r, var_t_down, var_t_up, n_mean, tau, eta_up, achromatic,
                fgd_split, fgd_lower, fgd_upper, tir_split, tir_lower, tir_upper, per_channel, use_tir, angular_s):
    """Lobe energies and evaluation roughnesses at the cosines ``c_j = (j / (n_nodes - 1))^2``."""
    Eg = np.zeros((n_nodes, n_lobes, 3))
    Ag = np.full((n_nodes, n_lobes, 3), ALPHA_EVAL_MIN)
    for j in numba.prange(n_nodes):
        V = np.zeros((n_lobes, 3))
        st = np.zeros((9, 3))
        wk = np.zeros((9, 3))
        t = j / (n_nodes - 1)
        adding_doubling(t * t, kind, alpha, var_r, var_t_down, var_t_up, n_mean, tau, eta_up, achromatic,
                        fgd_split, fgd_lower, fgd_upper, tir_split, tir_lower, tir_upper, per_channel, use_tir,
                        angular_s, Eg[j], V, st, wk)
        _lobe_alphas(Eg[j], V, Ag[j])
    return Eg, Ag


@numba.njit(parallel=True, cache=True)
def _eval_grid(l, v, mode, Eg, Ag, height_correlated, top_exact, top_alpha, top_eta, top_kappa, out_top, out_int):
    """Direction-dependent statistics interpolated (linearly in sqrt(c)) from :func:`_stats_grid`."""
    lx, ly, lz = l[0], l[1], l[2]
    n_dir = v.shape[0]
    n_nodes = Eg.shape[0]
    n_lobes = Eg.shape[1]
    nc = _chunks(n_dir)
    for chunk in numba.prange(nc):
        E = np.zeros((n_lobes, 3))
        A = np.zeros((n_lobes, 3))
        for n in range(chunk * n_dir // nc, (chunk + 1) * n_dir // nc):
            vx, vy, vz = v[n, 0], v[n, 1], v[n, 2]
            if vz <= 0.0 or lz <= 0.0:
                for ch in range(3):
                    out_top[n, ch] = 0.0
                    out_int[n, ch] = 0.0
                continue
            if mode == MODE_VIEW:
                c = vz
            else:
                hx = lx + vx
                hy = ly + vy
                hz = lz + vz
                c = abs(lx * hx + ly * hy + lz * hz) / math.sqrt(hx * hx + hy * hy + hz * hz)
            s = math.sqrt(min(max(c, 0.0), 1.0)) * (n_nodes - 1)
            j = min(int(s), n_nodes - 2)
            f = s - j
            for k in range(n_lobes):
                for ch in range(3):
                    E[k, ch] = Eg[j, k, ch] * (1.0 - f) + Eg[j + 1, k, ch] * f
                    A[k, ch] = Ag[j, k, ch] * (1.0 - f) + Ag[j + 1, k, ch] * f
            _sum_lobes(lx, ly, lz, vx, vy, vz, E, A, n_lobes, height_correlated, top_exact, top_alpha,
                       top_eta, top_kappa, out_top, out_int, n)


@numba.njit(parallel=True, cache=True)
def _eval_btdf(wi, v, T, A, height_correlated, out):
    """Transmission lobe by the mirror trick of §8: ``wi`` is the fake incident direction
    ``(-w_t.x, -w_t.y, |w_t.z|)``; values T D(h*) G(wi*, wo*) / (4 wi*_z |v_z|), h* = normalize(wi* + wo*),
    wo* = (v_x, v_y, |v_z|)."""
    ix, iy, iz = wi[0], wi[1], wi[2]
    n_dir = v.shape[0]
    nc = _chunks(n_dir)
    for chunk in numba.prange(nc):
        for n in range(chunk * n_dir // nc, (chunk + 1) * n_dir // nc):
            vx, vy, vz = v[n, 0], v[n, 1], -v[n, 2]
            if vz <= 0.0 or iz <= 0.0:
                for ch in range(3):
                    out[n, ch] = 0.0
                continue
            hx = ix + vx
            hy = iy + vy
            hz = iz + vz
            inv = 1.0 / math.sqrt(hx * hx + hy * hy + hz * hz)
            r = 0.0
            for ch in range(3):
                if ch == 0 or A[ch] != A[ch - 1]:
                    r = _lobe(ix, iy, iz, vx, vy, vz, hx * inv, hy * inv, hz * inv, A[ch], height_correlated)
                out[n, ch] = T[ch] * r


# --------------------------------------------------------------------------- public statistics

@dataclass(frozen=True)
class Lobe:
    """One GGX lobe: RGB energy (albedo, Fresnel included), RGB variance and roughness ``f^-1``."""

    energy: np.ndarray
    variance: np.ndarray
    alpha: np.ndarray


@dataclass(frozen=True)
class StackStatistics:
    """Result of the adding-doubling for one incidence cosine (§6; Bati 2021 notation).

    ``lobes[k]`` belongs to interface k. ``R0N``/``T0N``: reflectance/transmittance of the whole
    stack lit from above; ``RN0``/``TN0``: lit from below (inside the bottom medium); ``vR0N`` etc.
    their normalised variances (RGB); ``J0N``/``JN0`` the products of the variance Jacobians;
    ``cos_bottom`` the mean cosine in the last medium reached (below a transmitting stack, above a
    conductor; -1 after total internal reflection at the mean). Everything is RGB except the
    Jacobians and the cosine (angular quantities use the mean index).
    """

    lobes: list[Lobe]
    R0N: np.ndarray
    T0N: np.ndarray
    RN0: np.ndarray
    TN0: np.ndarray
    vR0N: np.ndarray
    vT0N: np.ndarray
    vRN0: np.ndarray
    vTN0: np.ndarray
    J0N: float
    JN0: float
    cos_bottom: float


def _run_statistics(packed: PackedStack, cos_theta: float, options: BelcourOptions):
    E = np.zeros((packed.n_lobes, 3))
    V = np.zeros((packed.n_lobes, 3))
    st = np.zeros((9, 3))
    wk = np.zeros((9, 3))
    adding_doubling(float(cos_theta), *packed.kernel_args(), options.per_channel, options.use_tir,
                    options.transmission_scale == "angular", E, V, st, wk)
    return E, V, st


def stack_statistics(stack: Stack, cos_theta: float, options: BelcourOptions | None = None,
                     **kwargs) -> StackStatistics:
    """Per-lobe energies and variances (and the stack's total statistics) at incidence ``cos_theta``
    (cosine in the ambient medium, air). Options as :class:`BelcourOptions` (or keyword arguments)."""
    if options is not None and kwargs:
        raise TypeError("give either a BelcourOptions or keyword options, not both")
    opts = options if options is not None else BelcourOptions(**kwargs)
    packed = pack_stack(stack, opts)
    E, V, st = _run_statistics(packed, cos_theta, opts)
    lobes = [Lobe(E[k].copy(), V[k].copy(), np.array([variance_to_roughness(x) for x in V[k]]))
             for k in range(packed.n_lobes)]
    return StackStatistics(lobes, st[_S_R0].copy(), st[_S_T0].copy(), st[_S_RI].copy(), st[_S_TI].copy(),
                           st[_S_VR0].copy(), st[_S_VT0].copy(), st[_S_VRI].copy(), st[_S_VTI].copy(),
                           float(st[_S_MISC, 0]), float(st[_S_MISC, 1]), float(st[_S_MISC, 2]))


def lobe_statistics(stack: Stack, cos_theta: float, options: BelcourOptions | None = None,
                    **kwargs) -> list[tuple[np.ndarray, np.ndarray]]:
    """``[(energy_rgb, alpha_rgb), ...]``, one pair per interface (top first), at ``cos_theta``.

    ``alpha`` is ``f^-1`` of the lobe variance, per channel (equal channels with
    ``per_channel=False``), not clamped. See :func:`stack_statistics` for everything else.
    """
    s = stack_statistics(stack, cos_theta, options, **kwargs)
    return [(lobe.energy, lobe.alpha) for lobe in s.lobes]


# --------------------------------------------------------------------------- models

class _BelcourBase(Model):
    """Shared machinery: options, support, per-instance caches of packed stacks and cosine grids."""

    def __init__(self, options: BelcourOptions) -> None:
        self.options = options
        self._packed: dict[Stack, PackedStack] = {}
        self._grids: dict[Stack, tuple[np.ndarray, np.ndarray]] = {}

    def support_reason(self, stack: Stack) -> str | None:
        return unsupported_reason(stack)

    def packed(self, stack: Stack) -> PackedStack:
        """The packed form of ``stack`` (memoised per model instance)."""
        p = self._packed.get(stack)
        if p is None:
            p = pack_stack(stack, self.options)
            self._packed[stack] = p
        return p

    def _grid(self, stack: Stack) -> tuple[np.ndarray, np.ndarray]:
        """Lobe energies and roughnesses tabulated over the incidence cosine (memoised per stack)."""
        g = self._grids.get(stack)
        if g is None:
            p = self.packed(stack)
            o = self.options
            g = _stats_grid(o.direction_grid, p.n_lobes, *p.kernel_args(), o.per_channel, o.use_tir,
                            o.transmission_scale == "angular")
            self._grids[stack] = g
        return g

    def lobe_statistics(self, stack: Stack, cos_theta: float) -> list[tuple[np.ndarray, np.ndarray]]:
        """:func:`lobe_statistics` with this model's options."""
        return lobe_statistics(stack, cos_theta, self.options)

    def _reflection(self, stack: Stack, l: np.ndarray, v: np.ndarray, mode: int, top_exact: bool) -> ModelValue:
        p = self.packed(stack)
        o = self.options
        l = np.ascontiguousarray(l, dtype=np.float64)
        shape = v.shape[:-1]
        vv = np.ascontiguousarray(v.reshape(-1, 3), dtype=np.float64)
        top = np.empty((vv.shape[0], 3))
        internal = np.empty((vv.shape[0], 3))
        top_alpha = max(float(p.alpha[0]), ALPHA_EVAL_MIN)
        if l[2] <= 0.0:
            top[:] = 0.0
            internal[:] = 0.0
        elif mode == MODE_LIGHT:
            E, V, _ = _run_statistics(p, float(l[2]), o)
            A = np.empty_like(V)
            _lobe_alphas(E, V, A)
            _eval_fixed(l, vv, E, A, o.height_correlated, top_exact, top_alpha, p.top_eta, p.top_kappa, top,
                        internal)
        elif o.direction_grid > 0:
            Eg, Ag = self._grid(stack)
            _eval_grid(l, vv, mode, Eg, Ag, o.height_correlated, top_exact, top_alpha, p.top_eta, p.top_kappa,
                       top, internal)
        else:
            _eval_dynamic(l, vv, mode, p.n_lobes, *p.kernel_args(), o.per_channel, o.use_tir,
                          o.transmission_scale == "angular", o.height_correlated, top_exact, top_alpha,
                          p.top_eta, p.top_kappa, top, internal)
        return ModelValue(top.reshape(shape + (3,)), internal.reshape(shape + (3,)))


def _options(**kw) -> BelcourOptions:
    if kw.get("cache_dir") is not None:
        kw["cache_dir"] = os.fspath(kw["cache_dir"])
    return BelcourOptions(**kw)


class BelcourForward(_BelcourBase):
    """Belcour 2018, forward model (statistics for the incident direction; not reciprocal)."""

    name = "belcour-fwd"
    description = "Belcour 2018 forward model: GGX lobes from adding-doubling of statistics at omega_i.n"
    sides = ("brdf",)

    def __init__(self, incident: str = "light", use_tir: bool = False, transmission_scale: str = "normal",
                 per_channel: bool = True, height_correlated: bool = False, fgd_source: str = "material",
                 cache_dir: str | os.PathLike | None = None, direction_grid: int = DIRECTION_GRID) -> None:
        super().__init__(_options(incident=incident, use_tir=use_tir, transmission_scale=transmission_scale,
                                  per_channel=per_channel, height_correlated=height_correlated,
                                  fgd_source=fgd_source, cache_dir=cache_dir, direction_grid=direction_grid))

    def _evaluate(self, stack: Stack, l: np.ndarray, v: np.ndarray, side: str) -> ModelValue:
        mode = MODE_LIGHT if self.options.incident == "light" else MODE_VIEW
        return self._reflection(stack, l, v, mode, top_exact=False)


class BelcourSymmetric(_BelcourBase):
    """Belcour 2018, symmetric model: statistics for c = |l.h| (reciprocal)."""

    name = "belcour-sym"
    description = "Belcour 2018 symmetric model: statistics from the half vector (reciprocal)"
    sides = ("brdf",)

    def __init__(self, use_tir: bool = False, transmission_scale: str = "normal", per_channel: bool = True,
                 height_correlated: bool = False, fgd_source: str = "material",
                 cache_dir: str | os.PathLike | None = None, direction_grid: int = DIRECTION_GRID) -> None:
        super().__init__(_options(use_tir=use_tir, transmission_scale=transmission_scale, per_channel=per_channel,
                                  height_correlated=height_correlated, fgd_source=fgd_source, cache_dir=cache_dir,
                                  direction_grid=direction_grid))

    def _evaluate(self, stack: Stack, l: np.ndarray, v: np.ndarray, side: str) -> ModelValue:
        return self._reflection(stack, l, v, MODE_HALF, top_exact=False)


class BelcourBati19(_BelcourBase):
    """Bati 2019 eq. 6: exact top-interface microfacet BRDF + Belcour forward lobes k >= 1."""

    name = "belcour-bati19"
    description = "Belcour forward model with lobe 0 replaced by the exact top-interface BRDF (Bati 2019 eq. 6)"
    sides = ("brdf",)

    def __init__(self, incident: str = "light", use_tir: bool = False, transmission_scale: str = "normal",
                 per_channel: bool = True, height_correlated: bool = False, fgd_source: str = "material",
                 cache_dir: str | os.PathLike | None = None, direction_grid: int = DIRECTION_GRID) -> None:
        super().__init__(_options(incident=incident, use_tir=use_tir, transmission_scale=transmission_scale,
                                  per_channel=per_channel, height_correlated=height_correlated,
                                  fgd_source=fgd_source, cache_dir=cache_dir, direction_grid=direction_grid))

    def _evaluate(self, stack: Stack, l: np.ndarray, v: np.ndarray, side: str) -> ModelValue:
        mode = MODE_LIGHT if self.options.incident == "light" else MODE_VIEW
        return self._reflection(stack, l, v, mode, top_exact=True)


class BelcourBTDF(_BelcourBase):
    """Belcour 2018 forward BTDF of slabs (``layered_dielectric``): one transmission lobe."""

    name = "belcour-btdf"
    description = "Belcour 2018 forward BTDF for slabs: one GGX lobe about the Snell direction"
    sides = ("btdf",)

    def __init__(self, use_tir: bool = False, transmission_scale: str = "normal", per_channel: bool = True,
                 height_correlated: bool = False, fgd_source: str = "material",
                 cache_dir: str | os.PathLike | None = None) -> None:
        super().__init__(_options(use_tir=use_tir, transmission_scale=transmission_scale, per_channel=per_channel,
                                  height_correlated=height_correlated, fgd_source=fgd_source, cache_dir=cache_dir))

    def support_reason(self, stack: Stack) -> str | None:
        reason = unsupported_reason(stack)
        if reason is not None:
            return reason
        if any(x.is_conductor for x in stack.interfaces):
            return "belcour-btdf models slabs only: every interface must be dielectric (kappa = 0)"
        if not stack.transmits:
            return "belcour-btdf needs a stack whose last layer is a dielectric interface (light exits below)"
        return None

    def transmission_lobe(self, stack: Stack, cos_theta: float) -> tuple[np.ndarray, np.ndarray, float]:
        """``(T0N_rgb, alpha_T_rgb, cos_N)``: energy, roughness (unclamped) and mean exit cosine."""
        p = self.packed(stack)
        _, _, st = _run_statistics(p, cos_theta, self.options)
        alpha = np.array([variance_to_roughness(x) for x in st[_S_VT0]])
        return st[_S_T0].copy(), alpha, float(st[_S_MISC, 2])

    def _evaluate(self, stack: Stack, l: np.ndarray, v: np.ndarray, side: str) -> ModelValue:
        p = self.packed(stack)
        shape = v.shape[:-1]
        vv = np.ascontiguousarray(v.reshape(-1, 3), dtype=np.float64)
        out = np.zeros((vv.shape[0], 3))
        if l[2] > 0.0:
            T, alpha, c_n = self.transmission_lobe(stack, float(l[2]))
            # Snell with the mean index through the whole stack (air above): the exit direction is
            # w_t = (-l_x / eta_N, -l_y / eta_N, -cos_N); the fake incident direction is its mirror.
            if c_n > 0.0 and np.any(T > 0.0):
                wi = np.array([l[0] / p.eta_exit, l[1] / p.eta_exit, c_n])
                wi /= np.linalg.norm(wi)
                A = np.maximum(alpha, ALPHA_EVAL_MIN)
                _eval_btdf(wi, vv, np.maximum(T, 0.0), A, self.options.height_correlated, out)
        zero = np.zeros_like(out)
        return ModelValue(zero.reshape(shape + (3,)), out.reshape(shape + (3,)))
