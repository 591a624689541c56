"""The statistics of the layers above a lobe (alg. 3 of Bati 2021, from Belcour 2018).

A :class:`Context` holds, per colour channel at normal incidence, ``R_0n, T_0n, R_n0, T_n0`` and
their variances for the stack already built, the Jacobian ``J_0n = eta_n / eta_0`` and the
absolute index ``eta_n`` of the current medium; :meth:`Context.with_interface` and
:meth:`Context.with_medium` add layers below it (kernels of :mod:`models.inverse.kernels`),
:meth:`Context.base_stats` gives eqs. 18-19. :func:`scalar_sigma_r` is the achromatic variance
of the next interface (choice 3 of ``docs/inverse.md``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from models.inverse.equations import eq18_scalar
from models.inverse.kernels import (ROW_R0, ROW_RI, ROW_T0, ROW_TI, ROW_VRI, ROW_VT0, ROW_VTI, SCALAR_ETA,
                                    SCALAR_J0, add_interface, add_medium, channel_sigma_r, combine_sigma,
                                    kernel_for)
from models.inverse.lobes import InverseError, InverseOptions, as_rgb, fmt_rgb


@dataclass(frozen=True)
class SubLobe:
    """The forward model's lobe of one interface, as the inverse predicts it (RGB energy, variance)."""

    energy: np.ndarray
    variance: np.ndarray


@dataclass(frozen=True)
class Context:
    """Statistics at normal incidence of the stack above the current medium (alg. 3, Belcour 2018).

    ``state`` rows: R_0n, T_0n, R_n0, T_n0 (energies) and sigma^R_0n, sigma^T_0n, sigma^R_n0,
    sigma^T_n0 (variances), per channel; ``J0``/``Ji`` the variance Jacobians (J_0n = eta_n/eta_0),
    ``eta`` the absolute index of the current medium; ``interfaces`` how many interfaces are above;
    ``absorbing``: whether a medium may be put above the next interface (False only at the top of a
    stack in air, where no layer holds it).
    """

    state: np.ndarray
    scalars: np.ndarray
    interfaces: int = 0
    absorbing: bool = False
    options: InverseOptions = field(default_factory=InverseOptions)

    @classmethod
    def ambient(cls, eta0: float = 1.0, absorbing: bool | None = None,
                options: InverseOptions | None = None) -> "Context":
        """An empty stack in a medium of index ``eta0`` (section 5: a single lobe in medium eta0).
        ``absorbing`` (default: ``eta0 != 1``) allows a coloured ``tau0`` above the lobe."""
        if not (math.isfinite(eta0) and eta0 > 0.0):
            raise InverseError(f"eta0: must be > 0, got {eta0!r}")
        st = np.zeros((8, 3))
        st[ROW_T0] = 1.0
        st[ROW_TI] = 1.0
        sc = np.array([1.0, 1.0, float(eta0)])
        return cls(st, sc, 0, bool(eta0 != 1.0) if absorbing is None else bool(absorbing),
                   options if options is not None else InverseOptions())

    @property
    def eta(self) -> float:
        return float(self.scalars[SCALAR_ETA])

    def row(self, r: int) -> np.ndarray:
        return self.state[r].copy()

    @property
    def R0n(self) -> np.ndarray:
        return self.row(ROW_R0)

    @property
    def T0n(self) -> np.ndarray:
        return self.row(ROW_T0)

    @property
    def Rn0(self) -> np.ndarray:
        return self.row(ROW_RI)

    @property
    def Tn0(self) -> np.ndarray:
        return self.row(ROW_TI)

    @property
    def vT0n(self) -> np.ndarray:
        return self.row(ROW_VT0)

    @property
    def vTn0(self) -> np.ndarray:
        return self.row(ROW_VTI)

    @property
    def vRn0(self) -> np.ndarray:
        return self.row(ROW_VRI)

    @property
    def J0n(self) -> float:
        return float(self.scalars[SCALAR_J0])

    def with_medium(self, tau: Any) -> "Context":
        """The context after an absorbing medium of optical depth ``tau`` (RGB)."""
        t = tau if isinstance(tau, np.ndarray) and tau.shape == (3,) else as_rgb(tau, "tau")
        if t.min() < 0.0:
            raise InverseError(f"tau: must be >= 0, got {fmt_rgb(t)}")
        if not t.max() > 0.0:
            return self
        if not self.absorbing:
            raise InverseError("tau: no medium can lie above the top interface of a stack in air")
        st = self.state.copy()
        add_medium(st, t)
        return replace(self, state=st)

    def with_interface(self, alpha: float, eta: Any, kappa: Any = 0.0) -> tuple["Context", SubLobe]:
        """The context below one more interface (roughness ``alpha``, absolute index ``eta + i kappa``
        of the medium below; kappa > 0 = conductor) and that interface's lobe."""
        w1, xs = kernel_for(self.options)
        e = as_rgb(eta, "eta")
        k = as_rgb(kappa, "kappa")
        conductor = bool(np.any(k > 0.0))
        st = self.state.copy()
        sc = self.scalars.copy()
        out_e = np.empty(3)
        out_v = np.empty(3)
        add_interface(st, sc, w1, xs, float(alpha), e, k, conductor, out_e, out_v)
        return replace(self, state=st, scalars=sc, interfaces=self.interfaces + 1, absorbing=True), \
            SubLobe(out_e, out_v)

    def r_prime(self, R: Any) -> np.ndarray:
        """Eq. 18 per channel: the reflectance the layers below must have, as seen in the current
        medium, for a lobe of energy ``R`` outside (``R`` itself for an empty stack)."""
        r = as_rgb(R, "R")
        return np.array([eq18_scalar(r[c], self.state[ROW_T0, c], self.state[ROW_TI, c], self.state[ROW_RI, c])
                         for c in range(3)])

    def sigma_r(self, R_prime: Any, sigma: float) -> np.ndarray:
        """Eq. 19 per channel: the variance sigma^R_{n,n+l} the layers below must have."""
        rp = as_rgb(R_prime, "R'")
        return np.array([channel_sigma_r(self.state, self.scalars, rp, float(sigma), c) for c in range(3)])

    def base_stats(self, R: Any, sigma: float) -> tuple[np.ndarray, np.ndarray]:
        """Algorithm 3: ``(R'_{n,n+l}, sigma^R_{n,n+l})`` per channel (eqs. 18 and 19)."""
        rp = self.r_prime(R)
        return rp, self.sigma_r(rp, sigma)

    def sigma_min(self, R_prime: Any) -> np.ndarray:
        """The smallest lobe variance reachable below this context (eq. 19 with sigma_R = 0), per channel."""
        rp = as_rgb(R_prime, "R'")
        ri, vti, vt0, vri = self.state[ROW_RI], self.state[ROW_VTI], self.state[ROW_VT0], self.state[ROW_VRI]
        q = ri * rp
        with np.errstate(divide="ignore", invalid="ignore"):
            return vti + self.J0n * (vt0 + np.where(q < 1.0, q / (1.0 - q), np.inf) * vri)


def _variance_channel(rp: np.ndarray) -> int:
    return int(np.argmax(rp))


def scalar_sigma_r(ctx: Context, rp: np.ndarray, sigma: float, options: InverseOptions) -> tuple[float, int]:
    """The achromatic sigma_R of an interface below ``ctx`` (choice 3): eq. 19 on the channel of
    maximal R' ("max"), or the value minimising the largest relative error ("minimax");
    returns it with the channel of maximal R'."""
    ch = _variance_channel(rp)
    per = ctx.sigma_r(rp, sigma)
    q = ctx.state[ROW_RI] * rp
    s = combine_sigma(per, q, ctx.J0n, options.variance_channel == "minimax", ch, np.ones(3, dtype=np.bool_))
    return float(s), ch
