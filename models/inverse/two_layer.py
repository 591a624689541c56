"""Classes of 2-layer lobes (Bati 2021 section 5.2): alg. 1 for the top lobe, alg. 5 when stacked.

The predicate of a first index ``eta1`` (compiled: eq. 19 for the first interface, eq. 20 and
eq. 18 for the second interface's target, eq. 19 for its variance, then N2 or the conductor
base) is scanned over ``[1, eta_max]`` to find N1 (eq. 12; choice 5 of ``docs/inverse.md``);
:class:`TwoLayerClass` then gives N2 (eq. 14) and ``tau1`` (eq. 13) at a chosen ``eta1``, or a
conductor base of equivalent index (section 5.2.4). :func:`two_layer_energy_max` bounds the
energy (T0, eq. 16; choice 8).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Sequence

import numpy as np

from models._jit import njit
from models.belcour import variance_to_roughness
from models.inverse.classes import Layer, LobeClass, LobeSolution
from models.inverse.context import Context, SubLobe, scalar_sigma_r
from models.inverse.equations import conductor_eta_bounds, eq18_scalar, eq19_scalar, eta_sigma_max
from models.inverse.kernels import (FAIL_BOTTOM_ENERGY, FAIL_BOTTOM_VARIANCE, FAIL_CONDUCTOR, FAIL_NO_ETA2,
                                    FAIL_TEXT, FAIL_TOP_ENERGY, FAIL_TOP_TARGET, FAIL_TOP_VARIANCE, OK, ROW_RI,
                                    ROW_T0, ROW_TI, ROW_VRI, ROW_VT0, ROW_VTI, SCALAR_ETA, SCALAR_J0, add_interface,
                                    albedo_normal, channel_sigma_r, combine_sigma, dielectric_roots, fgd_for,
                                    fgd_normal, kernel_for)
from models.inverse.lobes import InverseError, Interval, Lobe, Pick, PickError, as_pick, as_rgb, fmt_rgb
from models.inverse.one_layer import conductor_point, default_tau

#: eta1 samples of the fallback N1 scan (choice 5 of docs/inverse.md)
N_SCAN_FALLBACK = 1024
#: bisection tolerance on eta boundaries
ETA_TOL = 1e-10


# ============================================================================ the 2-layer predicate (compiled)

@njit(cache=True)
def _two_layer_eval(st, sc, w1, xs, rk, sigma, eta1, eta_max, conductor, exact, ch_top, vr_top_paper,
                    minimax, st1, sc1, sub, bot) -> int:
    """The 2-layer predicate at ``eta1`` (alg. 1 / alg. 5 up to N2).

    ``st, sc``: context at the lobe's top (medium tau0 included). Writes the context below the
    first interface into ``st1, sc1``; ``sub = (E1 rgb, v1 rgb, sigma_R1)`` the first interface's
    lobe; ``bot = (R'_b rgb, sigma_R2, alpha~2 rgb, alpha2)`` the second interface's target.
    Returns OK or a FAIL_* code.
    """
    zero = np.zeros(3)
    eta = np.full(3, eta1)
    e1 = np.empty(3)
    v1 = np.empty(3)
    vr = vr_top_paper
    if vr < 0.0:
        return FAIL_TOP_VARIANCE
    use = np.ones(3, dtype=np.bool_)
    if exact and st[ROW_RI, ch_top] > 0.0:
        # choice 2: eq. 19 with the first interface's own R' (fixed point; R' depends on alpha via FGD)
        per = np.empty(3)
        q = np.empty(3)
        for it in range(50):
            for c in range(3):
                at = variance_to_roughness(st[ROW_VT0, c] + vr) if st[ROW_VT0, c] > 0.0 else variance_to_roughness(vr)
                r1 = fgd_normal(w1, xs, at, eta1 / sc[SCALAR_ETA], 0.0)
                per[c] = eq19_scalar(sigma, r1, st[ROW_RI, c], st[ROW_VTI, c], st[ROW_VT0, c], st[ROW_VRI, c],
                                     sc[SCALAR_J0])
                q[c] = st[ROW_RI, c] * r1
            vr_new = combine_sigma(per, q, sc[SCALAR_J0], minimax, ch_top, use)
            if vr_new < 0.0:
                return FAIL_TOP_VARIANCE
            done = abs(vr_new - vr) <= 1e-15 * max(1.0, vr)
            vr = vr_new
            if done:
                break
    st1[:, :] = st
    sc1[:] = sc
    add_interface(st1, sc1, w1, xs, variance_to_roughness(vr), eta, zero, False, e1, v1)
    for ch in range(3):
        sub[ch] = e1[ch]
        sub[3 + ch] = v1[ch]
    sub[6] = vr
    # eq. 20: the second interface's target energy, then eq. 18 below the first interface
    rb = np.empty(3)
    for ch in range(3):
        rbar = rk[ch] - e1[ch]
        if rbar <= 0.0:
            return FAIL_TOP_ENERGY
        rb[ch] = eq18_scalar(rbar, st1[ROW_T0, ch], st1[ROW_TI, ch], st1[ROW_RI, ch])
        bot[ch] = rb[ch]
        if rb[ch] >= 1.0:
            return FAIL_BOTTOM_ENERGY
    cb = 0
    for ch in range(1, 3):
        if rb[ch] > rb[cb]:
            cb = ch
    per2 = np.empty(3)
    q2 = np.empty(3)
    for c in range(3):
        per2[c] = channel_sigma_r(st1, sc1, rb, sigma, c)
        q2[c] = st1[ROW_RI, c] * rb[c]
    s2 = combine_sigma(per2, q2, sc1[SCALAR_J0], minimax, cb, use)
    bot[3] = s2
    if s2 < 0.0:
        return FAIL_BOTTOM_VARIANCE
    a2 = variance_to_roughness(s2)
    bot[7] = a2
    for ch in range(3):
        bot[4 + ch] = variance_to_roughness(st1[ROW_VT0, ch] + s2) if st1[ROW_VT0, ch] > 0.0 else a2
    if conductor:
        for ch in range(3):
            if rb[ch] >= albedo_normal(w1, bot[4 + ch]):
                return FAIL_CONDUCTOR
        return OK
    # N2 non-empty: the extreme eta2 (1 or eta_max) works for every channel (FGD grows away from eta1)
    for e2 in (1.0, eta_max):
        good = True
        for ch in range(3):
            if fgd_normal(w1, xs, bot[4 + ch], e2 / eta1, 0.0) < rb[ch]:
                good = False
                break
        if good:
            return OK
    return FAIL_NO_ETA2


@njit(cache=True)
def _two_layer_scan(st, sc, w1, xs, rk, sigma, etas, eta_max, conductor, exact, ch_top, vr_top_paper, minimax,
                    status):
    """:func:`_two_layer_eval` at every ``etas[i]`` (statuses into ``status``)."""
    st1 = np.empty_like(st)
    sc1 = np.empty_like(sc)
    sub = np.empty(7)
    bot = np.empty(8)
    for i in range(etas.shape[0]):
        status[i] = _two_layer_eval(st, sc, w1, xs, rk, sigma, etas[i], eta_max, conductor, exact, ch_top,
                                    vr_top_paper, minimax, st1, sc1, sub, bot)


# ============================================================================ intervals

def _bisect(pred, good: float, bad: float, tol: float = ETA_TOL) -> float:
    """The boundary between ``good`` (pred True) and ``bad`` (pred False), returned on the good side."""
    for _ in range(200):
        if abs(bad - good) <= tol:
            break
        mid = 0.5 * (good + bad)
        if pred(mid):
            good = mid
        else:
            bad = mid
    return good


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Maximal runs [i, j] (inclusive) of True in a boolean array."""
    out = []
    i = 0
    n = mask.shape[0]
    while i < n:
        if mask[i]:
            j = i
            while j + 1 < n and mask[j + 1]:
                j += 1
            out.append((i, j))
            i = j + 1
        else:
            i += 1
    return out


def _position(intervals: Sequence[Interval], u: float) -> float:
    """The point at fraction ``u`` of the total length of a union of disjoint sorted intervals."""
    total = sum(iv.length for iv in intervals)
    if total <= 0.0:
        return intervals[0].lo
    target = u * total
    for iv in intervals:
        if target <= iv.length or iv is intervals[-1]:
            return min(iv.lo + target, iv.hi)
        target -= iv.length
    return intervals[-1].hi  # pragma: no cover


def _fraction(intervals: Sequence[Interval], x: float) -> float:
    """Inverse of :func:`_position` (the position of ``x``; NaN if outside)."""
    total = sum(iv.length for iv in intervals)
    acc = 0.0
    for iv in intervals:
        if iv.contains(x):
            return (acc + min(max(x - iv.lo, 0.0), iv.length)) / total if total > 0 else 0.0
        acc += iv.length
    return float("nan")


# ============================================================================ 2-layer classes

@dataclass
class TwoLayerPoint:
    """The second-interface problem at one ``eta1`` (alg. 1 inner loop / alg. 5)."""

    status: int
    eta1: float
    alpha1: float
    context1: Context | None
    sub1: SubLobe | None
    r_prime: np.ndarray          # R'_b per channel (eq. 11 / 18)
    sigma_r: float               # sigma_R12 (eq. 15 / 19)
    alpha2: float
    alpha_lookup: np.ndarray     # alpha'_2 per channel
    n2: list[Interval] = field(default_factory=list)


@dataclass
class TwoLayerClass(LobeClass):
    """Section 5.2 / alg. 1 (top lobe) and alg. 5 (stacked): ``eta1 in N1`` (eq. 12), then
    ``eta2 in N2(eta1)`` (eq. 14, dielectric base) with ``tau1`` from eq. 13, or a conductor base of
    equivalent index (5.2.4) with ``tau1`` free and the complex index on its class."""

    conductor: bool = False
    tau0: np.ndarray = field(default_factory=lambda: np.zeros(3))
    n1: list[Interval] = field(default_factory=list)
    eta_sigma_max: float = math.inf
    ch_top: int = 0
    vr_top_paper: float = 0.0
    top_context: Context | None = None
    scan_status: dict[int, int] = field(default_factory=dict)

    # ---- the inner problem at one eta1
    def at(self, eta1: float) -> TwoLayerPoint:
        ctx = self.top_context
        assert ctx is not None
        o = ctx.options
        w1, xs = kernel_for(o)
        st1 = np.empty_like(ctx.state)
        sc1 = np.empty_like(ctx.scalars)
        sub = np.empty(7)
        bot = np.full(8, np.nan)
        status = _two_layer_eval(ctx.state, ctx.scalars, w1, xs, self.lobe.rgb, self.lobe.sigma, float(eta1),
                                 o.eta_max, self.conductor, o.top_variance == "exact", self.ch_top,
                                 self.vr_top_paper, o.variance_channel == "minimax", st1, sc1, sub, bot)
        if status in (FAIL_TOP_VARIANCE,):
            return TwoLayerPoint(status, eta1, float("nan"), None, None, bot[:3], bot[3], bot[7], bot[4:7])
        c1 = replace(ctx, state=st1, scalars=sc1, interfaces=ctx.interfaces + 1, absorbing=True)
        s1 = SubLobe(sub[:3].copy(), sub[3:6].copy())
        alpha1 = variance_to_roughness(sub[6])
        pt = TwoLayerPoint(status, eta1, alpha1, c1, s1, bot[:3].copy(), float(bot[3]), float(bot[7]), bot[4:7].copy())
        if status != OK:
            return pt
        if not self.conductor:
            los, his = [], []
            for c in range(3):
                lo, hi = dielectric_roots(o, pt.alpha_lookup[c], pt.r_prime[c], eta1, 1.0, o.eta_max)
                los.append(lo)
                his.append(hi)
            n2 = []
            if all(v is not None for v in los) and min(los) >= 1.0 and eta1 > 1.0:
                n2.append(Interval(1.0, min(los)))
            if all(v is not None for v in his) and max(his) <= o.eta_max:
                n2.append(Interval(max(his), o.eta_max))
            if not n2:
                pt.status = FAIL_NO_ETA2
            pt.n2 = n2
        return pt

    def tau1_at(self, pt: TwoLayerPoint, eta2: float) -> np.ndarray:
        o = self.context.options
        r = np.array([fgd_for(o, a, eta2 / pt.eta1) for a in pt.alpha_lookup])
        with np.errstate(divide="ignore"):
            t = 0.5 * np.log(r / pt.r_prime)
        return np.where(np.abs(t) < 1e-12, 0.0, t)

    # ---- choices
    def _eta1(self, p: Pick) -> float:
        if p.eta1 is not None:
            e = as_rgb(p.eta1, "eta1")
            if np.ptp(e) != 0.0:
                raise PickError("eta1: a dielectric index is achromatic")
            eta1 = float(e[0])
            if not any(iv.contains(eta1) for iv in self.n1):
                raise PickError(f"eta1={eta1:g} is outside N1 = {_intervals_text(self.n1)}")
            return eta1
        u = 0.5 if p.u1 is None else (float(p.u1) if isinstance(p.u1, (int, float)) else float(as_rgb(p.u1, "u1")[0]))
        return _position(self.n1, u)

    def pick(self, pick: Pick | dict | None = None) -> LobeSolution:
        self._require()
        p = as_pick(pick)
        if p.root is not None:
            raise PickError("root: not a choice of a 2-layer lobe")
        if p.tau0 is not None and not np.allclose(as_rgb(p.tau0, "tau0"), self.tau0):
            raise PickError("tau0: the class was built for another tau0 (pass it to the class function)")
        eta1 = self._eta1(p)
        pt = self.at(eta1)
        if pt.status != OK:
            # a boundary point can fail by rounding: step inside N1
            iv = next(iv for iv in self.n1 if iv.contains(eta1))
            for frac in (1e-9, 1e-7, 1e-5):
                e2 = min(max(eta1, iv.lo + frac * iv.length), iv.hi - frac * iv.length)
                pt = self.at(e2)
                if pt.status == OK:
                    eta1 = e2
                    break
            else:
                raise PickError(f"eta1={eta1:g}: {FAIL_TEXT.get(pt.status, 'invalid')}")
        o = self.context.options
        top = Layer(self.tau0.copy(), pt.alpha1, np.full(3, eta1), np.zeros(3))
        choices: dict[str, Any] = {"tau0": self.tau0.tolist(), "eta1": eta1, "u1": _fraction(self.n1, eta1)}
        info: dict[str, Any] = {"alpha1": pt.alpha1, "alpha2": pt.alpha2, "r_prime_2": pt.r_prime.tolist(),
                                "sigma_r_2": pt.sigma_r, "N1": [iv.to_list() for iv in self.n1],
                                "eta_sigma_max": self.eta_sigma_max}
        if not self.conductor:
            if p.tau1 is not None:
                raise PickError("tau1: for a 2-layer dielectric lobe tau1 follows from eta2 (eq. 13)")
            if p.eta2 is not None:
                e = as_rgb(p.eta2, "eta2")
                if np.ptp(e) != 0.0:
                    raise PickError("eta2: a dielectric index is achromatic")
                eta2 = float(e[0])
                if not any(iv.contains(eta2) for iv in pt.n2):
                    raise PickError(f"eta2={eta2:g} is outside N2 = {_intervals_text(pt.n2)} (at eta1={eta1:.6g})")
            else:
                u2 = 0.5 if p.u2 is None else (float(p.u2) if isinstance(p.u2, (int, float)) else
                                               float(as_rgb(p.u2, "u2")[0]))
                eta2 = _position(pt.n2, u2)
            tau1 = np.maximum(self.tau1_at(pt, eta2), 0.0)
            bottom = Layer(tau1, pt.alpha2, np.full(3, eta2), np.zeros(3))
            choices.update({"eta2": eta2, "u2": _fraction(pt.n2, eta2), "tau1": tau1.tolist()})
            info["N2"] = [iv.to_list() for iv in pt.n2]
        else:
            tau1 = default_tau(pt.r_prime, True) if p.tau1 is None else as_rgb(p.tau1, "tau1")
            tgt = pt.r_prime * np.exp(2.0 * tau1)
            u2 = as_rgb(0.5 if p.u2 is None else p.u2, "u2")
            etas = None if p.eta2 is None else as_rgb(p.eta2, "eta2")
            eta2, kap2, rfs = np.empty(3), np.empty(3), np.empty(3)
            for c in range(3):
                r = conductor_point(o, pt.alpha_lookup[c], tgt[c], eta1, u=float(u2[c]),
                                     eta=None if etas is None else float(etas[c]))
                if isinstance(r, str):
                    raise PickError(f"conductor base, channel {'RGB'[c]}: {r} (choose tau1 to change its reflectance)")
                eta2[c], kap2[c], rfs[c] = r
            bottom = Layer(tau1.copy(), pt.alpha2, eta2, kap2)
            us = []
            for c in range(3):
                b = conductor_eta_bounds(rfs[c], eta1)
                us.append((eta2[c] - b[0]) / (b[1] - b[0]) if b and b[1] > b[0] else 0.0)
            eq_eta = eta1 * (1.0 + np.sqrt(rfs)) / (1.0 - np.sqrt(rfs))
            choices.update({"tau1": tau1.tolist(), "eta2": eta2.tolist(), "u2": us})
            info.update({"kappa2": kap2.tolist(), "R_fresnel_2": rfs.tolist(), "eta2_equivalent": eq_eta.tolist()})
        c1 = pt.context1.with_medium(bottom.tau) if np.any(bottom.tau > 0) else pt.context1
        c2, sub2 = c1.with_interface(bottom.alpha, bottom.eta, bottom.kappa)
        return LobeSolution([top, bottom], c2, [pt.sub1, sub2], choices, info)

    def T0(self) -> list[Interval | None]:
        """Eq. 16 per channel: the optical depths ``tau0`` above the lobe for which its class is not
        empty, ``1/2 log([R_min, R_max] / R)`` (choice 8: ``R_max`` of an achromatic lobe of the same
        variance found by bisection, ``R_min = 0``; None where even ``tau0 = 0`` is too dark). At
        the top of a stack in air only ``tau0 = 0`` exists. Costs a few dozen class evaluations."""
        R = self.lobe.rgb
        if not self.context.absorbing:
            return [Interval(0.0, 0.0) if self.achievable else None for _ in range(3)]
        r_max = two_layer_energy_max(self.lobe.sigma, self.context, self.conductor)
        if r_max is None:
            return [None, None, None]
        return [Interval(0.0, 0.5 * math.log(r_max / R[c])) if r_max >= R[c] else None for c in range(3)]

    # ---- sampling
    def sample(self, n1: int = 48, n2: int = 48) -> dict[str, np.ndarray]:
        """The sampled class: ``n1`` values of eta1 over N1 (interval ends included) and, for each,
        ``n2`` values of eta2 over N2 (dielectric; with ``tau1`` RGB from eq. 13 and the per-channel
        ``tau1 = 0`` isolines ``eta2_root_lower/upper``), or the ``tau1 >= 0`` range per channel
        (conductor: ``tau1_min``, the equivalent index of the conductor at ``tau1_min``)."""
        if not self.achievable:
            return {"eta1": np.zeros(0)}
        total = sum(iv.length for iv in self.n1)
        e1s: list[float] = []
        for iv in self.n1:
            k = max(2, int(round(n1 * iv.length / total))) if total > 0 else 1
            e1s.extend(np.linspace(iv.lo, iv.hi, k).tolist())
        o = self.context.options
        out: dict[str, list] = {"eta1": [], "alpha1": [], "alpha2": [], "eta2": [], "tau1": [], "root_lower": [],
                                "root_upper": [], "eta1_of_sample": [], "R_prime": []}
        for e1 in e1s:
            pt = self.at(e1)
            if pt.status != OK and not (pt.status == FAIL_NO_ETA2 and not self.conductor):
                continue
            out["eta1"].append(e1)
            out["alpha1"].append(pt.alpha1)
            out["alpha2"].append(pt.alpha2)
            out["R_prime"].append(pt.r_prime)
            lo_c, hi_c = [], []
            for c in range(3):
                lo, hi = dielectric_roots(o, pt.alpha_lookup[c], pt.r_prime[c], e1, 1.0 / 16.0, 16.0)
                lo_c.append(np.nan if lo is None else lo)
                hi_c.append(np.nan if hi is None else hi)
            out["root_lower"].append(lo_c)
            out["root_upper"].append(hi_c)
            if self.conductor or pt.status != OK:
                continue
            tot2 = sum(iv.length for iv in pt.n2)
            for iv in pt.n2:
                k = max(2, int(round(n2 * iv.length / tot2))) if tot2 > 0 else 1
                for e2 in np.linspace(iv.lo, iv.hi, k):
                    out["eta2"].append(e2)
                    out["tau1"].append(np.maximum(self.tau1_at(pt, float(e2)), 0.0))
                    out["eta1_of_sample"].append(e1)
        res = {k: np.array(v) for k, v in out.items()}
        return res


def _intervals_text(ivs: Sequence[Interval]) -> str:
    return " U ".join(f"[{iv.lo:.6g}, {iv.hi:.6g}]" for iv in ivs) if ivs else "{}"


def two_layer_class(lobe: Lobe, context: Context | None = None, conductor: bool = False,
                    tau0: Any = None, diagnose: bool = True, fine: bool | None = None) -> TwoLayerClass:
    """The class of a 2-layer lobe below ``context`` (alg. 1 for the top lobe, alg. 5 when stacked)
    with a medium of optical depth ``tau0`` (default 0) above its first interface; ``conductor``:
    the second interface is a conductor base (5.2.4). ``fine`` (default: ``diagnose``): rescan with
    N_SCAN_FALLBACK samples when the quick scan finds N1 empty; ``diagnose``: when empty, also
    bound the energy in the reason (bisection, slower)."""
    ctx = context if context is not None else Context.ambient()
    o = ctx.options
    R = lobe.rgb
    bounds: dict[str, Any] = {}
    kind = "conductor-2" if conductor else "dielectric-2"
    t0 = np.zeros(3) if tau0 is None else as_rgb(tau0, "tau0")
    if np.any(t0 < 0):
        raise InverseError("tau0: must be >= 0")
    mk = lambda ok, reason, **kw: TwoLayerClass(kind, lobe, ctx, ok, reason, bounds, conductor=conductor,  # noqa: E731
                                                tau0=t0, **kw)
    if np.any(t0 > 0) and not ctx.absorbing:
        return mk(False, "tau0 > 0 needs a medium above the lobe, and the top of a stack in air has none")
    bounds["tau0"] = t0
    top = ctx.with_medium(t0) if np.any(t0 > 0) else ctx
    rp = top.r_prime(R)
    bounds["r_prime"] = rp
    if np.any(rp >= 1.0):
        return mk(False, FAIL_TEXT[FAIL_TOP_TARGET] + f" (R'={fmt_rgb(rp)})")
    vr_paper, ch_top = scalar_sigma_r(top, rp, lobe.sigma, o)
    esm = math.inf
    hi = o.eta_max
    if top.interfaces == 0:
        esm = eta_sigma_max(variance_to_roughness(max(vr_paper, 0.0)), top.eta)
        hi = min(hi, esm)
    bounds["eta_sigma_max"] = esm
    cls = mk(True, None, top_context=top, ch_top=ch_top, vr_top_paper=vr_paper, eta_sigma_max=esm)
    if vr_paper < 0.0:
        cls.achievable = False
        bound = f"sigma_min={top.sigma_min(rp)[ch_top]:.4g}, " if diagnose else ""
        cls.reason = (f"sigma={lobe.sigma:g} is below the variance the layers above already add "
                      f"({bound}eq. 19 with sigma_R = 0)")
        return cls
    n1, counts = _scan_n1(cls, 1.0, hi, o.n_scan)
    if not n1 and (diagnose if fine is None else fine):
        n1, counts = _scan_n1(cls, 1.0, hi, N_SCAN_FALLBACK)
    cls.scan_status = counts
    cls.n1 = n1
    bounds["N1"] = n1
    if not n1:
        cls.achievable = False
        cls.reason = _two_layer_reason(cls, counts, diagnose)
    return cls


def _scan_n1(cls: TwoLayerClass, lo: float, hi: float, n: int) -> tuple[list[Interval], dict[int, int]]:
    """N1 (eq. 12) on [lo, hi]: scan, then bisection of each run's ends (choice 5)."""
    ctx = cls.top_context
    o = ctx.options
    w1, xs = kernel_for(o)
    if hi < lo:
        return [], {}
    etas = np.linspace(lo, hi, n)
    status = np.empty(n, dtype=np.int64)
    exact = o.top_variance == "exact"
    minimax = o.variance_channel == "minimax"
    _two_layer_scan(ctx.state, ctx.scalars, w1, xs, cls.lobe.rgb, cls.lobe.sigma, etas, o.eta_max, cls.conductor,
                    exact, cls.ch_top, cls.vr_top_paper, minimax, status)
    counts = {int(k): int(v) for k, v in zip(*np.unique(status, return_counts=True))}
    st1 = np.empty_like(ctx.state)
    sc1 = np.empty_like(ctx.scalars)
    sub = np.empty(7)
    bot = np.empty(8)

    def ok(e: float) -> bool:
        return _two_layer_eval(ctx.state, ctx.scalars, w1, xs, cls.lobe.rgb, cls.lobe.sigma, e, o.eta_max,
                               cls.conductor, exact, cls.ch_top, cls.vr_top_paper, minimax, st1, sc1, sub, bot) == OK

    out = []
    for i, j in _runs(status == OK):
        a = etas[i] if i == 0 else _bisect(ok, etas[i], etas[i - 1])
        b = etas[j] if j == n - 1 else _bisect(ok, etas[j], etas[j + 1])
        out.append(Interval(float(a), float(b)))
    return out, counts


def _two_layer_reason(cls: TwoLayerClass, counts: dict[int, int], diagnose: bool) -> str:
    """Why N1 is empty: the failure most samples share, and the energy bound when the lobe is too bright."""
    fails = {k: v for k, v in counts.items() if k != OK}
    if not fails:
        return "N1 is empty"
    main = max(fails, key=lambda k: fails[k])
    text = FAIL_TEXT.get(main, "invalid")
    where = " (top lobe: eta1 <= eta_sigma_max = %.4g, section 5.2.2)" % cls.eta_sigma_max \
        if math.isfinite(cls.eta_sigma_max) else ""
    msg = f"N1 (eq. 12) is empty for R={fmt_rgb(cls.lobe.rgb)}, sigma={cls.lobe.sigma:g}: for most eta1 {text}{where}"
    if diagnose and main in (FAIL_NO_ETA2, FAIL_BOTTOM_ENERGY, FAIL_TOP_ENERGY, FAIL_CONDUCTOR):
        r_max = two_layer_energy_max(cls.lobe.sigma, cls.context, cls.conductor, cls.tau0)
        if r_max is not None:
            where_ = " here (below the layers chosen above)" if cls.context.interfaces else ""
            msg += f"; the largest achromatic energy reachable with eta <= eta_max={cls.context.options.eta_max:g}" \
                   f"{where_} is R_max={r_max:.4g}"
    return msg


def two_layer_energy_max(sigma: float, context: Context, conductor: bool = False, tau0: Any = None,
                         tol: float = 1e-5) -> float | None:
    """The largest achromatic energy of a 2-layer lobe of variance ``sigma`` with a non-empty class
    in ``context`` (bisection on R; used for T0, eq. 16, and for messages). None if none is."""
    def ok(r: float) -> bool:
        c = two_layer_class(Lobe(r, sigma, 2), context, conductor, tau0, diagnose=False, fine=True)
        return c.achievable

    lo, hi = 0.0, 1.0 - 1e-9
    probe = [1e-4, 1e-3, 0.01, 0.05]
    start = next((p for p in probe if ok(p)), None)
    if start is None:
        return None
    lo = start
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        if ok(mid):
            lo = mid
        else:
            hi = mid
    return lo
