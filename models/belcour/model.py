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
  Bati 2019 precomputed per material, :func:`models.tables.belcour.fgd_slice`); ``"table"`` interpolates
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
``incident="light"`` runs it once per call (and computes each lobe's ``Lambda(l)`` once).

Covariances: the one adding-doubling kernel (:func:`adding_doubling`) and the lobe evaluation
also serve the anisotropic model ``belcour-aniso`` (:mod:`models.belcour.aniso`, Yamaguchi et al.
2019; its docstring has the equations and choices). Every (co)variance is stored as ``nq``
entries: ``nq = 1`` (a scalar variance; the isotropic models, :func:`pack_stack` by default) or
``nq = 3``, the entries ``(xx, xy, yy)`` of a 2 x 2 covariance in the macro tangent plane
(``pack_stack(..., anisotropic=True)``). All updates of §6 are linear with scalar coefficients, so
they act on each entry alike; an isotropic covariance (``xy = 0``, ``xx = yy``) goes through the
very floating-point operations of the scalar variance, so both forms give the same bits on
isotropic stacks. Only the FGD lookup roughness (:func:`lookup_alpha`) and the lobe's GGX
(:func:`principal` axes; ``a_1 = a_2`` needs no rotation) look at the off-diagonal entry.

The statistics themselves are exposed for the inverse method: :func:`lobe_statistics` (energy
and roughness per lobe, RGB) and :func:`stack_statistics` (also the variances and the
accumulated R0N, T0N, RN0, TN0 statistics of the stack, Bati 2021 notation);
:func:`run_adding_doubling` gives the raw kernel output for a packed stack.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numba
import numpy as np

from goniometer import optics
from goniometer.stack import Interface, Lambertian, Medium, Stack
from models._jit import njit
from models.tables import belcour as tables
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

#: rows of the energy state of the adding-doubling kernel: R0N, T0N, RN0, TN0 (per channel),
#: then (J0N, JN0, c_N)
_S_R0, _S_T0, _S_RI, _S_TI, _S_MISC = range(5)
#: rows of the (co)variance state: vR0N, vT0N, vRN0, vTN0 (Bati 2021 notation), nq entries each
_C_R0, _C_T0, _C_RI, _C_TI = range(4)
#: rows of the per-entry scratch array: R and T of the entry down and up, inter-reflection factor
#: m, lobe energy, second upward reflection term, 1 / (1 - Ri0 R)
_W_RDN, _W_TDN, _W_RUP, _W_TUP, _W_M, _W_E, _W_RUP2, _W_DINV = range(8)
#: columns of the lobe parameters: a_1, a_2, principal axis (e_x, e_y), Smith Lambda of l
_P_A1, _P_A2, _P_EX, _P_EY, _P_LAM = range(5)


# --------------------------------------------------------------------------- variance mapping

@njit(cache=True)
def roughness_to_variance(alpha: float) -> float:
    """``f(a) = a^1.1 / (1 - a^1.1)`` with ``a`` clamped to [0, 0.9999] (§2)."""
    a = min(max(alpha, 0.0), ALPHA_MAX)
    p = a ** 1.1
    return p / (1.0 - p)


@njit(cache=True)
def variance_to_roughness(var: float) -> float:
    """``f^-1(s) = (s / (1 + s))^(1/1.1)``; ``s <= 0`` (or NaN) gives 0, ``s = inf`` gives 1."""
    if not var > 0.0:
        return 0.0
    if math.isinf(var):
        return 1.0
    return (1.0 / (1.0 + 1.0 / var)) ** (1.0 / 1.1)


@njit(cache=True, inline="always")
def _transmission_roughness(a: float, n: float, c: float, c2: float, angular: bool) -> tuple:
    """Roughnesses ``(s_down a, s_up a)`` of the transmission lobes down and up through an interface
    of mean relative index ``n`` (§3): normal-incidence scales ``s_down = |n - 1| / (2 n)``,
    ``s_up = |1 - n| / 2`` (Bati 2021 eq. 6), or with ``angular`` ``s_down = |1 - c / (n c2)| / 2``,
    ``s_up = |1 - n c2 / c| / 2`` (``c``, ``c2``: mean cosines above and below)."""
    if angular:
        return a * 0.5 * abs(1.0 - c / (n * c2)), a * 0.5 * abs(1.0 - n * c2 / c)
    return a * 0.5 * abs(n - 1.0) / n, a * 0.5 * abs(1.0 - n)


# --------------------------------------------------------------------------- 2 x 2 covariances

@njit(cache=True, inline="always")
def interface_covariance(sx: float, sy: float, c: float, s: float) -> tuple:
    """``[t_x t_y] diag(sx, sy) [t_x t_y]^T`` with ``t_x = (c, s)``, ``t_y = (-s, c)`` (Y19 section 3.1):
    ``(xx, xy, yy)``."""
    return sx * c * c + sy * s * s, (sx - sy) * c * s, sx * s * s + sy * c * c


@njit(cache=True, inline="always")
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


@njit(cache=True, inline="always")
def blended_alpha(a1: float, a2: float, ex: float, ey: float, c: float, dx: float, dy: float) -> float:
    """FGD lookup roughness of an anisotropic GGX ``(a1 along (ex, ey), a2 across)`` seen at mean
    cosine ``c`` from azimuth ``d = (dx, dy)``:
    ``sqrt(c^2 (a1^2 + a2^2) / 2 + (1 - c^2) a_d^2)``, ``a_d^2 = a1^2 (d.e1)^2 + a2^2 (d.e2)^2``
    (rationale in :mod:`models.belcour.aniso`)."""
    p = dx * ex + dy * ey
    q = dy * ex - dx * ey
    ad2 = a1 * a1 * p * p + a2 * a2 * q * q
    c2 = c * c
    return math.sqrt(c2 * 0.5 * (a1 * a1 + a2 * a2) + (1.0 - c2) * ad2)


@njit(cache=True)
def lookup_alpha(xx: float, xy: float, yy: float, c: float, dx: float, dy: float) -> float:
    """FGD/TIR lookup roughness of the covariance ``(xx, xy, yy)``: ``f^-1(xx)`` if isotropic, else
    :func:`blended_alpha` of its principal roughnesses ``f^-1(eigenvalue)``."""
    if xy == 0.0 and xx == yy:
        return variance_to_roughness(xx)
    l1, l2, ex, ey = principal(xx, xy, yy)
    return blended_alpha(variance_to_roughness(l1), variance_to_roughness(l2), ex, ey, c, dx, dy)


@njit(cache=True, inline="always")
def _lobe_covariance(ax: float, ay: float, c: float, s: float, iso: bool) -> tuple:
    """``(xx, xy, yy)`` of a GGX lobe of roughnesses ``(ax, ay)`` along the tangent axes ``t_x = (c, s)``,
    ``t_y = (-s, c)``: ``(f(ax), 0, f(ax))`` if ``iso`` (so that ``xx`` is the scalar variance), else
    :func:`interface_covariance` of ``f(ax), f(ay)``."""
    if iso:
        v = roughness_to_variance(ax)
        return v, 0.0, v
    return interface_covariance(roughness_to_variance(ax), roughness_to_variance(ay), c, s)


@njit(cache=True, inline="always")
def _pick(q: int, x0: float, x1: float, x2: float) -> float:
    """Entry ``q`` of ``(x0, x1, x2)`` (a constant ``q`` folds away)."""
    if q == 0:
        return x0
    if q == 1:
        return x1
    return x2


@njit(cache=True, inline="always")
def unit_azimuth(x: float, y: float) -> tuple:
    """Unit azimuth of (x, y); ``(1, 0)`` at the pole."""
    r = math.sqrt(x * x + y * y)
    if r > 0.0:
        return x / r, y / r
    return 1.0, 0.0


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


def resolve_options(options: BelcourOptions | None, kwargs: dict, cls: type = BelcourOptions) -> BelcourOptions:
    """``options`` if given, else ``cls(**kwargs)`` (the calling convention of :func:`stack_statistics`:
    an options object *or* keyword options)."""
    if options is not None and kwargs:
        raise TypeError("give either an options object or keyword options, not both")
    return options if options is not None else cls(**kwargs)


@dataclass(frozen=True)
class PackedStack:
    """Flat arrays the kernels read; one entry per interface or medium, top first.

    * ``kind`` (KIND_*), ``alpha`` (interface roughness; along the tangent x axis), ``alpha_y``
      (along the tangent y axis), ``rot`` = (cos, sin) of the tangent-frame rotation, ``iso``
      (isotropic interface or medium);
    * ``cov_r``, ``cov_t_down``, ``cov_t_up`` (ne, nq): the (co)variances of reflection and of the
      normal-incidence transmission down and up, ``f(alpha)``, ``f(s_down alpha)``, ``f(s_up alpha)``
      (:func:`_transmission_roughness`): one column (scalar variances) or three, ``(xx, xy, yy)``
      (:func:`_lobe_covariance`; zeros for media);
    * ``n_mean``: mean relative index (Snell, s and J; 1 for conductors and media);
    * ``tau``: RGB optical depth of media; ``eta_up``: TIR index ratio across the interface above
      the entry's upper medium (1 = none);
    * ``achromatic``: the three channels share one FGD slice;
    * FGD slices per entry and channel (``fgd_split``, ``fgd_lower``, ``fgd_upper``: stacked
      :class:`models.tables.belcour.TableSlice`), TIR slices per entry (channel axis of length 1);
    * ``n_lobes`` (number of interfaces), ``eta_exit`` (absolute index of the last medium reached:
      below a transmitting stack, above a conductor), ``top_eta``/``top_kappa`` (relative index of
      the top interface, RGB).
    """

    kind: np.ndarray
    alpha: np.ndarray
    alpha_y: np.ndarray
    rot: np.ndarray
    iso: np.ndarray
    cov_r: np.ndarray
    cov_t_down: np.ndarray
    cov_t_up: np.ndarray
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

    @property
    def n_cov(self) -> int:
        """Entries per (co)variance: 1 (scalar variances) or 3 (``(xx, xy, yy)``)."""
        return self.cov_r.shape[1]

    @property
    def var_r(self) -> np.ndarray:
        """``f(alpha)`` per entry (the xx entries of ``cov_r``)."""
        return self.cov_r[:, 0]

    @property
    def var_t_down(self) -> np.ndarray:
        """``f(s_down alpha)`` per entry (the xx entries of ``cov_t_down``)."""
        return self.cov_t_down[:, 0]

    @property
    def var_t_up(self) -> np.ndarray:
        """``f(s_up alpha)`` per entry (the xx entries of ``cov_t_up``)."""
        return self.cov_t_up[:, 0]

    @property
    def isotropic(self) -> bool:
        """Every interface is isotropic."""
        return bool(np.all(self.iso))

    def kernel_args(self) -> tuple:
        """The ``stack`` argument of :func:`adding_doubling`: the arrays above, in order."""
        return (self.kind, self.alpha, self.alpha_y, self.rot, self.iso, self.cov_r, self.cov_t_down,
                self.cov_t_up, self.n_mean, self.tau, self.eta_up, self.achromatic, self.fgd_split, self.fgd_lower,
                self.fgd_upper, self.tir_split, self.tir_lower, self.tir_upper)


def unsupported_reason(stack: Stack, anisotropic: bool = False) -> str | None:
    """Why Belcour's model cannot represent ``stack`` (None if it can); anisotropic interfaces are
    refused unless ``anisotropic`` (the covariance form of ``belcour-aniso``)."""
    if any(isinstance(x, Lambertian) for x in stack.layers):
        return "Belcour's model cannot represent a Lambertian base (it only sums GGX lobes)"
    if not stack.interfaces:
        return "the stack has no interface"
    if not anisotropic and any(getattr(x, "is_anisotropic", False) for x in stack.interfaces):
        return "Belcour's model is isotropic: it cannot represent an anisotropic interface"
    return None


def _pad(a: np.ndarray, rows: int) -> np.ndarray:
    out = np.zeros((rows, a.shape[1]))
    out[: a.shape[0]] = a
    return out


def pack_stack(stack: Stack, options: BelcourOptions = BelcourOptions(), anisotropic: bool = False) -> PackedStack:
    """Flatten a supported stack and gather its FGD (and TIR) slices.

    ``anisotropic=False``: scalar variances (one column), anisotropic interfaces refused.
    ``anisotropic=True``: anisotropic interfaces accepted, covariances ``(xx, xy, yy)`` in the macro
    tangent plane (every stack, isotropic ones included). The FGD/TIR slices do not depend on
    roughness, so both forms share them."""
    reason = unsupported_reason(stack, anisotropic)
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
    alpha_y = np.zeros(ne)
    rot = np.zeros((ne, 2))
    rot[:, 0] = 1.0
    iso = np.ones(ne, dtype=np.bool_)
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
        alpha[e], alpha_y[e] = layer.alpha_xy
        if layer.is_anisotropic:
            psi = math.radians(layer.rotation_deg)
            rot[e] = (math.cos(psi), math.sin(psi))
            iso[e] = False
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
    nq = 3 if anisotropic else 1
    cov_r = np.zeros((ne, nq))
    cov_t_down = np.zeros((ne, nq))
    cov_t_up = np.zeros((ne, nq))
    for e in range(ne):
        if kind[e] == KIND_MEDIUM:
            continue
        c, s = rot[e]
        x_down, x_up = _transmission_roughness(alpha[e], n_mean[e], 1.0, 1.0, False)
        y_down, y_up = _transmission_roughness(alpha_y[e], n_mean[e], 1.0, 1.0, False)
        cov_r[e] = _lobe_covariance(alpha[e], alpha_y[e], c, s, iso[e])[:nq]
        cov_t_down[e] = _lobe_covariance(x_down, y_down, c, s, iso[e])[:nq]
        cov_t_up[e] = _lobe_covariance(x_up, y_up, c, s, iso[e])[:nq]
    return PackedStack(kind, alpha, alpha_y, rot, iso, cov_r, cov_t_down, cov_t_up, n_mean, tau, eta_up, achromatic,
                       fgd_split, fgd_lower, fgd_upper, tir_split, tir_lower, tir_upper, n_if, n_cur, top_eta,
                       top_kappa)


# --------------------------------------------------------------------------- adding-doubling kernel

@njit(cache=True, inline="always")
def _mean_row(a, row) -> float:
    return (a[row, 0] + a[row, 1] + a[row, 2]) / 3.0


@njit(cache=True, inline="always")
def _same_as_previous_channel(a, i, ch, nq) -> bool:
    """``a[i, ch, :nq] == a[i, ch - 1, :nq]`` (``ch > 0``)."""
    for q in range(nq):
        if a[i, ch, q] != a[i, ch - 1, q]:
            return False
    return True


@njit(cache=True, inline="always")
def _lookup_roughness(nq, cs, ch, r0, r1, r2, a, ay, rc, rs, iso, c, dx, dy) -> float:
    """FGD/TIR lookup roughness of an interface (§4): ``a~ = f^-1(vT0i + f(alpha))`` -- for
    covariances :func:`lookup_alpha` of ``Sigma_T0i + Sigma_r`` -- and the interface's own roughness
    (:func:`blended_alpha` if anisotropic) when nothing is accumulated above; ``(r0, r1, r2)``: the
    interface's reflection (co)variance."""
    if nq == 1:
        v = cs[_C_T0, ch, 0]
        return variance_to_roughness(v + r0) if v > 0.0 else a
    if cs[_C_T0, ch, 0] > 0.0 or cs[_C_T0, ch, 2] > 0.0:
        return lookup_alpha(cs[_C_T0, ch, 0] + r0, cs[_C_T0, ch, 1] + r1, cs[_C_T0, ch, 2] + r2, c, dx, dy)
    if iso:
        return a
    return blended_alpha(a, ay, rc, rs, c, dx, dy)


@njit(cache=True)
def _workspace(n_lobes: int, nq: int) -> tuple:
    """The output and scratch arrays of :func:`adding_doubling` for ``n_lobes`` lobes and ``nq``
    entries per (co)variance: ``(E, C, st, cs, wk, wc)``."""
    return (np.zeros((n_lobes, 3)), np.zeros((n_lobes, 3, nq)), np.zeros((5, 3)), np.zeros((4, 3, nq)),
            np.zeros((8, 3)), np.zeros((3, nq)))


@njit(cache=True, inline="always")
def _n_cov(stack) -> int:
    """Entries per (co)variance of a :meth:`PackedStack.kernel_args` tuple (the columns of ``cov_r``)."""
    return stack[5].shape[1]


@njit(cache=True)
def adding_doubling(c_in, dx, dy, stack, per_channel, use_tir, angular_s, E, C, st, cs, wk, wc):
    """The statistics of §6 for incidence cosine ``c_in`` (in the top medium) and unit incidence
    azimuth ``(dx, dy)`` (seen by anisotropic covariances only) through ``stack`` (the arrays of
    :meth:`PackedStack.kernel_args`), with ``nq`` = 1 or 3 entries per (co)variance (module docstring).

    Writes lobe energies ``E[k, ch]`` and (co)variances ``C[k, ch, :nq]`` (k = interface index;
    zeros for interfaces below a conductor or below total internal reflection at the mean), the
    energy state ``st`` (5, 3): rows R0N, T0N, RN0, TN0 (per channel) and ``st[4] = (J0N, JN0,
    c_N)`` with ``c_N`` the mean cosine in the last medium reached (below a transmitting stack,
    above a conductor; -1 after total internal reflection at the mean), and the (co)variance state
    ``cs[(R0N, T0N, RN0, TN0), ch, :nq]``. ``wk`` (8, 3) and ``wc`` (3, nq) are scratch
    (:func:`_workspace` makes them all). No allocation.
    """
    # one body, inlined with a constant nq each (the entry loops unroll)
    if _n_cov(stack) == 1:
        _adding_doubling(1, c_in, dx, dy, stack, per_channel, use_tir, angular_s, E, C, st, cs, wk, wc)
    else:
        _adding_doubling(3, c_in, dx, dy, stack, per_channel, use_tir, angular_s, E, C, st, cs, wk, wc)


@njit(cache=True, inline="always")
def _adding_doubling(nq, c_in, dx, dy, stack, per_channel, use_tir, angular_s, E, C, st, cs, wk, wc):
    """:func:`adding_doubling` for ``nq`` (a constant where inlined). Every update of a (co)variance is
    the scalar one of §6 applied to each entry, in the same floating-point order."""
    (kind, alpha, alpha_y, rot, iso, cov_r, cov_t_down, cov_t_up, n_mean, tau, eta_up, achromatic, fgd_split,
     fgd_lower, fgd_upper, tir_split, tir_lower, tir_upper) = stack
    n_e = kind.shape[0]
    for k in range(E.shape[0]):
        for ch in range(3):
            E[k, ch] = 0.0
            for q in range(nq):
                C[k, ch, q] = 0.0
    for ch in range(3):
        st[_S_R0, ch] = 0.0
        st[_S_RI, ch] = 0.0
        st[_S_T0, ch] = 1.0
        st[_S_TI, ch] = 1.0
        for r in range(4):
            for q in range(nq):
                cs[r, ch, q] = 0.0
    J0 = 1.0
    Ji = 1.0
    c = min(max(c_in, COS_MIN), 1.0)
    lobe = 0
    for e in range(n_e):
        # the entry's (co)variances: reflection r, transmission down d and up u (zero for media)
        r0 = r1 = r2 = 0.0
        d0 = d1 = d2 = 0.0
        u0 = u1 = u2 = 0.0
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
            r0 = cov_r[e, 0]
            if nq == 3:
                r1 = cov_r[e, 1]
                r2 = cov_r[e, 2]
            if passes:
                c2 = max(c2, COS_MIN)
                if angular_s:
                    x_down, x_up = _transmission_roughness(alpha[e], n, c, c2, True)
                    y_down, y_up = _transmission_roughness(alpha_y[e], n, c, c2, True)
                    d0, d1, d2 = _lobe_covariance(x_down, y_down, rot[e, 0], rot[e, 1], iso[e])
                    u0, u1, u2 = _lobe_covariance(x_up, y_up, rot[e, 0], rot[e, 1], iso[e])
                else:
                    d0 = cov_t_down[e, 0]
                    u0 = cov_t_up[e, 0]
                    if nq == 3:
                        d1 = cov_t_down[e, 1]
                        d2 = cov_t_down[e, 2]
                        u1 = cov_t_up[e, 1]
                        u2 = cov_t_up[e, 2]
                jd = (c2 / c) * n
                ju = 1.0 / jd
            do_tir = use_tir and e > 0 and eta_up[e] < 1.0
            a = alpha[e]
            at = a
            for ch in range(3):
                same = ch > 0 and _same_as_previous_channel(cs, _C_T0, ch, nq)
                if not same:
                    # a~ = f^-1(vT0i + f(alpha)); exactly alpha when nothing is accumulated above
                    at = _lookup_roughness(nq, cs, ch, r0, r1, r2, a, alpha_y[e], rot[e, 0], rot[e, 1], iso[e], c, dx,
                                           dy)
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
        # lobe (co)variance v_k = vTi0 + J0i (vT0i + vr + m (vr + vRi0)), entrywise
        m_avg = _mean_row(wk, _W_M)
        for ch in range(3):
            m = wk[_W_M, ch] if per_channel else m_avg
            for q in range(nq):
                vr = _pick(q, r0, r1, r2)
                wc[ch, q] = cs[_C_TI, ch, q] + J0 * (cs[_C_T0, ch, q] + vr + m * (vr + cs[_C_RI, ch, q]))
        if kind[e] != KIND_MEDIUM:
            for ch in range(3):
                E[lobe, ch] = wk[_W_E, ch]
                for q in range(nq):
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
            for q in range(nq):
                vr = _pick(q, r0, r1, r2)
                vtd = _pick(q, d0, d1, d2)
                vtu = _pick(q, u0, u1, u2)
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


@dataclass(frozen=True)
class AddingDoubling:
    """Output of :func:`adding_doubling` for one incidence (:func:`run_adding_doubling`).

    ``energy`` (n_lobes, 3) and ``covariance`` (n_lobes, 3, nq) of the lobes (one per interface, top
    first); the stack's energies ``R0N``, ``T0N``, ``RN0``, ``TN0`` (3,) and (co)variances ``cov_R0N``,
    ``cov_T0N``, ``cov_RN0``, ``cov_TN0`` (3, nq) (Bati 2021 notation); the Jacobian products ``J0N``,
    ``JN0`` and the mean cosine in the last medium reached ``cos_bottom`` (as :class:`StackStatistics`).
    """

    energy: np.ndarray
    covariance: np.ndarray
    R0N: np.ndarray
    T0N: np.ndarray
    RN0: np.ndarray
    TN0: np.ndarray
    cov_R0N: np.ndarray
    cov_T0N: np.ndarray
    cov_RN0: np.ndarray
    cov_TN0: np.ndarray
    J0N: float
    JN0: float
    cos_bottom: float


def run_adding_doubling(packed: PackedStack, cos_theta: float, options: BelcourOptions,
                        azimuth: tuple[float, float] = (1.0, 0.0)) -> AddingDoubling:
    """:func:`adding_doubling` of a packed stack at incidence ``cos_theta`` and unit azimuth
    ``azimuth`` (which only anisotropic covariances see), with the switches of ``options``."""
    E, C, st, cs, wk, wc = _workspace(packed.n_lobes, packed.n_cov)
    adding_doubling(float(cos_theta), float(azimuth[0]), float(azimuth[1]), packed.kernel_args(), options.per_channel,
                    options.use_tir, options.transmission_scale == "angular", E, C, st, cs, wk, wc)
    return AddingDoubling(E, C, st[_S_R0].copy(), st[_S_T0].copy(), st[_S_RI].copy(), st[_S_TI].copy(),
                          cs[_C_R0].copy(), cs[_C_T0].copy(), cs[_C_RI].copy(), cs[_C_TI].copy(),
                          float(st[_S_MISC, 0]), float(st[_S_MISC, 1]), float(st[_S_MISC, 2]))


# --------------------------------------------------------------------------- lobe evaluation

@njit(cache=True)
def _lobe_params(E, C, P, lx, ly, lz, k_lambda) -> None:
    """Evaluation GGX of every lobe with energy: ``P[k, ch, :4] = (a1, a2, ex, ey)`` from the
    (co)variance ``C[k, ch]``: ``a1 = a2 = max(f^-1(v), ALPHA_EVAL_MIN)`` for a scalar variance or an
    isotropic covariance, else ``a_i = max(f^-1(eigenvalue), ALPHA_EVAL_MIN)`` along the principal
    axes (:func:`principal`; ``(ex, ey)`` is the axis of ``a1 >= a2``); and, for the lobes
    ``k >= k_lambda``, ``P[k, ch, 4] = Lambda(l)`` in the lobe's frame."""
    nq = C.shape[2]
    for k in range(E.shape[0]):
        if E[k, 0] == 0.0 and E[k, 1] == 0.0 and E[k, 2] == 0.0:
            continue
        for ch in range(3):
            if ch > 0 and _same_as_previous_channel(C, k, ch, nq):
                for q in range(5):
                    P[k, ch, q] = P[k, ch - 1, q]
                continue
            xx = C[k, ch, 0]
            if nq == 1 or (C[k, ch, 1] == 0.0 and xx == C[k, ch, 2]):
                a = max(variance_to_roughness(xx), ALPHA_EVAL_MIN)
                P[k, ch, _P_A1] = a
                P[k, ch, _P_A2] = a
                P[k, ch, _P_EX] = 1.0
                P[k, ch, _P_EY] = 0.0
            else:
                l1, l2, ex, ey = principal(xx, C[k, ch, 1], C[k, ch, 2])
                P[k, ch, _P_A1] = max(variance_to_roughness(l1), ALPHA_EVAL_MIN)
                P[k, ch, _P_A2] = max(variance_to_roughness(l2), ALPHA_EVAL_MIN)
                P[k, ch, _P_EX] = ex
                P[k, ch, _P_EY] = ey
            if k >= k_lambda:
                P[k, ch, _P_LAM] = _lambda_in_frame(lx, ly, lz, P[k, ch, _P_A1], P[k, ch, _P_A2], P[k, ch, _P_EX],
                                                    P[k, ch, _P_EY])


@njit(cache=True, inline="always")
def _lambda_in_frame(wx, wy, wz, a1, a2, ex, ey) -> float:
    """Smith Lambda of ``w`` for the GGX ``(a1 along (ex, ey), a2 across)``."""
    if a1 == a2:
        return optics.ggx_lambda(wx, wy, wz, a1, a2)
    return optics.ggx_lambda(ex * wx + ey * wy, ex * wy - ey * wx, wz, a1, a2)


@njit(cache=True, inline="always")
def _same_params(P, k, ch) -> bool:
    """Lobe ``k`` has the same GGX in channels ``ch`` and ``ch - 1``."""
    return (P[k, ch, _P_A1] == P[k, ch - 1, _P_A1] and P[k, ch, _P_A2] == P[k, ch - 1, _P_A2]
            and P[k, ch, _P_EX] == P[k, ch - 1, _P_EX] and P[k, ch, _P_EY] == P[k, ch - 1, _P_EY])


@njit(cache=True, inline="always")
def _lobe(lz, vx, vy, vz, hx, hy, hz, a1, a2, ex, ey, lam_l, height_correlated) -> float:
    """GGX lobe without Fresnel: D(h'; a1, a2) G(l', v') / (4 l_z v_z), in 1/sr; primes in the lobe's
    principal frame (no rotation when ``a1 == a2``); ``lam_l`` = Lambda(l') precomputed."""
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


@njit(cache=True)
def _sum_lobes(lx, ly, lz, vx, vy, vz, E, P, k0, height_correlated, out_top, out_int, n) -> None:
    """Set ``out_top[n]`` to lobe 0 and ``out_int[n]`` to the sum of the others, lobes ``k >= k0`` only."""
    hx, hy, hz = optics.half_vector(lx, ly, lz, vx, vy, vz)
    for ch in range(3):
        out_top[n, ch] = 0.0
        out_int[n, ch] = 0.0
    for k in range(k0, E.shape[0]):
        if E[k, 0] == 0.0 and E[k, 1] == 0.0 and E[k, 2] == 0.0:
            continue
        r = 0.0
        for ch in range(3):
            if ch == 0 or not _same_params(P, k, ch):
                r = _lobe(lz, vx, vy, vz, hx, hy, hz, P[k, ch, _P_A1], P[k, ch, _P_A2], P[k, ch, _P_EX],
                          P[k, ch, _P_EY], P[k, ch, _P_LAM], height_correlated)
            if k == 0:
                out_top[n, ch] += E[k, ch] * r
            else:
                out_int[n, ch] += E[k, ch] * r


@njit(cache=True)
def _exact_top(lx, ly, lz, vx, vy, vz, E, top_alpha, top_eta, top_kappa, height_correlated, out_top, n) -> None:
    """``out_top[n]`` = the exact microfacet BRDF of the top interface (Bati 2019 eq. 6) in place of
    lobe 0 (if lobe 0 has energy). Kept out of :func:`_sum_lobes`, which it would slow down."""
    if E[0, 0] == 0.0 and E[0, 1] == 0.0 and E[0, 2] == 0.0:
        return
    for ch in range(3):
        if ch > 0 and top_eta[ch] == top_eta[ch - 1] and top_kappa[ch] == top_kappa[ch - 1]:
            out_top[n, ch] = out_top[n, ch - 1]
        else:
            out_top[n, ch] = optics.microfacet_reflection(lx, ly, lz, vx, vy, vz, top_alpha, top_alpha,
                                                          top_eta[ch], top_kappa[ch], height_correlated)


@njit(cache=True, inline="always")
def _chunks(n: int) -> int:
    """Number of parallel chunks for ``n`` directions."""
    return max(1, min(n // 2048, 512))


@njit(cache=True, inline="always")
def _below_horizon(lz, vz, out_top, out_int, n) -> bool:
    """If ``l`` or ``v`` is below the horizon, zero both outputs of direction ``n`` and say so."""
    if vz <= 0.0 or lz <= 0.0:
        for ch in range(3):
            out_top[n, ch] = 0.0
            out_int[n, ch] = 0.0
        return True
    return False


@njit(cache=True, inline="always")
def _statistics_cosine(mode, lx, ly, lz, vx, vy, vz) -> float:
    """The cosine the statistics are computed for: ``v_z`` (MODE_VIEW) or ``|l.h|`` (MODE_HALF)."""
    if mode == MODE_VIEW:
        return vz
    hx = lx + vx
    hy = ly + vy
    hz = lz + vz
    return abs(lx * hx + ly * hy + lz * hz) / math.sqrt(hx * hx + hy * hy + hz * hz)


@njit(parallel=True, cache=True)
def _eval_fixed(l, v, z_sign, E, P, height_correlated, top_exact, top_alpha, top_eta, top_kappa, out_top, out_int):
    """Lobes fixed for all directions (forward model with omega_i = l; ``P`` from :func:`_lobe_params`)
    at the views ``(v_x, v_y, z_sign v_z)`` (``z_sign = -1``: the mirror
    trick of the BTDF)."""
    lx, ly, lz = l[0], l[1], l[2]
    n_dir = v.shape[0]
    nc = _chunks(n_dir)
    k0 = 1 if top_exact else 0
    for chunk in numba.prange(nc):
        for n in range(chunk * n_dir // nc, (chunk + 1) * n_dir // nc):
            vx, vy, vz = v[n, 0], v[n, 1], z_sign * v[n, 2]
            if _below_horizon(lz, vz, out_top, out_int, n):
                continue
            _sum_lobes(lx, ly, lz, vx, vy, vz, E, P, k0, height_correlated, out_top, out_int, n)
            if top_exact:
                _exact_top(lx, ly, lz, vx, vy, vz, E, top_alpha, top_eta, top_kappa, height_correlated, out_top, n)


@njit(parallel=True, cache=True)
def _eval_dynamic(l, v, mode, n_lobes, stack, per_channel, use_tir, angular_s, height_correlated, top_exact, top_alpha,
                  top_eta, top_kappa, out_top, out_int):
    """Statistics recomputed per direction: ``mode`` MODE_VIEW (c = v_z) or MODE_HALF (c = |l.h|);
    the incidence azimuth is that of ``v``."""
    lx, ly, lz = l[0], l[1], l[2]
    n_dir = v.shape[0]
    nc = _chunks(n_dir)
    k0 = 1 if top_exact else 0
    nq = _n_cov(stack)
    for chunk in numba.prange(nc):
        E, C, st, cs, wk, wc = _workspace(n_lobes, nq)
        P = np.zeros((n_lobes, 3, 5))
        for n in range(chunk * n_dir // nc, (chunk + 1) * n_dir // nc):
            vx, vy, vz = v[n, 0], v[n, 1], v[n, 2]
            if _below_horizon(lz, vz, out_top, out_int, n):
                continue
            c = _statistics_cosine(mode, lx, ly, lz, vx, vy, vz)
            dx, dy = unit_azimuth(vx, vy) if nq == 3 else (1.0, 0.0)
            adding_doubling(c, dx, dy, stack, per_channel, use_tir, angular_s, E, C, st, cs, wk, wc)
            _lobe_params(E, C, P, lx, ly, lz, k0)
            _sum_lobes(lx, ly, lz, vx, vy, vz, E, P, k0, height_correlated, out_top, out_int, n)
            if top_exact:
                _exact_top(lx, ly, lz, vx, vy, vz, E, top_alpha, top_eta, top_kappa, height_correlated, out_top, n)


@njit(parallel=True, cache=True)
def _stats_grid(n_nodes, n_phi, n_lobes, stack, per_channel, use_tir, angular_s):
    """Statistics table ``G[i, j, k, ch, :]`` = (lobe energy, clamped roughness ``a`` (scalar
    variances) or roughness matrix ``a_1 e_1 e_1^T + a_2 e_2 e_2^T`` as ``(xx, xy, yy)`` (covariances))
    at the azimuths ``phi_i = i pi / n_phi`` and cosines ``c_j = (j / (n_nodes - 1))^2``.
    Azimuth-major, so that the two cosine neighbours of a direction are adjacent in memory."""
    nq = _n_cov(stack)
    G = np.zeros((n_phi, n_nodes, n_lobes, 3, 1 + nq))
    nc = max(1, min(n_nodes // 16, 512))
    for chunk in numba.prange(nc):
        E, C, st, cs, wk, wc = _workspace(n_lobes, nq)
        P = np.zeros((n_lobes, 3, 5))
        for j in range(chunk * n_nodes // nc, (chunk + 1) * n_nodes // nc):
            t = j / (n_nodes - 1)
            for i in range(n_phi):
                phi = i * math.pi / n_phi
                adding_doubling(t * t, math.cos(phi), math.sin(phi), stack, per_channel, use_tir, angular_s, E, C, st,
                                cs, wk, wc)
                for k in range(n_lobes):
                    for ch in range(3):
                        P[k, ch, _P_A1] = ALPHA_EVAL_MIN
                        P[k, ch, _P_A2] = ALPHA_EVAL_MIN
                        P[k, ch, _P_EX] = 1.0
                        P[k, ch, _P_EY] = 0.0
                _lobe_params(E, C, P, 0.0, 0.0, 1.0, n_lobes)
                for k in range(n_lobes):
                    for ch in range(3):
                        G[i, j, k, ch, 0] = E[k, ch]
                        a1, a2, ex, ey = P[k, ch, _P_A1], P[k, ch, _P_A2], P[k, ch, _P_EX], P[k, ch, _P_EY]
                        if nq == 1:
                            G[i, j, k, ch, 1] = a1
                        elif a1 == a2:
                            G[i, j, k, ch, 1] = a1
                            G[i, j, k, ch, 2] = 0.0
                            G[i, j, k, ch, 3] = a1
                        else:
                            xx, xy, yy = interface_covariance(a1, a2, ex, ey)
                            G[i, j, k, ch, 1] = xx
                            G[i, j, k, ch, 2] = xy
                            G[i, j, k, ch, 3] = yy
    return G


@njit(cache=True, inline="always")
def _lerp_nodes(G, i, j, k, ch, q, f) -> float:
    """``G[i, j, k, ch, q]`` interpolated linearly towards cosine node ``j + 1`` by ``f``."""
    return G[i, j, k, ch, q] * (1.0 - f) + G[i, j + 1, k, ch, q] * f


@njit(parallel=True, cache=True)
def _eval_grid(l, v, mode, G, height_correlated, top_exact, top_alpha, top_eta, top_kappa, out_top, out_int):
    """Direction-dependent statistics interpolated from :func:`_stats_grid`: linearly in ``sqrt(c)``
    and, with more than one azimuth node, periodically in the azimuth of ``v`` modulo pi; an
    interpolated roughness matrix is eigen-decomposed into the lobe's GGX."""
    lx, ly, lz = l[0], l[1], l[2]
    n_dir = v.shape[0]
    n_phi = G.shape[0]
    n_nodes = G.shape[1]
    n_lobes = G.shape[2]
    nq = G.shape[4] - 1
    k0 = 1 if top_exact else 0
    nc = _chunks(n_dir)
    for chunk in numba.prange(nc):
        E = np.zeros((n_lobes, 3))
        P = np.zeros((n_lobes, 3, 5))
        for n in range(chunk * n_dir // nc, (chunk + 1) * n_dir // nc):
            vx, vy, vz = v[n, 0], v[n, 1], v[n, 2]
            if _below_horizon(lz, vz, out_top, out_int, n):
                continue
            c = _statistics_cosine(mode, lx, ly, lz, vx, vy, vz)
            s = math.sqrt(min(max(c, 0.0), 1.0)) * (n_nodes - 1)
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
            pxx = 0.0
            pxy = 0.0
            pyy = 0.0
            for k in range(n_lobes):
                for ch in range(3):
                    e = _lerp_nodes(G, i0, j, k, ch, 0, f)
                    xx = _lerp_nodes(G, i0, j, k, ch, 1, f)
                    xy = _lerp_nodes(G, i0, j, k, ch, 2, f) if nq == 3 else 0.0
                    yy = _lerp_nodes(G, i0, j, k, ch, 3, f) if nq == 3 else 0.0
                    if n_phi > 1:
                        e = e * (1.0 - g) + _lerp_nodes(G, i1, j, k, ch, 0, f) * g
                        xx = xx * (1.0 - g) + _lerp_nodes(G, i1, j, k, ch, 1, f) * g
                        if nq == 3:
                            xy = xy * (1.0 - g) + _lerp_nodes(G, i1, j, k, ch, 2, f) * g
                            yy = yy * (1.0 - g) + _lerp_nodes(G, i1, j, k, ch, 3, f) * g
                    if nq == 1:
                        yy = xx
                    E[k, ch] = e
                    if ch > 0 and xx == pxx and xy == pxy and yy == pyy:
                        for q in range(5):
                            P[k, ch, q] = P[k, ch - 1, q]
                        continue
                    if nq == 1 or (xy == 0.0 and xx == yy):
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
                    if k >= k0:
                        P[k, ch, _P_LAM] = _lambda_in_frame(lx, ly, lz, P[k, ch, _P_A1], P[k, ch, _P_A2],
                                                            P[k, ch, _P_EX], P[k, ch, _P_EY])
                    pxx = xx
                    pxy = xy
                    pyy = yy
            _sum_lobes(lx, ly, lz, vx, vy, vz, E, P, k0, height_correlated, out_top, out_int, n)
            if top_exact:
                _exact_top(lx, ly, lz, vx, vy, vz, E, top_alpha, top_eta, top_kappa, height_correlated, out_top, n)


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


def stack_statistics(stack: Stack, cos_theta: float, options: BelcourOptions | None = None,
                     **kwargs) -> StackStatistics:
    """Per-lobe energies and variances (and the stack's total statistics) at incidence ``cos_theta``
    (cosine in the ambient medium, air). Options as :class:`BelcourOptions` (or keyword arguments)."""
    opts = resolve_options(options, kwargs)
    packed = pack_stack(stack, opts)
    r = run_adding_doubling(packed, cos_theta, opts)
    V = r.covariance[:, :, 0]
    lobes = [Lobe(r.energy[k].copy(), V[k].copy(), np.array([variance_to_roughness(x) for x in V[k]]))
             for k in range(packed.n_lobes)]
    return StackStatistics(lobes, r.R0N, r.T0N, r.RN0, r.TN0, r.cov_R0N[:, 0].copy(), r.cov_T0N[:, 0].copy(),
                           r.cov_RN0[:, 0].copy(), r.cov_TN0[:, 0].copy(), r.J0N, r.JN0, r.cos_bottom)


def lobe_statistics(stack: Stack, cos_theta: float, options: BelcourOptions | None = None,
                    **kwargs) -> list[tuple[np.ndarray, np.ndarray]]:
    """``[(energy_rgb, alpha_rgb), ...]``, one pair per interface (top first), at ``cos_theta``.

    ``alpha`` is ``f^-1`` of the lobe variance, per channel (equal channels with
    ``per_channel=False``), not clamped. See :func:`stack_statistics` for everything else.
    """
    s = stack_statistics(stack, cos_theta, options, **kwargs)
    return [(lobe.energy, lobe.alpha) for lobe in s.lobes]


# --------------------------------------------------------------------------- models

class BelcourModel(Model):
    """Machinery shared by the Belcour models (here and :class:`models.belcour.aniso.BelcourAniso`):
    options (``options_type(**options)``), support, per-instance memos of packed stacks and
    statistics grids, and the reflection evaluation. ``anisotropic`` (class attribute) selects the
    covariance form of :func:`pack_stack`; :meth:`_evaluate` is the forward model (statistics at
    ``omega_i`` = ``l`` or ``v`` as ``options.incident``; lobe 0 the exact top BRDF if ``top_exact``)."""

    options_type: type = BelcourOptions
    top_exact: bool = False

    def __init__(self, **options) -> None:
        if options.get("cache_dir") is not None:
            options["cache_dir"] = os.fspath(options["cache_dir"])
        self.options = self.options_type(**options)
        self._packed: dict[Stack, PackedStack] = {}
        self._grids: dict[Stack, np.ndarray] = {}

    def support_reason(self, stack: Stack) -> str | None:
        return unsupported_reason(stack, self.anisotropic)

    def packed(self, stack: Stack) -> PackedStack:
        """The packed form of ``stack`` (memoised per model instance)."""
        p = self._packed.get(stack)
        if p is None:
            p = pack_stack(stack, self.options, self.anisotropic)
            self._packed[stack] = p
        return p

    def azimuth_nodes(self, packed: PackedStack) -> int:
        """Azimuth nodes of the statistics grid of a packed stack (1: isotropic statistics)."""
        return 1

    def _grid(self, stack: Stack) -> np.ndarray:
        """The :func:`_stats_grid` table of ``stack`` (memoised per stack)."""
        g = self._grids.get(stack)
        if g is None:
            p = self.packed(stack)
            o = self.options
            g = _stats_grid(o.direction_grid, self.azimuth_nodes(p), p.n_lobes, p.kernel_args(), o.per_channel,
                            o.use_tir, o.transmission_scale == "angular")
            self._grids[stack] = g
        return g

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
            r = run_adding_doubling(p, float(l[2]), o, unit_azimuth(float(l[0]), float(l[1])))
            P = np.zeros((p.n_lobes, 3, 5))
            _lobe_params(r.energy, r.covariance, P, float(l[0]), float(l[1]), float(l[2]), 1 if top_exact else 0)
            _eval_fixed(l, vv, 1.0, r.energy, P, o.height_correlated, top_exact, top_alpha, p.top_eta, p.top_kappa,
                        top, internal)
        elif o.direction_grid > 0:
            _eval_grid(l, vv, mode, self._grid(stack), o.height_correlated, top_exact, top_alpha, p.top_eta,
                       p.top_kappa, top, internal)
        else:
            _eval_dynamic(l, vv, mode, p.n_lobes, p.kernel_args(), o.per_channel, o.use_tir,
                          o.transmission_scale == "angular", o.height_correlated, top_exact, top_alpha,
                          p.top_eta, p.top_kappa, top, internal)
        return ModelValue(top.reshape(shape + (3,)), internal.reshape(shape + (3,)))

    def _evaluate(self, stack: Stack, l: np.ndarray, v: np.ndarray, side: str) -> ModelValue:
        mode = MODE_LIGHT if self.options.incident == "light" else MODE_VIEW
        return self._reflection(stack, l, v, mode, self.top_exact)


class _BelcourBase(BelcourModel):
    """The isotropic models: scalar variances, :func:`lobe_statistics` with the model's options."""

    def lobe_statistics(self, stack: Stack, cos_theta: float) -> list[tuple[np.ndarray, np.ndarray]]:
        """:func:`lobe_statistics` with this model's options."""
        return lobe_statistics(stack, cos_theta, self.options)


class _ForwardBase(_BelcourBase):
    """The constructor of the isotropic forward models."""

    def __init__(self, incident: str = "light", use_tir: bool = False, transmission_scale: str = "normal",
                 per_channel: bool = True, height_correlated: bool = False, fgd_source: str = "material",
                 cache_dir: str | os.PathLike | None = None, direction_grid: int = DIRECTION_GRID) -> None:
        super().__init__(incident=incident, use_tir=use_tir, transmission_scale=transmission_scale,
                         per_channel=per_channel, height_correlated=height_correlated, fgd_source=fgd_source,
                         cache_dir=cache_dir, direction_grid=direction_grid)


class BelcourForward(_ForwardBase):
    """Belcour 2018, forward model (statistics for the incident direction; not reciprocal)."""

    name = "belcour-fwd"
    description = "Belcour 2018 forward model: GGX lobes from adding-doubling of statistics at omega_i.n"
    sides = ("brdf",)


class BelcourSymmetric(_BelcourBase):
    """Belcour 2018, symmetric model: statistics for c = |l.h| (reciprocal)."""

    name = "belcour-sym"
    description = "Belcour 2018 symmetric model: statistics from the half vector (reciprocal)"
    sides = ("brdf",)

    def __init__(self, use_tir: bool = False, transmission_scale: str = "normal", per_channel: bool = True,
                 height_correlated: bool = False, fgd_source: str = "material",
                 cache_dir: str | os.PathLike | None = None, direction_grid: int = DIRECTION_GRID) -> None:
        super().__init__(use_tir=use_tir, transmission_scale=transmission_scale, per_channel=per_channel,
                         height_correlated=height_correlated, fgd_source=fgd_source, cache_dir=cache_dir,
                         direction_grid=direction_grid)

    def _evaluate(self, stack: Stack, l: np.ndarray, v: np.ndarray, side: str) -> ModelValue:
        return self._reflection(stack, l, v, MODE_HALF, top_exact=False)


class BelcourBati19(_ForwardBase):
    """Bati 2019 eq. 6: exact top-interface microfacet BRDF + Belcour forward lobes k >= 1."""

    name = "belcour-bati19"
    description = "Belcour forward model with lobe 0 replaced by the exact top-interface BRDF (Bati 2019 eq. 6)"
    sides = ("brdf",)
    top_exact = True


class BelcourBTDF(_BelcourBase):
    """Belcour 2018 forward BTDF of slabs (``layered_dielectric``): one transmission lobe."""

    name = "belcour-btdf"
    description = "Belcour 2018 forward BTDF for slabs: one GGX lobe about the Snell direction"
    sides = ("btdf",)

    def __init__(self, use_tir: bool = False, transmission_scale: str = "normal", per_channel: bool = True,
                 height_correlated: bool = False, fgd_source: str = "material",
                 cache_dir: str | os.PathLike | None = None) -> None:
        super().__init__(use_tir=use_tir, transmission_scale=transmission_scale, per_channel=per_channel,
                         height_correlated=height_correlated, fgd_source=fgd_source, cache_dir=cache_dir)

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
        r = run_adding_doubling(self.packed(stack), cos_theta, self.options)
        alpha = np.array([variance_to_roughness(x) for x in r.cov_T0N[:, 0]])
        return r.T0N, alpha, r.cos_bottom

    def _evaluate(self, stack: Stack, l: np.ndarray, v: np.ndarray, side: str) -> ModelValue:
        p = self.packed(stack)
        shape = v.shape[:-1]
        vv = np.ascontiguousarray(v.reshape(-1, 3), dtype=np.float64)
        out = np.zeros((vv.shape[0], 3))
        zero = np.zeros_like(out)
        if l[2] > 0.0:
            r = run_adding_doubling(p, float(l[2]), self.options)
            T, c_n = r.T0N, r.cos_bottom
            # Snell with the mean index through the whole stack (air above): the exit direction is
            # w_t = (-l_x / eta_N, -l_y / eta_N, -cos_N); the fake incident direction is its mirror.
            if c_n > 0.0 and np.any(T > 0.0):
                wi = np.array([l[0] / p.eta_exit, l[1] / p.eta_exit, c_n])
                wi /= np.linalg.norm(wi)
                # one lobe of energy T0N and variance vT0N (roughness clamped as every lobe)
                E = np.maximum(T, 0.0)[None, :]
                P = np.zeros((1, 3, 5))
                _lobe_params(E, r.cov_T0N[None], P, float(wi[0]), float(wi[1]), float(wi[2]), 0)
                # the mirror trick of §8: the lobe about w_t is a reflection lobe about wi for the
                # mirrored views (v_x, v_y, -v_z); lobe 0 goes to ``out``, the other output is the
                # BTDF's zero top part
                _eval_fixed(wi, vv, -1.0, E, P, self.options.height_correlated, False, ALPHA_EVAL_MIN, p.top_eta,
                            p.top_kappa, out, zero)
        return ModelValue(zero.reshape(shape + (3,)), out.reshape(shape + (3,)))
