"""A stack flattened into the arrays the Belcour kernels read (:class:`BelcourPackedStack`,
:func:`pack_stack`), with the FGD (and TIR) slices of its interfaces (:mod:`models.tables.belcour`).

Entries are the stack's layers, top first; indices are relative to the medium above the interface
(``eta = n_interface / n_above``). (Co)variances have ``nq = 1`` entry (a scalar variance) or ``nq = 3``,
``(xx, xy, yy)`` in the macro tangent plane (``anisotropic=True``); ``docs/belcour.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from goniometer.stack import Interface, Lambertian, Medium, Stack
from models._jit import njit
from models.belcour.covariance import lobe_covariance, transmission_roughness
from models.belcour.options import BelcourOptions
from models.tables import belcour as tables

KIND_DIELECTRIC = 0
KIND_CONDUCTOR = 1
KIND_MEDIUM = 2


@dataclass(frozen=True)
class BelcourPackedStack:
    """Flat arrays the kernels read; one entry per interface or medium, top first.

    * ``kind`` (KIND_*), ``alpha`` (interface roughness; along the tangent x axis), ``alpha_y``
      (along the tangent y axis), ``rot`` = (cos, sin) of the tangent-frame rotation, ``iso``
      (isotropic interface or medium);
    * ``cov_r``, ``cov_t_down``, ``cov_t_up`` (ne, nq): the (co)variances of reflection and of the
      normal-incidence transmission down and up, ``f(alpha)``, ``f(s_down alpha)``, ``f(s_up alpha)``
      (:func:`transmission_roughness`): one column (scalar variances) or three, ``(xx, xy, yy)``
      (:func:`lobe_covariance`; zeros for media);
    * ``n_mean``: mean relative index (Snell, s and J; 1 for conductors and media);
    * ``tau``: RGB (extinction) optical depth of media; ``tau_s``: their RGB scattering optical
      depth ``scattering_albedo * tau`` (sigma_s d); ``var_s``: the forward-scattering variance
      ``sigma_HG(g)`` of each medium per channel (0 in a channel that does not scatter,
      :func:`forward_scattering_variance`); ``eta_up``: TIR index ratio across the interface above
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
    tau_s: np.ndarray
    var_s: np.ndarray
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
                self.fgd_upper, self.tir_split, self.tir_lower, self.tir_upper, self.tau_s, self.var_s)


#: smallest Henyey-Greenstein asymmetry of a scattering medium the Belcour models accept: sigma_HG(g)
#: diverges at g = 0 (and is undefined below); at g = 0.1 its lobe roughness is already 0.85
#: (``docs/belcour.md``, "Scattering media")
G_MIN = 0.1


def forward_scattering_variance(g: float) -> float:
    """Belcour 2018's forward-scattering variance of a Henyey-Greenstein medium,
    ``sigma_HG(g) = ((1 - g) / g)^0.8 / (1 + g)`` (reference code; defined for 0 < g < 1)."""
    if not 0.0 < g < 1.0:
        raise ValueError(f"sigma_HG(g) is defined for 0 < g < 1, got g = {g!r}")
    return ((1.0 - g) / g) ** 0.8 / (1.0 + g)


def forward_scattering_reason(stack: Stack) -> str | None:
    """Why Belcour's forward-scattering operator cannot represent a scattering medium of ``stack``
    (None if every scattering medium has ``g >= G_MIN``)."""
    for i, x in enumerate(stack.layers):
        if isinstance(x, Medium) and x.scatters and not x.g >= G_MIN:
            return (f"Belcour's forward-scattering operator needs g >= {G_MIN} (sigma_HG(g) diverges at g = 0; "
                    f"layers[{i}] is a scattering medium with g = {x.g})")
    return None


def unsupported_reason(stack: Stack, anisotropic: bool = False) -> str | None:
    """Why Belcour's model cannot represent ``stack`` (None if it can); anisotropic interfaces are
    refused unless ``anisotropic`` (the covariance form of ``belcour-aniso``); scattering media need
    ``g >= G_MIN`` (:func:`forward_scattering_reason`)."""
    if any(isinstance(x, Lambertian) for x in stack.layers):
        return "Belcour's model cannot represent a Lambertian base (it only sums GGX lobes)"
    if not stack.interfaces:
        return "the stack has no interface"
    if not anisotropic and any(getattr(x, "is_anisotropic", False) for x in stack.interfaces):
        return "Belcour's model is isotropic: it cannot represent an anisotropic interface"
    return forward_scattering_reason(stack)


def _pad(a: np.ndarray, rows: int) -> np.ndarray:
    out = np.zeros((rows, a.shape[1]))
    out[: a.shape[0]] = a
    return out


def pack_stack(stack: Stack, options: BelcourOptions = BelcourOptions(),
               anisotropic: bool = False) -> BelcourPackedStack:
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
    tabs = tables.load_belcour_tables(options.cache_dir, hc) if options.fgd_source == "table" else None

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
    tau_s = np.zeros((ne, 3))
    var_s = np.zeros((ne, 3))
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
            if layer.scatters:
                v = forward_scattering_variance(layer.g)
                for ch in range(3):
                    tau_s[e, ch] = layer.scattering_albedo[ch] * layer.optical_depth[ch]
                    var_s[e, ch] = v if tau_s[e, ch] > 0.0 else 0.0
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
        x_down, x_up = transmission_roughness(alpha[e], n_mean[e], 1.0, 1.0, False)
        y_down, y_up = transmission_roughness(alpha_y[e], n_mean[e], 1.0, 1.0, False)
        cov_r[e] = lobe_covariance(alpha[e], alpha_y[e], c, s, iso[e])[:nq]
        cov_t_down[e] = lobe_covariance(x_down, y_down, c, s, iso[e])[:nq]
        cov_t_up[e] = lobe_covariance(x_up, y_up, c, s, iso[e])[:nq]
    return BelcourPackedStack(kind, alpha, alpha_y, rot, iso, cov_r, cov_t_down, cov_t_up, n_mean, tau, tau_s, var_s,
                              eta_up,
                              achromatic, fgd_split, fgd_lower, fgd_upper, tir_split, tir_lower, tir_upper, n_if,
                              n_cur, top_eta, top_kappa)


@njit(cache=True, inline="always")
def kernel_n_cov(stack) -> int:
    """Entries per (co)variance of a :meth:`BelcourPackedStack.kernel_args` tuple (the columns of ``cov_r``)."""
    return stack[5].shape[1]
