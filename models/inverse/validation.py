"""Validation of the inverse method (Bati 2021, :mod:`models.inverse.solver`) on target lobe configurations.

For every case of a cases file (``configs/inverse/cases.toml``: ``[[case]]`` tables with ``name``,
``base`` and ``[[case.lobe]]`` tables ``R``, ``sigma``, ``layers``; optional ``pick`` -- the
``--pick`` syntax of ``gonio invert`` -- ``expect_achievable`` and ``note``):

(a) **Forward check** (the paper's figure 25): the retrieved stack goes through Belcour's forward
    model (:func:`models.belcour.model.stack_statistics` at ``cos theta = 1``, per-channel statistics,
    material FGD slices). Lobe ``k``'s energy is the sum of the energies of its interfaces' lobes,
    its variance their energy-weighted mean (eq. 4). Requested vs obtained ``R_k`` and ``sigma_k``
    per channel.
(b) **Simulation** (optional): the goniometer simulates the stack at normal incidence (half-vector
    slices, dense near the mirror direction) and each lobe's energy and variance are estimated
    from the slice by the estimator below.

Lobe estimator (documented limits)
----------------------------------
At normal incidence the BRDF is isotropic about the normal, so the slice is reduced to **ring
energies** ``D_i`` (fraction of the incident flux leaving through ring ``i`` of the half-vector
grid, ``theta_v = 2 theta_h``; rings reaching the horizon, ``theta_h > 45 deg``, are left out;
the first ring, masked by the simulator for error statistics only, is kept: it holds the Dirac
of smooth lobes), separately for bounce order 1 and for orders >= 2. The model is a sum of GGX
lobes about the normal (the form of Belcour's eq. 3), each written with its *albedo* ``e`` (the
energy the paper calls ``R_k``: "matches a Fresnel reflectance for a Dirac") and roughness
``alpha``: ``f = sum_g e_g D(h; a_g) G1(v; a_g) / (4 cos theta_v A(a_g))``,
``A(a) = Int D G1 cos theta_h dw_h`` (separable Smith, ``G1(l) = 1`` at normal incidence). Its ring
energies are exact: with ``u = tan^2 theta_h / (a^2 + tan^2 theta_h)`` (the GGX projected-area CDF)
a ring's energy is ``e / A Int G1(v(u)) du`` over the ring, by 8-point Gauss-Legendre in ``u`` --
accurate for any lobe width, even inside one ring.

Identification: **bounce order 1 is exactly the top interface's reflection** -- lobe 1 if it has
one layer, the first sub-lobe of lobe 1 if it has two -- and is fitted alone with one lobe. The
internal part (orders >= 2) holds the other components (lobe 1's second sub-lobe, lobes 2..K)
and is fitted with one lobe per group of components whose requested variances can be told apart.
A 2-layer lobe 1 combines its two parts as eq. 4 (energies added, variances energy-weighted).
Fits are least squares per channel with each ring's deviation taken under the model
(``tests/conftest.cell_chi2``'s rule: ``Var ~ model x (mean w^2 / mean w) / N``) from several starts
(the requested values, alpha x 0.5 and x 2); standard errors from the Jacobian, scaled by
``sqrt(chi2/dof)`` when above 1.

Limits: components whose requested variances are within a factor ``SEPARABLE_RATIO = 1.8`` of
each other (or both below ``SIGMA_RES``) cannot be told apart at normal incidence -- they are
fitted as one lobe and only their sum is compared (``R_simulated`` and ``sigma_simulated`` are null
for those lobes and the group is reported); separations near that ratio are poorly determined
(large standard errors, reported). A lobe narrower than the first ring (``alpha < ~2e-4`` for 90
half rings) has an undetermined variance: its fitted sigma is only an upper bound. Belcour's model
itself is approximate (its lobes are GGX projections, the variance mapping ``f`` is empirical,
inter-reflections between rough interfaces are not GGX): differences between the simulated lobes
and the requested ones beyond the standard errors measure the forward model's error, not the
inverse's, and the chi2/dof of the fits (well above 1 at millions of rays) shows how far from
GGX the simulated lobes are.

The top interface's reflection is exactly bounce order 1 of the simulation, whose energy is also
compared with ``FGD(1, alpha_0, eta_1)`` of the forward model (an independent check of the FGD
table at normal incidence).

Outputs (:func:`run_validation`): a JSON document (per case ``name``, ``achievable`` -- with
``reason`` when false -- and per lobe ``R_requested``, ``R_forward``, ``sigma_requested``,
``sigma_forward`` RGB lists, plus ``R_simulated``, ``sigma_simulated`` with ``--simulate``) and,
with a report directory, ``report.md`` (tables), ``index.html``, the figure-25-style scatter plots
and one profile figure per simulated case. Every file is written atomically (temporary file +
rename).
"""

from __future__ import annotations

import json
import math
import os
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
from scipy import optimize

from goniometer import atomic
from goniometer.stack import Stack
from models import belcour
from models.inverse import solver as inverse
from models.belcour import roughness_to_variance, variance_to_roughness
from models.inverse.solver import InverseError, Inversion, Lobe

#: requested variances closer than this ratio are fitted as one lobe
SEPARABLE_RATIO = 1.8
#: variances below this are "smooth" for the estimator (below the first half ring at 90 rings)
SIGMA_RES = 1e-4
#: relative tolerance of the forward check (figure 25): what the tests require of the round trip
FORWARD_RTOL = 0.01
#: default simulation settings of the validation
DEFAULT_RAYS = 4_000_000
DEFAULT_RESOLUTION = (90, 8)
GL_NODES = 8
ALPHA_FIT_MIN = 1e-8
ALPHA_FIT_MAX = 0.9999


# ============================================================================ cases

@dataclass(frozen=True)
class Case:
    """One target configuration: lobes (top first), base, optional picks and expectations."""

    name: str
    base: str
    lobes: tuple[Lobe, ...]
    pick: str = ""
    expect_achievable: bool = True
    note: str = ""

    def picks(self) -> list[inverse.Pick]:
        return inverse.parse_picks(self.pick, len(self.lobes))


def load_cases(path: str | os.PathLike) -> list[Case]:
    """Read a cases file; raises :class:`InverseError` naming the file, case and field."""
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except OSError as e:
        raise InverseError(f"{p}: cannot read: {e.strerror or e}") from None
    except tomllib.TOMLDecodeError as e:
        raise InverseError(f"{p}: invalid TOML: {e}") from None
    raw = data.get("case")
    if not isinstance(raw, list) or not raw:
        raise InverseError(f"{p}: no [[case]] tables")
    unknown = sorted(set(data) - {"case"})
    if unknown:
        raise InverseError(f"{p}: {unknown[0]}: unknown key (only [[case]] tables)")
    cases, names = [], set()
    for i, c in enumerate(raw):
        where = f"{p}: case[{i}]"
        if not isinstance(c, dict):
            raise InverseError(f"{where}: must be a table")
        bad = sorted(set(c) - {"name", "base", "lobe", "pick", "expect_achievable", "note"})
        if bad:
            raise InverseError(f"{where}.{bad[0]}: unknown key (name, base, lobe, pick, expect_achievable, note)")
        name = c.get("name")
        if not isinstance(name, str) or not name.strip():
            raise InverseError(f"{where}.name: required, a non-empty string")
        where = f"{p}: case {name!r}"
        if name in names:
            raise InverseError(f"{where}: duplicate name")
        names.add(name)
        base = c.get("base", "dielectric")
        if base not in ("dielectric", "conductor"):
            raise InverseError(f"{where}.base: {base!r} is not one of dielectric, conductor")
        lobes_raw = c.get("lobe")
        if not isinstance(lobes_raw, list) or not lobes_raw:
            raise InverseError(f"{where}.lobe: at least one [[case.lobe]] table is required")
        lobes = []
        for j, lr in enumerate(lobes_raw):
            w = f"{where}.lobe[{j}]"
            if not isinstance(lr, dict):
                raise InverseError(f"{w}: must be a table")
            bad = sorted(set(lr) - {"R", "sigma", "layers"})
            if bad:
                raise InverseError(f"{w}.{bad[0]}: unknown key (R, sigma, layers)")
            if "R" not in lr:
                raise InverseError(f"{w}.R: required")
            try:
                lobes.append(Lobe(lr["R"] if not isinstance(lr["R"], list) else tuple(lr["R"]),
                                  lr.get("sigma", 0.0), lr.get("layers", 1)))
            except (InverseError, TypeError, ValueError) as e:
                raise InverseError(f"{w}: {e}") from None
        pick = c.get("pick", "")
        if not isinstance(pick, str):
            raise InverseError(f"{where}.pick: a string in the --pick syntax (e.g. \"1.u1=0.3\")")
        try:
            inverse.parse_picks(pick, len(lobes))
        except InverseError as e:
            raise InverseError(f"{where}.pick: {e}") from None
        exp = c.get("expect_achievable", True)
        if not isinstance(exp, bool):
            raise InverseError(f"{where}.expect_achievable: true or false")
        note = c.get("note", "")
        cases.append(Case(name, base, tuple(lobes), pick, exp, str(note)))
    return cases


# ============================================================================ (a) forward check

@dataclass
class LobeCheck:
    """Requested vs forward (and simulated) statistics of one lobe (RGB arrays)."""

    R_requested: np.ndarray
    sigma_requested: float
    R_forward: np.ndarray
    sigma_forward: np.ndarray
    interfaces: list[int]
    R_predicted: np.ndarray
    sigma_predicted: np.ndarray
    R_simulated: np.ndarray | None = None
    sigma_simulated: np.ndarray | None = None
    R_simulated_err: np.ndarray | None = None
    sigma_simulated_err: np.ndarray | None = None
    group: list[int] | None = None

    @property
    def R_rel_error(self) -> np.ndarray:
        return self.R_forward / self.R_requested - 1.0

    @property
    def sigma_rel_error(self) -> np.ndarray:
        if self.sigma_requested > 0.0:
            return self.sigma_forward / self.sigma_requested - 1.0
        return self.sigma_forward  # absolute for a smooth lobe


def forward_lobes(stack: Stack, lobe_interfaces: Sequence[Sequence[int]],
                  options: belcour.BelcourOptions | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """Belcour's forward model of ``stack`` at normal incidence, grouped per requested lobe:
    ``[(energy RGB, variance RGB), ...]`` (energies summed, variances energy-weighted, eq. 4)."""
    s = belcour.stack_statistics(stack, 1.0, options)
    out = []
    for idx in lobe_interfaces:
        e = np.sum([s.lobes[i].energy for i in idx], axis=0)
        ev = np.sum([s.lobes[i].energy * s.lobes[i].variance for i in idx], axis=0)
        out.append((e, np.where(e > 0, ev / np.where(e > 0, e, 1.0), 0.0)))
    return out


def forward_check(inv: Inversion) -> list[LobeCheck]:
    """Requested vs forward-model statistics of every lobe of an achievable inversion."""
    fw = forward_lobes(inv.stack(), inv.lobe_interfaces)
    pred = inv.predicted()
    return [LobeCheck(lobe.rgb, lobe.sigma, e, v, idx, pe, pv)
            for lobe, (e, v), (pe, pv), idx in zip(inv.lobes, fw, pred, inv.lobe_interfaces)]


# ============================================================================ (b) simulation and estimator

def _lambda(tan2: np.ndarray, alpha: float) -> np.ndarray:
    """Smith Lambda of GGX for an isotropic roughness (same formula as goniometer.optics.ggx_lambda)."""
    return 0.5 * (np.sqrt(1.0 + alpha * alpha * tan2) - 1.0)


_GL_X, _GL_W = np.polynomial.legendre.leggauss(GL_NODES)


def lobe_ring_fractions(theta_h_edges: np.ndarray, alpha: float) -> np.ndarray:
    """Fraction of a normalised GGX lobe's albedo (normal incidence) leaving through each ring
    ``[theta_h_edges[i], theta_h_edges[i+1])`` of half-vector elevation (radians, ``< pi/4``).

    ``Int D(h) G1(v) cos theta_h dw_h / A(alpha)`` with the substitution ``u = tan^2 / (a^2 + tan^2)``
    (module docstring); ``A(alpha)`` integrates up to ``theta_h = pi/4`` (``theta_v = pi/2``)."""
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
class FitResult:
    """Fitted lobes of one channel: energies, roughnesses, their standard errors, chi2/dof."""

    energy: np.ndarray
    alpha: np.ndarray
    energy_err: np.ndarray
    alpha_err: np.ndarray
    chi2_dof: float


def fit_lobes(data: np.ndarray, stderr: np.ndarray, edges: np.ndarray, rays: int, alpha0: Sequence[float],
              energy0: Sequence[float]) -> FitResult:
    """Least-squares fit of ``len(alpha0)`` normalised GGX lobes to ring energies ``data``.

    Each ring's standard deviation is taken under the model, as ``tests/conftest.cell_chi2`` does
    (a ring value is a sum of rare weighted exits: Var ~ model x (mean squared weight / mean weight)
    / N, the weight ratio from the simulation, ``stderr^2 N / data``; 1 for rings never hit), so that
    rings the model fills but the simulation did not hit count, and noise does not bias the weights.
    """
    D = np.asarray(data, dtype=float)
    se = np.asarray(stderr, dtype=float)
    G = len(alpha0)
    hit = (D > 0) & (se > 0)
    ratio = np.where(hit, se * se * rays / np.where(hit, D, 1.0), 1.0)     # mean w^2 / mean w per ring
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
        sd = np.sqrt(np.maximum(m, 1.0 / rays) * ratio / rays)
        return (m - D) / sd

    lo = np.concatenate([np.zeros(G), np.full(G, math.log(ALPHA_FIT_MIN))])
    hi = np.concatenate([np.ones(G), np.full(G, math.log(ALPHA_FIT_MAX))])
    best = None
    for scale in (1.0, 0.5, 2.0):
        a = np.clip(np.asarray(alpha0, dtype=float) * scale, ALPHA_FIT_MIN * 1.01, ALPHA_FIT_MAX * 0.99)
        x0 = np.concatenate([np.clip(np.asarray(energy0, dtype=float), 1e-7, 0.99), np.log(a)])
        r = optimize.least_squares(resid, x0, bounds=(lo, hi), x_scale="jac", max_nfev=400)
        if best is None or r.cost < best.cost:
            best = r
    x = best.x
    dof = max(1, D.shape[0] - 2 * G)
    chi2 = 2.0 * best.cost / dof
    J = best.jac
    cov = np.linalg.pinv(J.T @ J) * max(1.0, chi2)
    err = np.sqrt(np.maximum(np.diag(cov), 0.0))
    alpha = np.exp(x[G:])
    return FitResult(x[:G].copy(), alpha, err[:G], alpha * err[G:], float(chi2))


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
    when within SEPARABLE_RATIO of each other or both below SIGMA_RES (module docstring)."""
    return _group_sigmas([lb.sigma for lb in lobes])


def simulate_case(stack: Stack, lobes: Sequence[Lobe], rays: int = DEFAULT_RAYS,
                  resolution: tuple[int, int] = DEFAULT_RESOLUTION, seed: int = 1,
                  threads: int | None = None) -> tuple[Any, RingData]:
    """Simulate ``stack`` at normal incidence (half slices) and reduce to rings."""
    from goniometer.settings import SimulationSettings
    from goniometer.simulate import simulate
    settings = SimulationSettings(incident_deg=(0.0,), rays=int(rays), parametrization="half",
                                  resolution=tuple(resolution), seed=int(seed), threads=threads)
    result = simulate(stack, settings)
    return result, ring_data(result)


def _sigma_err(a: float, a_err: float) -> float:
    """Delta method: d f / d alpha = 1.1 a^0.1 / (1 - a^1.1)^2."""
    return 1.1 * a ** 0.1 / (1.0 - a ** 1.1) ** 2 * a_err


def estimate_lobes(rings: RingData, lobes: Sequence[Lobe]) -> dict[str, Any]:
    """Per-lobe simulated energy and variance (RGB) from the rings (module docstring).

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
                    "sigma_err": _sigma_err(f.alpha[0], f.alpha_err[0]), "alpha": f.alpha[0], "chi2": f.chi2_dof})
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
        dS = np.array([_sigma_err(a, ae) for a, ae in zip(A, Ae)])
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


# ============================================================================ running cases

@dataclass
class CaseResult:
    """Everything the validation found for one case."""

    case: Case
    inversion: Inversion
    checks: list[LobeCheck] = field(default_factory=list)
    simulated: dict[str, Any] | None = None
    rings: RingData | None = None
    top_order1: dict[str, Any] | None = None
    stack_json: dict | None = None
    elapsed_invert_s: float = 0.0
    elapsed_simulate_s: float = 0.0

    @property
    def achievable(self) -> bool:
        return self.inversion.achievable

    def max_forward_error(self) -> tuple[float, float]:
        """Largest relative error of R and sigma (absolute sigma for smooth lobes) over lobes and channels."""
        if not self.checks:
            return float("nan"), float("nan")
        er = max(float(np.max(np.abs(c.R_rel_error))) for c in self.checks)
        es = max(float(np.max(np.abs(c.sigma_rel_error))) for c in self.checks)
        return er, es

    def to_json(self) -> dict[str, Any]:
        d: dict[str, Any] = {"name": self.case.name, "base": self.case.base, "achievable": self.achievable,
                             "expect_achievable": self.case.expect_achievable}
        if self.case.note:
            d["note"] = self.case.note
        if self.case.pick:
            d["pick"] = self.case.pick
        if not self.achievable:
            d["reason"] = self.inversion.reason
            d["lobes"] = [{"R_requested": list(lb.R), "sigma_requested": [lb.sigma] * 3, "layers": lb.layers}
                          for lb in self.case.lobes]
            return d
        d["stack"] = self.stack_json
        d["searched"] = self.inversion.searched
        d["elapsed_invert_s"] = self.elapsed_invert_s
        lobes = []
        for k, c in enumerate(self.checks):
            e: dict[str, Any] = {
                "layers": self.case.lobes[k].layers,
                "interfaces": c.interfaces,
                "R_requested": c.R_requested.tolist(),
                "R_forward": c.R_forward.tolist(),
                "sigma_requested": [c.sigma_requested] * 3,
                "sigma_forward": c.sigma_forward.tolist(),
                "R_forward_rel_error": c.R_rel_error.tolist(),
                "sigma_forward_error": c.sigma_rel_error.tolist(),
                "sigma_forward_error_kind": "relative" if c.sigma_requested > 0 else "absolute",
                "choices": inverse._jsonable(self.inversion.solutions[k].choices),
            }
            if self.simulated is not None:
                s = self.simulated["lobes"][k]
                e["R_simulated"] = None if s.get("R") is None else np.asarray(s["R"]).tolist()
                e["sigma_simulated"] = None if s.get("sigma") is None else np.asarray(s["sigma"]).tolist()
                e["R_simulated_stderr"] = None if s.get("R_err") is None else np.asarray(s["R_err"]).tolist()
                e["sigma_simulated_stderr"] = None if s.get("sigma_err") is None else np.asarray(s["sigma_err"]).tolist()
                if s.get("group"):
                    e["simulated_group"] = s["group"]
            lobes.append(e)
        d["lobes"] = lobes
        if self.simulated is not None:
            d["simulation"] = {
                "rays": self.rings.rays if self.rings else None,
                "groups": inverse._jsonable(self.simulated["groups"]),
                "fit_chi2_dof_internal": self.simulated["chi2_dof"],
                "fit_chi2_dof_order1": self.simulated["chi2_dof_top"],
                "top_interface_order1": inverse._jsonable(self.top_order1),
                "elapsed_s": self.elapsed_simulate_s,
            }
        return d


def run_case(case: Case, simulate: bool = False, rays: int = DEFAULT_RAYS,
             resolution: tuple[int, int] = DEFAULT_RESOLUTION, seed: int = 1,
             options: inverse.InverseOptions | None = None, threads: int | None = None) -> CaseResult:
    """Invert one case, check it through the forward model and optionally simulate it."""
    t0 = time.perf_counter()
    inv = inverse.solve(list(case.lobes), case.base, case.picks(), options, name=case.name)
    res = CaseResult(case, inv, elapsed_invert_s=time.perf_counter() - t0)
    if not inv.achievable:
        return res
    stack = inv.stack()
    res.stack_json = json.loads(stack.to_json())
    res.checks = forward_check(inv)
    if simulate:
        t1 = time.perf_counter()
        result, rings = simulate_case(stack, case.lobes, rays, resolution, seed, threads)
        res.elapsed_simulate_s = time.perf_counter() - t1
        res.rings = rings
        est = estimate_lobes(rings, case.lobes)
        res.simulated = est
        for k, c in enumerate(res.checks):
            s = est["lobes"][k]
            if s.get("R") is not None:
                c.R_simulated, c.sigma_simulated = s["R"], s["sigma"]
                c.R_simulated_err, c.sigma_simulated_err = s["R_err"], s["sigma_err"]
            else:
                c.group = s.get("group")
        # order 1 = reflection off the top interface = FGD(1, alpha_0, eta_1) in the forward model
        fs = belcour.stack_statistics(stack, 1.0)
        o1 = rings.orders[0].sum(axis=1) if rings.orders.shape[0] else np.zeros(3)
        res.top_order1 = {"simulated": o1, "fgd": fs.lobes[0].energy,
                          "stderr": np.sqrt(np.maximum(o1, 0.0) / rings.rays)}
    return res


def run_validation(cases: Sequence[Case], simulate: bool = False, rays: int = DEFAULT_RAYS,
                   resolution: tuple[int, int] = DEFAULT_RESOLUTION, seed: int = 1,
                   options: inverse.InverseOptions | None = None, threads: int | None = None,
                   progress: Callable[[int, int, str], None] | None = None) -> list[CaseResult]:
    """Run every case (``progress(done, total, name)`` after each)."""
    out = []
    for i, c in enumerate(cases):
        out.append(run_case(c, simulate, rays, resolution, seed, options, threads))
        if progress:
            progress(i + 1, len(cases), c.name)
    return out


def validation_json(results: Sequence[CaseResult], simulate: bool, meta: dict | None = None) -> dict[str, Any]:
    """The JSON document of :func:`run_validation` (module docstring)."""
    achieved = [r for r in results if r.achievable]
    errs = [r.max_forward_error() for r in achieved]
    return {
        "format": "goniometer.inverse-validation",
        "version": 1,
        "simulated": simulate,
        "meta": meta or {},
        "summary": {
            "cases": len(results),
            "achievable": len(achieved),
            "unexpected": [r.case.name for r in results if r.achievable != r.case.expect_achievable],
            "max_R_forward_rel_error": max((e[0] for e in errs), default=None),
            "max_sigma_forward_error": max((e[1] for e in errs), default=None),
            "forward_rtol": FORWARD_RTOL,
        },
        "cases": [r.to_json() for r in results],
    }


# ============================================================================ report

_atomic_bytes = atomic.write_bytes


def write_json(path: str | os.PathLike, obj: Any) -> None:
    """Write JSON atomically."""
    _atomic_bytes(Path(path), (json.dumps(inverse._jsonable(obj), indent=2) + "\n").encode())


def _save_figure(fig, path: Path) -> None:
    import io
    import matplotlib.pyplot as plt
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    _atomic_bytes(path, buf.getvalue())


def _f(x: Any, fmt: str = ".4g") -> str:
    if x is None:
        return "-"
    a = np.atleast_1d(np.asarray(x, dtype=float))
    if a.size == 3 and np.ptp(a) == 0:
        return format(float(a[0]), fmt)
    return " ".join(format(float(v), fmt) for v in a)


def _pct(x: Any) -> str:
    a = np.atleast_1d(np.asarray(x, dtype=float))
    return " ".join(f"{100 * v:+.2f}%" for v in a)


_SPREAD_NOTE = ("forward variances differ between channels: a coloured lobe below an interface has a "
                "channel-dependent inter-reflection factor m (eq. 19) but one achromatic roughness; the minimax "
                "choice halves the spread")


def _why(case: CaseResult, k: int, c: LobeCheck) -> str:
    """A short explanation of a lobe's remaining differences."""
    notes = []
    if c.sigma_requested > 0 and np.max(np.abs(c.sigma_rel_error)) > 1e-4 and np.ptp(c.sigma_forward) > 0:
        notes.append(_SPREAD_NOTE)
    if np.max(np.abs(c.R_rel_error)) > 1e-6:
        notes.append("FGD split slice of the forward model (relative index < 1) differs slightly from the "
                     "inverse's unsplit quadrature")
    if c.R_simulated is not None:
        z = np.abs(c.R_simulated - c.R_forward) / np.maximum(c.R_simulated_err, 1e-12)
        if np.any(z > 5):
            notes.append("simulated energy differs from Belcour's forward model beyond noise "
                         "(the forward model is approximate for internal lobes)")
    if c.sigma_simulated is not None and c.sigma_requested >= SIGMA_RES:
        z = np.abs(c.sigma_simulated - c.sigma_forward) / np.maximum(c.sigma_simulated_err, 1e-12)
        if np.any(z > 5):
            notes.append("simulated variance differs from the forward model beyond noise (Belcour's variance "
                         "adding through rough interfaces and its Jacobians are approximate; the simulated lobe is "
                         "not exactly GGX)")
    if c.group:
        notes.append(f"variance too close to lobe(s) {c.group} to separate at normal incidence")
    if c.sigma_requested < SIGMA_RES and c.sigma_simulated is not None:
        notes.append("smooth lobe: the fitted variance is only an upper bound (first ring)")
    return "; ".join(notes)


def report_markdown(results: Sequence[CaseResult], simulate: bool, figures: dict[str, str]) -> str:
    lines = ["# Inverse method validation (Bati 2021)", ""]
    doc = validation_json(results, simulate)["summary"]
    lines += [f"{doc['cases']} cases, {doc['achievable']} achievable; largest forward-model error over all lobes "
              f"and channels: R {100 * (doc['max_R_forward_rel_error'] or 0):.3f}%, sigma "
              f"{100 * (doc['max_sigma_forward_error'] or 0):.3f}% (figure 25; tolerance {100 * FORWARD_RTOL:g}%).", ""]
    if doc["unexpected"]:
        lines += [f"**Unexpected achievability:** {', '.join(doc['unexpected'])}", ""]
    if "scatter" in figures:
        lines += [f"![requested vs obtained]({figures['scatter']})", ""]
    lines += ["Columns: requested, Belcour forward model of the retrieved stack (error), "
              + ("goniometer simulation at normal incidence (fit of GGX lobes, +- 1 standard error). " if simulate else "")
              + "Sigma errors are relative, absolute for smooth lobes.", ""]
    for r in results:
        lines.append(f"## {r.case.name}")
        lines.append("")
        if r.case.note:
            lines += [r.case.note, ""]
        lines.append(f"base: {r.case.base}; lobes: " + "; ".join(lb.describe() for lb in r.case.lobes)
                     + (f"; picks: `{r.case.pick}`" if r.case.pick else ""))
        lines.append("")
        if not r.achievable:
            exp = "" if r.case.expect_achievable else " (expected)"
            lines += [f"**Not physically achievable{exp}:** {r.inversion.reason}", ""]
            continue
        if not r.case.expect_achievable:
            lines += ["**Achievable although the case expected otherwise.**", ""]
        lines.append("Retrieved stack (top first): " + _stack_text(r.stack_json)
                     + (" -- default picks moved by the search (choice 6)" if r.inversion.searched else ""))
        lines.append("")
        hdr = "| lobe | R requested | R forward | error | sigma req. | sigma forward | error |"
        sep = "|---|---|---|---|---|---|---|"
        if simulate:
            hdr += " R simulated | sigma simulated | notes |"
            sep += "---|---|---|"
        else:
            hdr += " notes |"
            sep += "---|"
        lines += [hdr, sep]
        for k, c in enumerate(r.checks):
            row = (f"| {k + 1} ({r.case.lobes[k].layers}L) | {_f(c.R_requested)} | {_f(c.R_forward)} | "
                   f"{_pct(c.R_rel_error)} | {c.sigma_requested:.4g} | {_f(c.sigma_forward)} | "
                   + (_pct(c.sigma_rel_error) if c.sigma_requested > 0 else _f(c.sigma_rel_error, '.2e')) + " |")
            if simulate:
                if c.R_simulated is not None:
                    row += (f" {_f(c.R_simulated)} +- {_f(c.R_simulated_err, '.1g')} | {_f(c.sigma_simulated)} +- "
                            f"{_f(c.sigma_simulated_err, '.1g')} |")
                else:
                    row += f" (group {c.group}) | (group) |"
            row += f" {_why(r, k, c)} |"
            lines.append(row)
        lines.append("")
        if simulate and r.simulated is not None:
            for g in r.simulated["groups"][1:]:
                if len(g["lobes"]) > 1:
                    req = np.sum([r.case.lobes[k - 1].rgb for k in g["lobes"]], axis=0)
                    lines.append(f"- lobes {g['lobes']} fitted together: R {_f(g['R'])} (requested sum {_f(req)}), "
                                 f"sigma {_f(g['sigma'])}")
            if r.top_order1 is not None:
                t = r.top_order1
                lines.append(f"- top interface (bounce order 1): simulated {_f(t['simulated'])} +- {_f(t['stderr'], '.1g')}"
                             f", forward FGD {_f(t['fgd'])}")
            chi = [x for x in list(r.simulated["chi2_dof_top"]) + list(r.simulated["chi2_dof"]) if np.isfinite(x)]
            lines.append(f"- fit chi2/dof per channel: order 1 {_f(r.simulated['chi2_dof_top'], '.3g')}; internal "
                         f"{_f(r.simulated['chi2_dof'], '.3g') if r.simulated['chi2_dof'] else '-'}"
                         + (" (well above 1: the simulated lobes are not exactly GGX; standard errors are scaled up "
                            "accordingly)" if chi and max(chi) > 3 else ""))
            if r.case.name in figures:
                lines.append(f"\n![profile]({figures[r.case.name]})")
            lines.append("")
    return "\n".join(lines) + "\n"


def _stack_text(sj: dict | None) -> str:
    if not sj:
        return "-"
    parts = []
    for layer in sj["layers"]:
        if layer["type"] == "interface":
            ior = layer["ior"]
            ext = layer.get("extinction")
            ior_t = _f(ior, ".4g") if isinstance(ior, list) else f"{ior:.4g}"
            parts.append(f"interface(alpha={layer['roughness']:.4g}, eta={ior_t}"
                         + (f", kappa={_f(ext, '.4g')}" if ext else "") + ")")
        elif layer["type"] == "medium":
            parts.append(f"medium(tau={_f(layer['optical_depth'], '.3g')})")
    return " / ".join(parts)


def scatter_figure(results: Sequence[CaseResult], simulate: bool):
    """Figure-25-style plots: obtained vs requested energy and variance, per channel."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.6))
    colours = ("tab:red", "tab:green", "tab:blue")
    for ax, what in zip(axes, ("R", "sigma")):
        lim = 0.0
        for r in results:
            for c in r.checks:
                req = c.R_requested if what == "R" else np.full(3, c.sigma_requested)
                fw = c.R_forward if what == "R" else c.sigma_forward
                sim = c.R_simulated if what == "R" else c.sigma_simulated
                for ch in range(3):
                    ax.plot(req[ch], fw[ch], "o", ms=5, mfc="none", color=colours[ch])
                    if simulate and sim is not None:
                        ax.plot(req[ch], sim[ch], "x", ms=5, color=colours[ch])
                lim = max(lim, float(np.max(req)), float(np.max(fw)))
        lim = lim * 1.08 if lim > 0 else 1.0
        ax.plot([0, lim], [0, lim], "k:", lw=1)
        ax.set_xlim(0, lim)
        ax.set_ylim(0, lim)
        ax.set_xlabel(f"requested {what}")
        ax.set_ylabel(f"obtained {what}")
        ax.set_title(("energy" if what == "R" else "variance") + " (o forward model" + (", x simulation)" if simulate else ")"))
    fig.tight_layout()
    return fig


def profile_figure(r: CaseResult):
    """Ring energies per unit theta_v (log scale) of the simulated slice with the fitted lobes and
    Belcour's forward prediction, per channel."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    rings = r.rings
    assert rings is not None and r.simulated is not None
    edges = rings.theta_h_edges
    tv = np.degrees(2.0 * edges)
    width = np.diff(tv)
    centre = 0.5 * (tv[:-1] + tv[1:])
    fs = belcour.stack_statistics(r.inversion.stack(), 1.0)
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8), sharey=True)
    for ch, ax in enumerate(axes):
        d = rings.energy[ch] / width
        ax.errorbar(centre, d, yerr=rings.stderr[ch] / width, fmt=".", ms=3, color="k", lw=0.6, label="simulation")
        ax.plot(centre, rings.order1[ch] / width, ".", ms=2, color="0.6", label="simulation, order 1")
        total = np.zeros_like(d)
        for g in r.simulated["groups"]:
            a = g["alpha"][ch]
            if not np.isfinite(a):
                continue
            m = g["R"][ch] * lobe_ring_fractions(edges, a) / width
            total += m
            ax.plot(centre, m, "--", lw=1, label=f"fit {g['part']}: lobe(s) {g['lobes']}")
        ax.plot(centre, total, "-", color="tab:orange", lw=1.2, label="fit total")
        fw = np.zeros_like(d)
        for lobe in fs.lobes:
            a = variance_to_roughness(lobe.variance[ch])
            if lobe.energy[ch] > 0:
                fw += lobe.energy[ch] * lobe_albedo(a) * lobe_ring_fractions(edges, a) / width
        ax.plot(centre, fw, ":", color="tab:purple", lw=1.4, label="Belcour forward")
        ax.set_yscale("log")
        ax.set_xscale("log")
        ax.set_xlim(centre[0] / 1.5, 95.0)
        ax.set_xlabel("theta_v (deg)")
        ax.set_title("RGB"[ch])
        pos = d[d > 0]
        if pos.size:
            ax.set_ylim(max(pos.min() * 0.3, pos.max() * 1e-6), pos.max() * 3)
    axes[0].set_ylabel("ring energy / dtheta_v (1/deg)")
    axes[0].legend(fontsize=7)
    fig.suptitle(r.case.name)
    fig.tight_layout()
    return fig


def _html(markdown_text: str) -> str:
    """A minimal HTML rendering of the markdown report (headings, tables, images, paragraphs)."""
    import html as H
    out = ["<!doctype html><meta charset='utf-8'><title>Inverse validation</title>",
           "<style>body{font-family:sans-serif;max-width:1200px;margin:auto}table{border-collapse:collapse;"
           "font-size:13px}td,th{border:1px solid #ccc;padding:2px 6px}img{max-width:100%}</style>"]
    in_table = False
    for line in markdown_text.splitlines():
        if line.startswith("|"):
            cells = [c.strip() for c in line.strip("|").split("|")]
            if set("".join(cells)) <= set("-"):
                continue
            if not in_table:
                out.append("<table>")
                in_table = True
                out.append("<tr>" + "".join(f"<th>{H.escape(c)}</th>" for c in cells) + "</tr>")
            else:
                out.append("<tr>" + "".join(f"<td>{H.escape(c)}</td>" for c in cells) + "</tr>")
            continue
        if in_table:
            out.append("</table>")
            in_table = False
        if line.startswith("# "):
            out.append(f"<h1>{H.escape(line[2:])}</h1>")
        elif line.startswith("## "):
            out.append(f"<h2>{H.escape(line[3:])}</h2>")
        elif line.strip().startswith("![") and "](" in line:
            src = line.split("](", 1)[1].rstrip(")").strip()
            out.append(f"<p><img src='{H.escape(src)}'></p>")
        elif line.strip():
            out.append(f"<p>{H.escape(line)}</p>")
    if in_table:
        out.append("</table>")
    return "\n".join(out) + "\n"


def write_report(results: Sequence[CaseResult], out_dir: str | os.PathLike, simulate: bool) -> dict[str, Path]:
    """Write ``report.md``, ``index.html``, ``validation.json`` and the figures into ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    figures: dict[str, str] = {}
    achieved = [r for r in results if r.achievable]
    if achieved:
        _save_figure(scatter_figure(achieved, simulate), out / "figure25.png")
        figures["scatter"] = "figure25.png"
    for i, r in enumerate(achieved):
        if r.rings is not None and r.simulated is not None:
            name = f"profile-{i:02d}.png"
            _save_figure(profile_figure(r), out / name)
            figures[r.case.name] = name
    md = report_markdown(results, simulate, figures)
    _atomic_bytes(out / "report.md", md.encode())
    _atomic_bytes(out / "index.html", _html(md).encode())
    write_json(out / "validation.json", validation_json(results, simulate))
    return {"markdown": out / "report.md", "html": out / "index.html", "json": out / "validation.json"}


# ============================================================================ equivalence-class figures

_CH = ("tab:red", "tab:green", "tab:blue")


def save_png(fig, path: str | os.PathLike) -> None:
    """Save a matplotlib figure as PNG atomically."""
    _save_figure(fig, Path(path))


def _panel_empty(ax, title: str, reason: str | None) -> None:
    import textwrap
    ax.set_title(title, fontsize=9)
    ax.text(0.5, 0.5, "not physically achievable:\n" + textwrap.fill(reason or "", 50), ha="center", va="center",
            fontsize=7, transform=ax.transAxes, color="firebrick")
    ax.set_xticks([])
    ax.set_yticks([])


def _panel_dielectric1(ax, cls: inverse.OneLayerDielectricClass, sol) -> None:
    """Figure 4a / 6 style: R_{n,n+1} = FGD(alpha~, eta1 / eta_n) against eta1 with the targets R'."""
    o = cls.context.options
    etas = np.linspace(1.0, o.eta_max, 300)
    for c in range(3):
        r = [inverse._fgd(o, cls.alpha_lookup[c], e / cls.context.eta) for e in etas]
        ax.plot(etas, r, color=_CH[c], lw=1)
        ax.axhline(cls.r_prime[c], color=_CH[c], ls="--", lw=0.8)
    for name, iv in cls.branches.items():
        ax.axvspan(iv.lo, max(iv.hi, iv.lo + 1e-3), color="0.85", zorder=0)
    if sol is not None:
        e1 = sol.choices["eta1"]
        ax.plot([e1], [inverse._fgd(o, cls.alpha, e1 / cls.context.eta)], "kx", ms=8)
    ax.set_xlabel("eta1")
    ax.set_ylabel("R_{n,n+1} (FGD at normal incidence)")
    ax.set_title(f"1-layer dielectric (eta_n={cls.context.eta:.3g}, alpha={cls.alpha:.3g}); dashed: R' per channel",
                 fontsize=9)


def _panel_conductor(ax, samples: dict, chosen: tuple | None, eta_n: float, title: str) -> None:
    """Figure 4b/c style: kappa against eta along the conductor class, per channel."""
    e, k = samples["eta1"], samples["kappa1"]
    for c in range(3):
        ax.plot(e[:, c], k[:, c], color=_CH[c], lw=1.5)
    if chosen is not None:
        for c in range(3):
            ax.plot([chosen[0][c]], [chosen[1][c]], "x", color=_CH[c], ms=8)
    lim = np.nanmax(e) * 1.1 if np.isfinite(np.nanmax(e)) else 2.0
    ax.plot([0, lim], [0, lim], "k:", lw=0.8, label="kappa = eta")
    ax.set_xlabel("eta (real part)")
    ax.set_ylabel("kappa")
    ax.set_title(title, fontsize=9)


def _panel_dielectric2(ax, cls: inverse.TwoLayerClass, sol) -> None:
    """Figures 9b / 11 / 12 style: the class in the (eta1, eta2) plane coloured by tau1, with the
    per-channel tau1 = 0 isolines, the eta_max box and eta_sigma_max."""
    smp = cls.sample(40, 40)
    o = cls.context.options
    if smp.get("eta2") is not None and smp["eta2"].size:
        t = np.max(smp["tau1"], axis=1)
        # tau1 diverges where R'_12 -> 0 (edge of N1): clip the colour scale at the 90th percentile
        vmax = max(float(np.percentile(t, 90)), 1e-6)
        sc = ax.scatter(smp["eta1_of_sample"], smp["eta2"], c=np.minimum(t, vmax), s=6, cmap="viridis", vmin=0,
                        vmax=vmax)
        import matplotlib.pyplot as plt
        plt.colorbar(sc, ax=ax, label="max tau1")
    if smp["eta1"].size:
        for c in range(3):
            ax.plot(smp["eta1"], smp["root_lower"][:, c], color=_CH[c], lw=1)
            ax.plot(smp["eta1"], smp["root_upper"][:, c], color=_CH[c], lw=1)
    ax.add_patch(__import__("matplotlib.patches", fromlist=["Rectangle"]).Rectangle(
        (1, 1), o.eta_max - 1, o.eta_max - 1, fill=False, ls="--", color="0.4"))
    if math.isfinite(cls.eta_sigma_max):
        ax.axvline(cls.eta_sigma_max, color="0.3", ls="-.", lw=1, label="eta_sigma_max")
    for iv in cls.n1:
        ax.axvspan(iv.lo, iv.hi, ymax=0.03, color="k", alpha=0.6)
    if sol is not None:
        ax.plot([sol.choices["eta1"]], [sol.choices["eta2"]], "rx", ms=9, mew=2)
    ax.set_xlim(0.9, o.eta_max + 0.2)
    ax.set_ylim(0.9, o.eta_max + 0.2)
    ax.set_xlabel("eta1 (bar: N1)")
    ax.set_ylabel("eta2")
    ax.set_title(f"2-layer dielectric (tau0={_f(cls.tau0, '.3g')}); lines: tau1 = 0 per channel", fontsize=9)


def _panel_conductor2_eq(ax, cls: inverse.TwoLayerClass, sol) -> None:
    """Figure 16 (left) style: eta1 against the equivalent index of the conductor at tau1 = 0
    (the class extends upwards: tau1 > 0 raises the required reflectance)."""
    smp = cls.sample(60, 1)
    if smp["eta1"].size:
        rp = smp["R_prime"]
        for c in range(3):
            s = np.sqrt(np.clip(rp[:, c], 0, 0.999999))
            eq = smp["eta1"] * (1 + s) / (1 - s)
            ax.plot(smp["eta1"], eq, color=_CH[c], lw=1)
            ax.fill_between(smp["eta1"], eq, np.nanmax(eq) * 2, color=_CH[c], alpha=0.07)
    if sol is not None:
        eqs = sol.info.get("eta2_equivalent")
        for c in range(3):
            ax.plot([sol.choices["eta1"]], [eqs[c]], "x", color=_CH[c], ms=8)
    ax.set_xlabel("eta1")
    ax.set_ylabel("equivalent eta2 (tau1 = 0 at the curve)")
    ax.set_title("2-layer conductor: (eta1, equivalent index), section 5.2.4", fontsize=9)


def _panel_tau_slice(ax, cls: inverse.TwoLayerClass, sol) -> None:
    """Figure 9c style: tau1 per channel along N2 at the chosen eta1 (eq. 13)."""
    pt = cls.at(sol.choices["eta1"])
    for iv in pt.n2:
        e2 = np.linspace(iv.lo, iv.hi, 120)
        t = np.array([cls.tau1_at(pt, float(e)) for e in e2])
        for c in range(3):
            ax.plot(e2, t[:, c], color=_CH[c], lw=1)
    ax.plot([sol.choices["eta2"]] * 3, sol.choices["tau1"], "kx", ms=7)
    ax.set_xlabel("eta2 (N2 at the chosen eta1)")
    ax.set_ylabel("tau1 (eq. 13)")
    ax.set_title(f"slice eta1 = {sol.choices['eta1']:.4g}", fontsize=9)


def classes_figure(inv: Inversion):
    """One row per lobe with its equivalence class in the context of the lobes chosen above it
    (figures 4, 7, 9, 11, 12 and 16 of the paper, in that spirit); crosses mark the chosen point."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    classes = inv.classes
    n = max(1, len(classes))
    fig, axes = plt.subplots(n, 2, figsize=(11, 3.9 * n), squeeze=False)
    for k, cls in enumerate(classes):
        sol = inv.solutions[k] if k < len(inv.solutions) else None
        a0, a1 = axes[k]
        title = f"lobe {k + 1}: {cls.lobe.describe()}"
        a1.axis("off")
        if not cls.achievable:
            _panel_empty(a0, title, cls.reason)
            continue
        if cls.kind == "dielectric-1":
            _panel_dielectric1(a0, cls, sol)
        elif cls.kind == "conductor-1":
            smp = cls.sample(48)
            chosen = None if sol is None else (np.asarray(sol.choices["eta1"]), np.asarray(sol.info["kappa1"]))
            _panel_conductor(a0, smp, chosen, cls.context.eta,
                             f"1-layer conductor (eta_n={cls.context.eta:.3g}; eqs. 8-10)")
        elif cls.kind == "dielectric-2":
            _panel_dielectric2(a0, cls, sol)
            if sol is not None:
                a1.axis("on")
                _panel_tau_slice(a1, cls, sol)
        else:
            _panel_conductor2_eq(a0, cls, sol)
            if sol is not None:
                a1.axis("on")
                o = cls.context.options
                pt = cls.at(sol.choices["eta1"])
                tgt = pt.r_prime * np.exp(2.0 * np.asarray(sol.choices["tau1"]))
                us = np.linspace(0, 1, 40)
                e = np.full((40, 3), np.nan)
                kk = np.full((40, 3), np.nan)
                for c in range(3):
                    for i, u in enumerate(us):
                        r = inverse._conductor_point(o, pt.alpha_lookup[c], tgt[c], pt.eta1, u=float(u))
                        if not isinstance(r, str):
                            e[i, c], kk[i, c] = r[0], r[1]
                _panel_conductor(a1, {"eta1": e, "kappa1": kk},
                                 (np.asarray(sol.choices["eta2"]), np.asarray(sol.info["kappa2"])), pt.eta1,
                                 f"its conductor base at tau1={_f(sol.choices['tau1'], '.3g')}")
        a0.set_title(title + "\n" + a0.get_title(), fontsize=9)
    fig.tight_layout()
    return fig
