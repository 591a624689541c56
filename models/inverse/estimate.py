"""Lobe estimator of the inverse method's validation: simulated lobes from a normal-incidence slice.

A simulated BRDF slice at normal incidence (half-vector parametrization) is reduced to ring
energies (:func:`ring_data`: fractions of the incident flux per ring of half-vector elevation,
``theta_v = 2 theta_h``, rings below ``theta_h = 45 deg``; bounce order 1 apart from the internal
orders), and fitted with normalised GGX lobes about the normal (:func:`fit_lobes`, exact ring
fractions :func:`lobe_ring_fractions`); :func:`estimate_lobes` identifies them with the requested
lobes (order 1 = the top interface). Energies are albedos (the paper's ``R_k``), variances
Belcour's ``f(alpha)``. Method, identification and limits: ``docs/inverse.md``, "Lobe estimator".
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np
from scipy import optimize

from models.belcour import roughness_to_variance, variance_to_roughness
from models.inverse.lobes import Lobe

#: requested variances closer than this ratio are fitted as one lobe
SEPARABLE_RATIO = 1.8
#: variances below this are "smooth" for the estimator (below the first half ring at 90 rings)
SIGMA_RES = 1e-4
GL_NODES = 8
ALPHA_FIT_MIN = 1e-8
ALPHA_FIT_MAX = 0.9999


def _lambda(tan2: np.ndarray, alpha: float) -> np.ndarray:
    """Smith Lambda of GGX for an isotropic roughness (same formula as goniometer.optics.ggx_lambda)."""
    return 0.5 * (np.sqrt(1.0 + alpha * alpha * tan2) - 1.0)


_GL_X, _GL_W = np.polynomial.legendre.leggauss(GL_NODES)


def lobe_ring_fractions(theta_h_edges: np.ndarray, alpha: float) -> np.ndarray:
    """Fraction of a normalised GGX lobe's albedo (normal incidence) leaving through each ring
    ``[theta_h_edges[i], theta_h_edges[i+1])`` of half-vector elevation (radians, ``< pi/4``).

    ``Int D(h) G1(v) cos theta_h dw_h / A(alpha)`` with the substitution ``u = tan^2 / (a^2 + tan^2)``
    (docs/inverse.md); ``A(alpha)`` integrates up to ``theta_h = pi/4`` (``theta_v = pi/2``)."""
    a = max(float(alpha), ALPHA_FIT_MIN)
    a2 = a * a

    def u_of(th: np.ndarray) -> np.ndarray:
        t2 = np.tan(th) ** 2
        return t2 / (a2 + t2)

    def g1_of_u(u: np.ndarray) -> np.ndarray:
        u = np.clip(u, 0.0, 1.0 - 1e-15)
        t2h = a2 * u / (1.0 - u)             # tan^2 theta_h
        # theta_v = 2 theta_h: tan^2(2 t) = 4 tan^2 t / (1 - tan^2 t)^2
        t2v = 4.0 * t2h / np.maximum((1.0 - t2h) ** 2, 1e-300)
        return 1.0 / (1.0 + _lambda(t2v, a))

    def integral(ua: np.ndarray, ub: np.ndarray) -> np.ndarray:
        mid = 0.5 * (ua + ub)
        half = 0.5 * (ub - ua)
        x = mid[:, None] + half[:, None] * _GL_X[None, :]
        return half * np.sum(_GL_W[None, :] * g1_of_u(x), axis=1)

    edges = np.clip(np.asarray(theta_h_edges, dtype=float), 0.0, math.pi / 4)
    u = u_of(edges)
    # split the total into a few panels for accuracy over the whole range
    total_edges = u_of(np.linspace(0.0, math.pi / 4, 65))
    total = float(np.sum(integral(total_edges[:-1], total_edges[1:])))
    return integral(u[:-1], u[1:]) / total


def lobe_albedo(alpha: float) -> float:
    """``A(alpha)``: the albedo at normal incidence of an (un-normalised) GGX lobe with F = 1."""
    a = max(float(alpha), ALPHA_FIT_MIN)
    a2 = a * a
    th = np.linspace(0.0, math.pi / 4, 65)
    t2 = np.tan(th) ** 2
    u = t2 / (a2 + t2)
    mid = 0.5 * (u[:-1] + u[1:])
    half = 0.5 * (u[1:] - u[:-1])
    x = mid[:, None] + half[:, None] * _GL_X[None, :]
    xx = np.clip(x, 0.0, 1.0 - 1e-15)
    t2h = a2 * xx / (1.0 - xx)
    t2v = 4.0 * t2h / np.maximum((1.0 - t2h) ** 2, 1e-300)
    g = 1.0 / (1.0 + _lambda(t2v, a))
    return float(np.sum(half * np.sum(_GL_W[None, :] * g, axis=1)))


@dataclass
class RingData:
    """Ring energies of a normal-incidence slice over the rings with half-vector edges
    ``theta_h_edges`` (radians): ``energy[c, i]`` and ``stderr[c, i]`` (all exits), ``order1`` /
    ``order1_stderr`` (bounce order 1: reflection off the top interface), ``internal`` /
    ``internal_stderr`` (orders >= 2), ``orders[k, c, i]`` per stored order; ``rays`` per slice."""

    theta_h_edges: np.ndarray
    energy: np.ndarray
    stderr: np.ndarray
    orders: np.ndarray
    rays: int
    order1: np.ndarray | None = None
    order1_stderr: np.ndarray | None = None
    internal: np.ndarray | None = None
    internal_stderr: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.order1 is None:
            self.order1 = self.orders[0] if self.orders.shape[0] else np.zeros_like(self.energy)
        if self.internal is None:
            self.internal = self.energy - self.order1
        if self.internal_stderr is None:
            self.internal_stderr = self.stderr.copy()
        if self.order1_stderr is None:
            # a ray exits in one order only, so the two parts' variances nearly add up (their covariance
            # -m1 m2 / N is negligible at these counts)
            self.order1_stderr = np.sqrt(np.maximum(self.stderr ** 2 - self.internal_stderr ** 2, 0.0))


def ring_data(result: Any) -> RingData:
    """Reduce the first (normal-incidence) BRDF slice of a :class:`SimulationResult` to rings."""
    sd = result.brdf
    grid = sd.grid
    if grid.parametrization != "half":
        raise ValueError("the lobe estimator needs half-vector slices (parametrization='half')")
    om = sd.proj_solid_angle[0]
    edges_deg = grid.theta_edges_deg()
    # at normal incidence a half ring maps entirely above the horizon iff theta_h < 45 deg; row 0 is
    # masked by the simulator for error statistics only (degenerate width), its value is valid and
    # holds the Dirac of smooth lobes, so it is kept
    n = int(np.count_nonzero(edges_deg[1:] <= 45.0 + 1e-9))

    def rings(v: np.ndarray) -> np.ndarray:
        return np.sum(v[..., :n, :] * om[:n], axis=-1)

    def rings_se(se: np.ndarray) -> np.ndarray:
        return np.sqrt(np.sum((se[..., :n, :] * om[:n]) ** 2, axis=-1))

    e = rings(sd.value[0])
    s = rings_se(sd.stderr[0])
    o = rings(sd.orders[0])
    si = rings_se(sd.stderr_internal[0]) if sd.stderr_internal is not None else None
    o1 = o[0] if o.shape[0] else np.zeros_like(e)
    return RingData(np.radians(edges_deg[: n + 1]), e, s, o, int(result.settings.rays), o1, None, e - o1, si)


@dataclass
class LobeFit:
    """Fitted lobes of one channel: energies, roughnesses, their standard errors, chi2/dof."""

    energy: np.ndarray
    alpha: np.ndarray
    energy_err: np.ndarray
    alpha_err: np.ndarray
    chi2_dof: float


def fit_lobes(data: np.ndarray, stderr: np.ndarray, edges: np.ndarray, rays: int, alpha0: Sequence[float],
              energy0: Sequence[float]) -> LobeFit:
    """Least-squares fit of ``len(alpha0)`` normalised GGX lobes to ring energies ``data``.

    Each ring's standard deviation is taken under the model, as :func:`goniometer.testing.cell_chi2`
    does (``docs/testing.md``): a ring value is a sum of rare weighted exits, Var ~ model x (mean
    squared weight / mean weight) / N, the weight ratio from the simulation, ``stderr^2 N / data``;
    1 for rings never hit. So rings the model fills but the simulation did not hit count, and noise
    does not bias the weights.
    """
    D = np.asarray(data, dtype=float)
    se = np.asarray(stderr, dtype=float)
    hit = (D > 0) & (se > 0)
    ratio = np.where(hit, se * se * rays / np.where(hit, D, 1.0), 1.0)     # mean w^2 / mean w per ring

    def deviation(m: np.ndarray) -> np.ndarray:
        return np.sqrt(np.maximum(m, 1.0 / rays) * ratio / rays)

    return fit_ring_lobes(D, edges, alpha0, energy0, deviation)


def fit_ring_lobes(data: np.ndarray, edges: np.ndarray, alpha0: Sequence[float], energy0: Sequence[float],
                   deviation: Callable[[np.ndarray], np.ndarray], scales: Sequence[float] = (1.0, 0.5, 2.0),
                   scale_errors: str = "above_one") -> LobeFit:
    """The least squares of :func:`fit_lobes` with the rings' standard deviations given by
    ``deviation(model)`` (ring energies of the model -> one deviation per ring; a ring with an
    infinite deviation is left out): ``len(alpha0)`` normalised GGX lobes, energies in [0, 1],
    roughnesses in [ALPHA_FIT_MIN, ALPHA_FIT_MAX] (fitted in log alpha), started from ``energy0``
    and ``alpha0`` times each of ``scales``, the lowest cost kept. Standard errors from the Jacobian,
    scaled by ``sqrt(chi2/dof)`` when it is above 1 (``scale_errors="above_one"``) or always
    (``"always"``: deviations known only up to a factor)."""
    D = np.asarray(data, dtype=float)
    G = len(alpha0)
    fr_cache: dict[float, np.ndarray] = {}

    def frac(a: float) -> np.ndarray:
        f = fr_cache.get(a)
        if f is None:
            f = lobe_ring_fractions(edges, a)
            if len(fr_cache) < 4096:
                fr_cache[a] = f
        return f

    def model(x: np.ndarray) -> np.ndarray:
        m = np.zeros_like(D)
        for g in range(G):
            m += x[g] * frac(math.exp(x[G + g]))
        return m

    def resid(x: np.ndarray) -> np.ndarray:
        m = model(x)
        return (m - D) / deviation(m)

    lo = np.concatenate([np.zeros(G), np.full(G, math.log(ALPHA_FIT_MIN))])
    hi = np.concatenate([np.ones(G), np.full(G, math.log(ALPHA_FIT_MAX))])
    best = None
    for scale in scales:
        a = np.clip(np.asarray(alpha0, dtype=float) * scale, ALPHA_FIT_MIN * 1.01, ALPHA_FIT_MAX * 0.99)
        x0 = np.concatenate([np.clip(np.asarray(energy0, dtype=float), 1e-7, 0.99), np.log(a)])
        r = optimize.least_squares(resid, x0, bounds=(lo, hi), x_scale="jac", max_nfev=400)
        if best is None or r.cost < best.cost:
            best = r
    x = best.x
    used = int(np.count_nonzero(np.isfinite(deviation(model(x)))))
    dof = max(1, used - 2 * G)
    chi2 = 2.0 * best.cost / dof
    J = best.jac
    cov = np.linalg.pinv(J.T @ J) * (max(1.0, chi2) if scale_errors == "above_one" else chi2)
    err = np.sqrt(np.maximum(np.diag(cov), 0.0))
    alpha = np.exp(x[G:])
    return LobeFit(x[:G].copy(), alpha, err[:G], alpha * err[G:], float(chi2))


def _group_sigmas(sigmas: Sequence[float]) -> list[list[int]]:
    """Indices grouped when their variances are within SEPARABLE_RATIO or both below SIGMA_RES."""
    order = sorted(range(len(sigmas)), key=lambda k: sigmas[k])
    groups: list[list[int]] = []
    for k in order:
        s = sigmas[k]
        if groups:
            prev = sigmas[groups[-1][-1]]
            both_smooth = s < SIGMA_RES and prev < SIGMA_RES
            close = prev >= SIGMA_RES and s < SEPARABLE_RATIO * prev
            if both_smooth or close:
                groups[-1].append(k)
                continue
        groups.append([k])
    return groups


def lobe_groups(lobes: Sequence[Lobe]) -> list[list[int]]:
    """Lobes that can be told apart at normal incidence: requested variances sorted and grouped
    when within SEPARABLE_RATIO of each other or both below SIGMA_RES (docs/inverse.md)."""
    return _group_sigmas([lb.sigma for lb in lobes])


def sigma_stderr(a: float, a_err: float) -> float:
    """Standard error of ``sigma = f(alpha)`` from that of ``alpha``, by the delta method:
    ``d f / d alpha = 1.1 a^0.1 / (1 - a^1.1)^2``."""
    return 1.1 * a ** 0.1 / (1.0 - a ** 1.1) ** 2 * a_err


def estimate_lobes(rings: RingData, lobes: Sequence[Lobe]) -> dict[str, Any]:
    """Per-lobe simulated energy and variance (RGB) from the rings (docs/inverse.md, "Lobe estimator").

    Bounce order 1 is exactly the top interface's reflection, i.e. lobe 1 (1-layer) or lobe 1's
    first sub-lobe (2-layer): it is fitted alone with one GGX lobe. The internal part (orders
    >= 2) holds the other components -- lobe 1's second sub-lobe if lobe 1 has 2 layers, then lobes
    2..K -- fitted with one GGX lobe per group of components whose requested variances cannot be
    separated (:func:`lobe_groups`). A 2-layer lobe 1 combines its two parts as eq. 4 does (energies
    added, variances energy-weighted). Values of lobes in a group of several are None."""
    K = len(lobes)
    N = rings.rays
    edges = rings.theta_h_edges
    out_lobes: list[dict[str, Any]] = [{} for _ in range(K)]
    # ---- order 1: the top interface
    top = []
    a_top = max(variance_to_roughness(max(lobes[0].sigma, 1e-12)), 2 * ALPHA_FIT_MIN)
    for c in range(3):
        d, se = rings.order1[c], rings.order1_stderr[c]
        tot = float(d.sum())
        if tot * N < 25.0:        # too few exits to fit a shape: energy only
            top.append({"R": tot, "R_err": math.sqrt(max(tot, 1.0 / N) / N), "sigma": None, "sigma_err": None})
            continue
        if c > 0 and np.array_equal(d, rings.order1[c - 1]):
            top.append(dict(top[-1]))
            continue
        f = fit_lobes(d, se, edges, N, [a_top], [tot])
        top.append({"R": f.energy[0], "R_err": f.energy_err[0], "sigma": roughness_to_variance(f.alpha[0]),
                    "sigma_err": sigma_stderr(f.alpha[0], f.alpha_err[0]), "alpha": f.alpha[0], "chi2": f.chi2_dof})
    # ---- internal components
    comps: list[tuple[int, float, np.ndarray]] = []      # (lobe index, sigma, energy guess RGB)
    if lobes[0].layers == 2:
        comps.append((0, lobes[0].sigma, np.maximum(lobes[0].rgb - np.array([t["R"] for t in top]), 1e-6)))
    for k in range(1, K):
        comps.append((k, lobes[k].sigma, lobes[k].rgb))
    groups = _group_sigmas([c[1] for c in comps]) if comps else []
    fits = []
    for c in range(3):
        if not groups:
            break
        if c > 0 and np.array_equal(rings.internal[c], rings.internal[c - 1]):
            fits.append(fits[-1])
            continue
        a0 = [max(variance_to_roughness(max(comps[g[0]][1], 1e-12)), 2 * ALPHA_FIT_MIN) for g in groups]
        e0 = [sum(comps[j][2][c] for j in g) for g in groups]
        fits.append(fit_lobes(rings.internal[c], rings.internal_stderr[c], edges, N, a0, e0))
    group_out = []
    internal_of: dict[int, dict[str, np.ndarray] | None] = {}
    for gi, g in enumerate(groups):
        E = np.array([f.energy[gi] for f in fits])
        Ee = np.array([f.energy_err[gi] for f in fits])
        A = np.array([f.alpha[gi] for f in fits])
        Ae = np.array([f.alpha_err[gi] for f in fits])
        S = np.array([roughness_to_variance(a) for a in A])
        dS = np.array([sigma_stderr(a, ae) for a, ae in zip(A, Ae)])
        members = [comps[j][0] + 1 for j in g]
        group_out.append({"lobes": members, "part": "internal", "R": E, "R_err": Ee, "sigma": S, "sigma_err": dS,
                          "alpha": A})
        for j in g:
            internal_of[comps[j][0]] = {"R": E, "R_err": Ee, "sigma": S, "sigma_err": dS} if len(g) == 1 else None
    # ---- per lobe
    tR = np.array([t["R"] for t in top])
    tRe = np.array([t["R_err"] for t in top])
    tS = np.array([np.nan if t["sigma"] is None else t["sigma"] for t in top])
    tSe = np.array([np.nan if t["sigma_err"] is None else t["sigma_err"] for t in top])
    group_out.insert(0, {"lobes": [1], "part": "order 1 (top interface)", "R": tR, "R_err": tRe, "sigma": tS,
                         "sigma_err": tSe, "alpha": np.array([t.get("alpha", np.nan) for t in top])})
    if lobes[0].layers == 1:
        out_lobes[0] = {"R": tR, "R_err": tRe, "sigma": None if np.any(np.isnan(tS)) else tS,
                        "sigma_err": None if np.any(np.isnan(tSe)) else tSe}
    for k in range(K):
        if k == 0 and lobes[0].layers == 1:
            continue
        part = internal_of.get(k)
        if part is None:
            grp = next((g["lobes"] for g in group_out[1:] if k + 1 in g["lobes"]), [k + 1])
            out_lobes[k] = {"R": None, "R_err": None, "sigma": None, "sigma_err": None, "group": grp}
            continue
        if k == 0:        # 2-layer top lobe: order 1 + its internal part (eq. 4)
            R = tR + part["R"]
            Re = np.sqrt(tRe ** 2 + part["R_err"] ** 2)
            ts = np.where(np.isnan(tS), part["sigma"], tS)
            S = (tR * ts + part["R"] * part["sigma"]) / np.where(R > 0, R, 1.0)
            Se = np.sqrt((tR * np.nan_to_num(tSe)) ** 2 + (part["R"] * part["sigma_err"]) ** 2) / np.where(R > 0, R, 1.0)
            out_lobes[0] = {"R": R, "R_err": Re, "sigma": S, "sigma_err": Se}
        else:
            out_lobes[k] = part
    return {"lobes": out_lobes, "groups": group_out, "chi2_dof": [f.chi2_dof for f in fits],
            "chi2_dof_top": [t.get("chi2", float("nan")) for t in top]}
