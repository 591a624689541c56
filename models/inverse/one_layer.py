"""Classes of 1-layer lobes (Bati 2021 section 5.1): a dielectric interface or a conductor.

:func:`one_layer_dielectric_class` (section 5.1.1, eq. 7 and its rough version by inverting FGD
at normal incidence; a coloured lobe through ``tau0``) and :func:`conductor_class` (section
5.1.2, eqs. 8-10 on the Fresnel reflectance that gives the FGD target: choice 1 of
``docs/inverse.md``). :func:`conductor_point` and :func:`default_tau` are shared with the
conductor base of 2-layer lobes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import optimize

from models.belcour import variance_to_roughness
from models.inverse.classes import Layer, LobeClass, LobeSolution
from models.inverse.context import Context, scalar_sigma_r
from models.inverse.equations import CONDUCTOR_R_MIN, conductor_eta_bounds, eq8_kappa, eq9_eta_max
from models.inverse.kernels import (FAIL_TEXT, FAIL_TOP_TARGET, ROW_RI, ROW_T0, ROW_TI, albedo_for,
                                    dielectric_roots, fgd_for)
from models.inverse.lobes import InverseError, InverseOptions, Interval, Lobe, Pick, PickError, as_pick, as_rgb, \
    fmt_rgb

#: default conductor reflectance when absorption above it is needed to reach the conductor range
CONDUCTOR_R_FLOOR = 0.2


# ============================================================================ 1-layer dielectric

@dataclass
class OneLayerDielectricClass(LobeClass):
    """Section 5.1.1 / alg. 4: ``eta1`` on the upper (``eta1 > eta_n``) and/or lower branch; on each
    branch ``tau0`` grows from 0 (max channel) at the root to the branch's far end."""

    alpha: float = 0.0
    alpha_lookup: np.ndarray = field(default_factory=lambda: np.zeros(3))
    r_prime: np.ndarray = field(default_factory=lambda: np.zeros(3))
    sigma_r: float = 0.0
    branches: dict[str, Interval] = field(default_factory=dict)

    def tau_at(self, eta1: float) -> np.ndarray:
        r = np.array([fgd_for(self.context.options, a, eta1 / self.context.eta) for a in self.alpha_lookup])
        with np.errstate(divide="ignore"):
            t = 0.5 * np.log(r / self.r_prime)
        return np.where(np.abs(t) < 1e-12, 0.0, t)

    def _branch_eta(self, name: str, u: float) -> float:
        iv = self.branches[name]
        # u = 0 is the tau = 0 root end of the branch
        return iv.lo + u * iv.length if name == "upper" else iv.hi - u * iv.length

    def pick(self, pick: Pick | dict | None = None) -> LobeSolution:
        self._require()
        p = as_pick(pick)
        for bad in ("u2", "eta2", "tau1", "tau0"):
            if getattr(p, bad) is not None:
                what = "follows from eta1 (alg. 4)" if bad == "tau0" else "is for 2-layer lobes"
                raise PickError(f"{bad}: not a choice of a 1-layer dielectric lobe ({what})")
        if p.eta1 is not None:
            e = as_rgb(p.eta1, "eta1")
            if np.ptp(e) != 0.0:
                raise PickError("eta1: a dielectric index is achromatic")
            eta1 = float(e[0])
            name = next((k for k, iv in self.branches.items() if iv.contains(eta1)), None)
            if name is None:
                raise PickError(f"eta1={eta1:g} is outside the class ({self._branch_text()})")
        else:
            name = p.root or ("upper" if "upper" in self.branches else "lower")
            if name not in self.branches:
                raise PickError(f"root={name}: that branch is empty ({self._branch_text()})")
            u = 0.0 if p.u1 is None else float(as_rgb(p.u1, "u1")[0])
            if not self.context.absorbing and u > 0.0:
                raise PickError("u1 > 0 needs a medium above the interface, and the top of the stack has none")
            eta1 = self._branch_eta(name, u)
        tau = np.maximum(self.tau_at(eta1), 0.0) if self.context.absorbing else np.zeros(3)
        ctx = self.context.with_medium(tau) if np.any(tau > 0) else self.context
        ctx2, sub = ctx.with_interface(self.alpha, eta1)
        layer = Layer(tau, self.alpha, np.full(3, eta1), np.zeros(3))
        u_res = (eta1 - self.branches[name].lo) / self.branches[name].length if self.branches[name].length > 0 else 0.0
        if name == "lower":
            u_res = 1.0 - u_res
        return LobeSolution([layer], ctx2, [sub], {"root": name, "u1": u_res, "eta1": eta1, "tau0": tau.tolist()},
                            {"alpha": self.alpha, "r_prime": self.r_prime.tolist(), "sigma_r": self.sigma_r})

    def _branch_text(self) -> str:
        return ", ".join(f"{k}: [{iv.lo:.6g}, {iv.hi:.6g}]" for k, iv in self.branches.items()) or "empty"

    def sample(self, n: int = 64) -> dict[str, np.ndarray]:
        """``eta1`` samples on each branch (a single point per branch at the top of a stack in air)
        with their ``tau0`` (RGB)."""
        if not self.achievable:
            return {"eta1": np.zeros(0), "tau0": np.zeros((0, 3)), "branch": np.zeros(0, dtype=int)}
        etas, taus, br = [], [], []
        for b, (name, iv) in enumerate(self.branches.items()):
            us = np.linspace(0.0, 1.0, n) if self.context.absorbing else np.zeros(1)
            for u in us:
                e = self._branch_eta(name, float(u))
                etas.append(e)
                taus.append(np.maximum(self.tau_at(e), 0.0))
                br.append(b)
        return {"eta1": np.array(etas), "tau0": np.array(taus), "branch": np.array(br)}


def one_layer_dielectric_class(lobe: Lobe, context: Context | None = None) -> OneLayerDielectricClass:
    """The class of a 1-layer dielectric lobe below ``context`` (section 5.1.1, alg. 3-4)."""
    ctx = context if context is not None else Context.ambient()
    o = ctx.options
    R = lobe.rgb
    bounds: dict[str, Any] = {}
    mk = lambda ok, reason, **kw: OneLayerDielectricClass("dielectric-1", lobe, ctx, ok, reason, bounds, **kw)  # noqa: E731
    if not ctx.absorbing and not lobe.achromatic:
        return mk(False, f"a coloured 1-layer dielectric lobe (R={fmt_rgb(R)}) needs an absorbing medium above its "
                         "interface (tau0, section 5.1.1), and the top of a stack in air has none: use layers=2")
    rp = ctx.r_prime(R)
    if np.any(rp >= 1.0) or np.any(rp < 0.0):
        return mk(False, FAIL_TEXT[FAIL_TOP_TARGET] + f" (R'={fmt_rgb(rp)})")
    sigma_r, ch = scalar_sigma_r(ctx, rp, lobe.sigma, o)
    bounds["r_prime"] = rp
    bounds["sigma_r"] = sigma_r
    if sigma_r < 0.0:
        smin = ctx.sigma_min(rp)
        return mk(False, f"sigma={lobe.sigma:g} is below the variance the layers above already add "
                         f"(sigma_min={smin[ch]:.4g}, eq. 19 with sigma_R = 0)")
    alpha = variance_to_roughness(sigma_r)
    vt0 = ctx.vT0n
    at = np.array([variance_to_roughness(v + sigma_r) if v > 0 else alpha for v in vt0])
    bounds["alpha"] = alpha
    # roots per channel; the branch is valid where tau >= 0 in every channel (R >= R' in all channels)
    los, his = [], []
    for c in range(3):
        lo, hi = dielectric_roots(o, at[c], rp[c], ctx.eta, 1.0, o.eta_max)
        los.append(lo)
        his.append(hi)
    branches: dict[str, Interval] = {}
    if all(h is not None for h in his):
        h = max(his)
        if h <= o.eta_max:
            branches["upper"] = Interval(h, o.eta_max if ctx.absorbing else h)
    if all(lv is not None for lv in los) and ctx.eta > 1.0:
        lv = min(los)
        if lv >= 1.0:
            branches["lower"] = Interval(1.0 if ctx.absorbing else lv, lv)
    bounds["eta1"] = {k: v for k, v in branches.items()}
    # the largest energy per channel: eq. 17 with the largest FGD reachable (eta1 = eta_max or 1)
    r_max = np.array([_eq17_scalar(max(fgd_for(o, at[c], o.eta_max / ctx.eta), fgd_for(o, at[c], 1.0 / ctx.eta)),
                                   ctx, c)
                      for c in range(3)])
    bounds["R_max"] = r_max
    if ctx.absorbing:
        bounds["T0"] = [Interval(0.0, 0.5 * math.log(r_max[c] / R[c])) if r_max[c] > R[c] else None
                        for c in range(3)]
    if not branches:
        over = [c for c in range(3) if R[c] > r_max[c] * (1 - 1e-12)]
        which = "" if len(over) in (0, 3) else " in channel(s) " + "".join("RGB"[c] for c in over)
        where = " here (below the layers chosen above)" if ctx.interfaces else ""
        return mk(False, f"R={fmt_rgb(R)} is above the maximum energy of a 1-layer dielectric lobe with "
                         f"eta <= eta_max={o.eta_max:g}{where}{which} (R_max={fmt_rgb(r_max)}; eq. 1/7 at eta_max)",
                  alpha=alpha, alpha_lookup=at, r_prime=rp, sigma_r=sigma_r)
    return mk(True, None, alpha=alpha, alpha_lookup=at, r_prime=rp, sigma_r=sigma_r, branches=branches)


def _eq17_scalar(rp: float, ctx: Context, ch: int) -> float:
    st = ctx.state
    return st[ROW_T0, ch] * rp * st[ROW_TI, ch] / (1.0 - rp * st[ROW_RI, ch])


# ============================================================================ conductors

def conductor_point(o: InverseOptions, alpha_lookup: float, target: float, eta_n: float,
                     u: float | None = None, eta: float | None = None) -> tuple[float, float, float] | str:
    """``(eta, kappa, R_F)`` of a conductor below a medium ``eta_n`` with ``FGD(alpha~, .) = target``,
    at position ``u`` of its class (eqs. 8-10 on the Fresnel reflectance ``R_F``; choice 1), or with
    real part ``eta``. Returns a reason string when impossible."""

    def at_rf(rf: float) -> tuple[float, float]:
        b = conductor_eta_bounds(rf, eta_n)
        assert b is not None
        e = b[0] + u * (b[1] - b[0]) if eta is None else eta
        k = eq8_kappa(rf, e, eta_n)
        return e, k

    def g(rf: float) -> float:
        e, k = at_rf(rf)
        if not math.isfinite(k):
            return -1.0
        return fgd_for(o, alpha_lookup, e / eta_n, k / eta_n) - target

    if target >= albedo_for(o, alpha_lookup):
        return (f"the conductor would need a reflectance {target:.4g} at or above the albedo "
                f"{albedo_for(o, alpha_lookup):.4g} of a perfectly reflecting GGX interface of "
                f"alpha={alpha_lookup:.4g}")
    lo_rf = CONDUCTOR_R_MIN
    if eta is not None:
        # the smallest R_F whose class contains eta: eta <= eta_c_max(R_F) (eq. 9 grows with R_F)
        lo_rf = max(lo_rf, _rf_for_eta_max(eta / eta_n))
    if g(lo_rf) > 0.0:
        return (f"reflectance {target:.4g} is below the darkest conductor (kappa >= eta) "
                f"{'with this eta ' if eta is not None else ''}(R >= 3 - 2 sqrt 2 = {CONDUCTOR_R_MIN:.4f}, eq. 9)")
    hi_rf = 1.0 - 1e-15
    if g(hi_rf) < 0.0:
        return f"reflectance {target:.4g} is not reachable by a rough conductor with alpha={alpha_lookup:.4g}"
    rf = target if alpha_lookup <= 0.0 and lo_rf <= target else optimize.brentq(g, lo_rf, hi_rf, xtol=1e-15, rtol=1e-14)
    e, k = at_rf(rf)
    if eta is not None:
        b = conductor_eta_bounds(rf, eta_n)
        if b is None or not (b[0] - 1e-9 <= eta <= b[1] + 1e-9):
            return (f"eta={eta:g} is outside the conductor class [{b[0]:.6g}, {b[1]:.6g}] for this reflectance "
                    "(eqs. 9-10)" if b else "no conductor")
    return e, k, rf


def _rf_for_eta_max(x: float) -> float:
    """Smallest R with eq9(R) >= x (relative index), i.e. the conductor class reaches eta = x eta_n."""
    if x <= eq9_eta_max(CONDUCTOR_R_MIN):
        return CONDUCTOR_R_MIN
    return optimize.brentq(lambda r: eq9_eta_max(r) - x, CONDUCTOR_R_MIN, 1.0 - 1e-15, xtol=1e-15)


def default_tau(rp: np.ndarray, absorbing: bool) -> np.ndarray:
    """Choice 6: no absorption unless the conductor would be darker than 3 - 2 sqrt 2; then the
    smallest tau bringing it to CONDUCTOR_R_FLOOR."""
    if not absorbing:
        return np.zeros(3)
    with np.errstate(divide="ignore"):
        return np.where(rp < CONDUCTOR_R_MIN, 0.5 * np.log(CONDUCTOR_R_FLOOR / np.maximum(rp, 1e-300)), 0.0)


@dataclass
class ConductorClass(LobeClass):
    """Section 5.1.2: per channel, ``eta1`` in ``[eta_c_min, eta_c_max]`` (eqs. 9-10) and ``kappa1``
    from eq. 8 (on the Fresnel reflectance giving the FGD target, choice 1), below a medium of
    optical depth ``tau0``."""

    alpha: float = 0.0
    alpha_lookup: np.ndarray = field(default_factory=lambda: np.zeros(3))
    r_prime: np.ndarray = field(default_factory=lambda: np.zeros(3))
    sigma_r: float = 0.0
    tau0: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def targets(self) -> np.ndarray:
        return self.r_prime * np.exp(2.0 * self.tau0)

    def pick(self, pick: Pick | dict | None = None) -> LobeSolution:
        self._require()
        p = as_pick(pick)
        for bad in ("u2", "eta2", "tau1", "root"):
            if getattr(p, bad) is not None:
                raise PickError(f"{bad}: not a choice of a 1-layer conductor lobe")
        if p.tau0 is not None and not np.allclose(as_rgb(p.tau0, "tau0"), self.tau0):
            raise PickError("tau0: the class was built for another tau0 (pass it to the class function)")
        u = as_rgb(0.5 if p.u1 is None else p.u1, "u1")
        etas = None if p.eta1 is None else as_rgb(p.eta1, "eta1")
        eta, kap, rfs = np.empty(3), np.empty(3), np.empty(3)
        tgt = self.targets()
        for c in range(3):
            r = conductor_point(self.context.options, self.alpha_lookup[c], tgt[c], self.context.eta,
                                 u=float(u[c]), eta=None if etas is None else float(etas[c]))
            if isinstance(r, str):
                raise PickError(f"channel {'RGB'[c]}: {r}")
            eta[c], kap[c], rfs[c] = r
        ctx = self.context.with_medium(self.tau0)
        ctx2, sub = ctx.with_interface(self.alpha, eta, kap)
        layer = Layer(self.tau0.copy(), self.alpha, eta, kap)
        us = []
        for c in range(3):
            b = conductor_eta_bounds(rfs[c], self.context.eta)
            us.append((eta[c] - b[0]) / (b[1] - b[0]) if b and b[1] > b[0] else 0.0)
        return LobeSolution([layer], ctx2, [sub], {"u1": us, "eta1": eta.tolist(), "tau0": self.tau0.tolist()},
                            {"alpha": self.alpha, "kappa1": kap.tolist(), "R_fresnel": rfs.tolist(),
                             "r_prime": self.r_prime.tolist(), "sigma_r": self.sigma_r})

    def sample(self, n: int = 64) -> dict[str, np.ndarray]:
        """Per channel: ``eta1``, ``kappa1`` (n, 3) along the class (u from 0 to 1)."""
        if not self.achievable:
            return {"u": np.zeros(0), "eta1": np.zeros((0, 3)), "kappa1": np.zeros((0, 3))}
        us = np.linspace(0.0, 1.0, n)
        eta = np.full((n, 3), np.nan)
        kap = np.full((n, 3), np.nan)
        tgt = self.targets()
        for c in range(3):
            for i, u in enumerate(us):
                r = conductor_point(self.context.options, self.alpha_lookup[c], tgt[c], self.context.eta, u=float(u))
                if not isinstance(r, str):
                    eta[i, c], kap[i, c] = r[0], r[1]
        return {"u": us, "eta1": eta, "kappa1": kap}


def conductor_class(lobe: Lobe, context: Context | None = None, tau0: Any = None) -> ConductorClass:
    """The class of a 1-layer conductor lobe below ``context`` (section 5.1.2, alg. 3-4), under a
    medium of optical depth ``tau0`` (default: choice 6)."""
    ctx = context if context is not None else Context.ambient()
    o = ctx.options
    R = lobe.rgb
    bounds: dict[str, Any] = {}
    mk = lambda ok, reason, **kw: ConductorClass("conductor-1", lobe, ctx, ok, reason, bounds, **kw)  # noqa: E731
    rp = ctx.r_prime(R)
    bounds["r_prime"] = rp
    if np.any(rp >= 1.0) or np.any(rp <= 0.0):
        return mk(False, FAIL_TEXT[FAIL_TOP_TARGET] + f" (R'={fmt_rgb(rp)})" if np.any(rp >= 1.0)
                  else "a conductor reflects in every channel (R > 0)")
    if tau0 is None:
        t0 = default_tau(rp, ctx.absorbing)
    else:
        t0 = as_rgb(tau0, "tau0")
        if np.any(t0 < 0):
            raise InverseError("tau0: must be >= 0")
        if np.any(t0 > 0) and not ctx.absorbing:
            return mk(False, "tau0 > 0 needs a medium above the interface, and the top of a stack in air has none")
    bounds["tau0"] = t0
    sigma_r, ch = scalar_sigma_r(ctx, rp, lobe.sigma, o)
    bounds["sigma_r"] = sigma_r
    if sigma_r < 0.0:
        smin = ctx.sigma_min(rp)
        return mk(False, f"sigma={lobe.sigma:g} is below the variance the layers above already add "
                         f"(sigma_min={smin[ch]:.4g}, eq. 19 with sigma_R = 0)")
    alpha = variance_to_roughness(sigma_r)
    at = np.array([variance_to_roughness(v + sigma_r) if v > 0 else alpha for v in ctx.vT0n])
    bounds["alpha"] = alpha
    tgt = rp * np.exp(2.0 * t0)
    bounds["R_conductor"] = tgt
    classes = []
    for c in range(3):
        r = conductor_point(o, at[c], tgt[c], ctx.eta, u=0.5)
        if isinstance(r, str):
            extra = ""
            if not ctx.absorbing and tgt[c] < CONDUCTOR_R_MIN * 1.05:
                extra = " at the top of a stack in air (no medium above to absorb)"
            return mk(False, f"channel {'RGB'[c]} (R={R[c]:.4g}): {r}{extra}", alpha=alpha, alpha_lookup=at,
                      r_prime=rp, sigma_r=sigma_r, tau0=t0)
        b = conductor_eta_bounds(r[2], ctx.eta)
        classes.append(Interval(*b))
    bounds["eta1"] = classes
    return mk(True, None, alpha=alpha, alpha_lookup=at, r_prime=rp, sigma_r=sigma_r, tau0=t0)
