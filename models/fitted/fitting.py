"""Fit a family to the BRDF of one simulated file (:func:`fit`, :class:`FitResult`): bounded
nonlinear least squares from several starts, colour parameters solved linearly before each start,
the problem handed to the optimiser in a compressed form (:class:`_Problem`), parameter standard
errors from the reference's Monte Carlo errors. The optimiser, its starts and the NaN guard:
``docs/fitted.md``, "Fitting".
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from goniometer.run.results import SimulationResult, SliceData
from models._jit import njit
from models.base import ModelError
from models.compare import compare, integrate
from models.compare.errors import NoCellsError, require_cells
from models.fitted.data import FitData, fit_data
from models.fitted.family import Family
from models.fitted.ggx import GGXFamily
from models.fitted.model import FAMILIES, FittedModel, model_class

#: value that replaces a non-finite model cell value inside the optimiser (1/sr)
NONFINITE_VALUE = 1e12


@dataclass
class FitResult:
    """The outcome of :func:`fit`. Every number is finite.

    ``params``: natural parameters by name (scalars or RGB lists); ``param_stderr``: their
    standard errors propagated from the reference's Monte Carlo standard errors through the
    weighted least-squares problem (sandwich estimate at the solution; ``None`` where the data do
    not constrain a parameter at all; meaningless for a parameter sitting on a bound).
    ``cost``: ``0.5 sum r^2`` of the best start (the weighting: :mod:`models.fitted.data`);
    ``converged``/``message``: from ``least_squares`` for the best start; ``errors``:
    ``{"internal": E, "total": E}`` (eq. 4, the same comparison twice) of the fitted model
    integrated onto the reference cells with ``s = 5``. ``n_cells``: the cells fitted (the paper
    weighting leaves out grazing ones); ``cells``, ``cells_total``: the reference's valid cells of
    its grid's (:class:`models.compare.errors.Coverage`).
    """

    kind: str
    params: dict[str, float | list[float]]
    cost: float
    converged: bool
    message: str
    model: FittedModel
    errors: dict | None = None
    param_stderr: dict[str, float | list[float | None] | None] = field(default_factory=dict)
    starts: int = 0
    nfev: int = 0
    n_cells: int = 0
    subcells: int = 1
    peak_subcells: int = 1
    weighting: str = "paper"
    elapsed_s: float = 0.0
    costs: list[float] = field(default_factory=list)
    cells: int = 0
    cells_total: int = 0

    @property
    def name(self) -> str:
        return self.model.name

    def to_json(self) -> dict:
        """A JSON-ready summary (what ``gonio fit --json`` may print)."""
        return {
            "model": self.model.name, "kind": self.kind, "params": self.params,
            "param_stderr": self.param_stderr, "cost": self.cost, "converged": self.converged,
            "message": self.message, "errors": self.errors, "starts": self.starts, "nfev": self.nfev,
            "n_cells": self.n_cells, "cells": self.cells, "cells_total": self.cells_total,
            "subcells": self.subcells, "peak_subcells": self.peak_subcells,
            "weighting": self.weighting,
            "elapsed_s": self.elapsed_s,
        }


@njit(cache=True, fastmath={"reassoc", "contract"})
def _gram(f: np.ndarray, V: np.ndarray, cols: np.ndarray, ref: np.ndarray, sw: np.ndarray, d: np.ndarray,
          big: float, n: int):
    """Normal equations of the weighted residuals (no (m x n) temporaries, no BLAS threads).

    Residual of cell ``i``, channel ``c``: ``r = sw_i (f_ic - ref_ic)``; its Jacobian row has
    ``sw_i V[c, k, i]`` in column ``cols[c, k]`` (see :data:`SparseJac`). Returns
    ``(J^T diag(d) J, J^T r, r^T r)`` with ``n`` columns. Non-finite model values count as
    ``big`` and non-finite Jacobian entries as 0 (the NaN guard of ``docs/fitted.md``).
    """
    n_cells = f.shape[0]
    K = cols.shape[1]
    G = np.zeros((n, n))
    g = np.zeros(n)
    rr = 0.0
    r = np.empty(n_cells)
    rows = np.empty((K, n_cells))
    rows_d = np.empty(n_cells)
    for c in range(3):
        for i in range(n_cells):
            fv = f[i, c]
            if not math.isfinite(fv):
                fv = big
            r[i] = sw[i] * (fv - ref[i, c])
            rr += r[i] * r[i]
        for a in range(K):
            for i in range(n_cells):
                x = V[c, a, i]
                rows[a, i] = sw[i] * x if math.isfinite(x) else 0.0
        for a in range(K):
            ca = cols[c, a]
            ra = rows[a]
            acc = 0.0
            for i in range(n_cells):
                acc += ra[i] * r[i]
            g[ca] += acc
            for i in range(n_cells):
                rows_d[i] = ra[i] * d[i, c]
            for b in range(a, K):
                cb = cols[c, b]
                rb = rows[b]
                acc = 0.0
                for i in range(n_cells):
                    acc += rows_d[i] * rb[i]
                G[ca, cb] += acc
                if b != a:
                    G[cb, ca] += acc
    return G, g, rr


def _square_root(G: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(R, t)`` (n, n) and (n,) with ``R^T R = G`` and ``R^T t = g`` (for ``g`` in the range of ``G``).

    Eigen-decomposition of the column-scaled ``G`` (robust to rank deficiency: eigenvalues below
    1e-14 of the largest are dropped, their rows of ``R`` are 0).
    """
    n = G.shape[0]
    d = np.sqrt(np.maximum(np.diag(G), 0.0))
    d = np.where(d > 0, d, 1.0)
    lam, V = np.linalg.eigh(G / np.outer(d, d))
    keep = lam > max(lam.max(), 0.0) * 1e-14
    R = np.zeros((n, n))
    t = np.zeros(n)
    if keep.any():
        sq = np.sqrt(lam[keep])
        R[: keep.sum()] = (sq[:, None] * V[:, keep].T) * d[None, :]
        t[: keep.sum()] = (V[:, keep].T @ (g / d)) / sq
    return R, t


class _Problem:
    """The weighted residuals ``r = sqrt(W) (f - ref)`` (n_cells * 3) of one family on one data set.

    ``least_squares`` is given an equivalent **compressed** problem of n + 1 residuals: with
    ``R^T R = J^T J`` and ``R^T t = J^T r`` (:func:`_square_root`), the residual vector
    ``[t, sqrt(|r|^2 - |t|^2)]`` and Jacobian ``[R; 0]`` have exactly the cost, gradient and
    Gauss-Newton matrix of the full problem, so every trust-region step, the cost and the
    termination tests are the same; but the optimiser's dense linear algebra (an SVD per
    iteration) runs on an (n+1) x n matrix instead of a (3 n_cells) x n one. (On a shared machine
    a multithreaded BLAS on the tall matrix was 5-30x slower than the whole model evaluation.)
    Because the compressed residual needs ``J``, each new point evaluates the Jacobian too; the
    last point is cached, so the usual call ``fun(z)`` then ``jac(z)`` costs one evaluation.
    """

    def __init__(self, family: Family, data: FitData) -> None:
        self.family = family
        self.data = data
        self.sw = np.ascontiguousarray(np.sqrt(data.weight))
        self._ones = np.ones(data.ref.shape)
        self._z: np.ndarray | None = None
        self._cache: tuple | None = None

    def _point(self, z: np.ndarray) -> tuple:
        """Evaluate (cached) at internal point ``z``: ``(G, g, rr, comp_r, comp_J)``."""
        if self._z is not None and np.array_equal(z, self._z):
            return self._cache
        f, (V, cols) = self.family.cells_and_jac(z, self.data.samples, True)
        G, g, rr = _gram(f, V, cols, self.data.ref, self.sw, self._ones, NONFINITE_VALUE, self.family.size)
        R, t = _square_root(G, g)
        extra = math.sqrt(max(0.0, rr - float(t @ t)))
        comp_r = np.concatenate([t, [extra]])
        comp_J = np.vstack([R, np.zeros((1, R.shape[1]))])
        self._z = z.copy()
        self._cache = (G, g, rr, comp_r, comp_J, f, V, cols)
        return self._cache

    def gram(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(J^T J, J^T r)`` of the full weighted problem at ``z``."""
        c = self._point(z)
        return c[0], c[1]

    def cost(self, z: np.ndarray) -> float:
        """``0.5 |r|^2`` of the full weighted problem at ``z``."""
        return 0.5 * self._point(z)[2]

    def residuals(self, z: np.ndarray) -> np.ndarray:
        """Compressed residuals (n + 1,)."""
        return self._point(z)[3]

    def jacobian(self, z: np.ndarray) -> np.ndarray:
        """Compressed Jacobian (n + 1, n)."""
        return self._point(z)[4]

    def sandwich(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(J^T J, J^T diag(W se^2) J)`` at ``z`` (for parameter standard errors)."""
        G, _, _, _, _, f, V, cols = self._point(z)
        var_r = np.ascontiguousarray((self.data.stderr * self.sw[:, None]) ** 2)  # variance of each residual
        B, _, _ = _gram(f, V, cols, self.data.ref, self.sw, var_r, NONFINITE_VALUE, self.family.size)
        return G, B

    def linear_init(self, z: np.ndarray) -> np.ndarray:
        """Solve the affine (colour) parameters by bounded linear least squares, others fixed.

        The residual is affine in them: ``r(z_lin) = r0 + J_lin (z_lin - z_lin0)``; the bounded
        problem is solved in its compressed (Gram square-root) form.
        """
        lin = self.family.linear_mask()
        if not lin.any():
            return z
        lo, hi = self.family.internal_bounds()
        G, g = self.gram(z)
        Gl = G[np.ix_(lin, lin)]
        # min |J_l x + (r0 - J_l x0)|^2  <=>  min x^T Gl x - 2 x^T gl
        gl = Gl @ z[lin] - g[lin]
        R, t = _square_root(Gl, gl)
        if not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
            return z
        from scipy.optimize import lsq_linear   # here: scipy.optimize takes 0.4 s to import (gonio models)
        try:
            sol = lsq_linear(R, t, bounds=(lo[lin], hi[lin]), method="bvls")
        except (ValueError, np.linalg.LinAlgError):  # pragma: no cover - degenerate data
            return z
        out = z.copy()
        out[lin] = np.clip(sol.x, lo[lin], hi[lin])
        return out


def _stderr(problem: _Problem, z: np.ndarray) -> np.ndarray:
    """Sandwich standard errors of the natural parameters at ``z`` (NaN where unconstrained).

    ``Cov = (J^T J)^+ J^T diag(W se^2) J (J^T J)^+`` with ``se`` the reference's standard errors,
    computed on column-scaled matrices; converted from internal to natural coordinates.
    """
    G, Bm = problem.sandwich(z)
    norms = np.sqrt(np.maximum(np.diag(G), 0.0))
    ok = norms > 0
    out = np.full(G.shape[0], np.nan)
    if ok.any():
        dn = np.outer(norms[ok], norms[ok])
        A = np.linalg.pinv(G[np.ix_(ok, ok)] / dn, rcond=1e-12, hermitian=True)
        cov = A @ (Bm[np.ix_(ok, ok)] / dn) @ A
        out[ok] = np.sqrt(np.maximum(np.diag(cov), 0.0)) / norms[ok]
    fam = problem.family
    x = fam.to_natural(z)
    for s, sl in zip(fam.specs, fam.slices().values()):
        out[sl] = out[sl] * (x[sl] if s.log else fam.scale(s))
    return out


def _stderr_dict(family: Family, se: np.ndarray) -> dict:
    out: dict = {}
    for s, sl in zip(family.specs, family.slices().values()):
        vals = [float(t) if np.isfinite(t) else None for t in se[sl]]
        out[s.name] = vals[0] if s.size == 1 else vals
    return out


def _run_starts(problem: _Problem, starts: list[np.ndarray], max_nfev: int,
                progress: Callable[[int, float], None] | None):
    """Run ``least_squares`` from every start (natural coordinates); return all results."""
    from scipy.optimize import least_squares   # here: scipy.optimize takes 0.4 s to import (gonio models)
    fam = problem.family
    lo, hi = fam.internal_bounds()
    results = []
    for k, x0 in enumerate(starts):
        z0 = np.clip(fam.to_internal(np.clip(x0, *fam.bounds())), lo, hi)
        z0 = problem.linear_init(z0)
        res = least_squares(problem.residuals, z0, jac=problem.jacobian, bounds=(lo, hi), method="trf",
                            max_nfev=max_nfev, x_scale=1.0)
        results.append(res)
        if progress is not None:
            progress(k, float(res.cost))
    return results


def _best(results: list) -> object:
    """The start with the lowest cost; a converged start within 1e-6 (relative) of it is preferred.

    (A flat valley -- e.g. two GGX lobes fitting data that have one -- can leave a start crawling
    to a cost lower by 1e-9 when its budget runs out while another has converged.)
    """
    best = min(results, key=lambda r: r.cost)
    if best.status > 0:
        return best
    ok = [r for r in results if r.status > 0 and r.cost <= best.cost * (1.0 + 1e-6) + 1e-300]
    return min(ok, key=lambda r: r.cost) if ok else best


def _finite_slices(sd: SliceData) -> SliceData:
    """``sd`` with cells holding non-finite reference values masked out (and zeroed) for the errors.

    Simulated files never hold such values; this keeps a hand-made reference from turning the
    reported errors into NaN. A measured reference's standard errors are NaN everywhere (unknown:
    its noise floor is reported as unknown, ``models.compare.errors``); they do not mask a cell.
    Returns ``sd`` itself when every value is finite.
    """
    bad = ~np.all(np.isfinite(sd.value), axis=1)
    if not bad.any():
        return sd
    keep = ~bad[:, None]
    return replace(sd, value=np.where(keep, sd.value, 0.0), stderr=np.where(keep, sd.stderr, 0.0),
                   mask=sd.mask & ~bad)


def _sort_lobes(family: Family, x: np.ndarray) -> np.ndarray:
    """GGX2: put the sharper lobe (smaller alpha) first."""
    if not isinstance(family, GGXFamily) or family.n_lobes != 2:
        return x
    s = family.slices()
    if x[s["alpha_1"]][0] <= x[s["alpha_2"]][0]:
        return x
    y = x.copy()
    for a, b in (("ks_1", "ks_2"), ("F0_1", "F0_2"), ("alpha_1", "alpha_2")):
        y[s[a]], y[s[b]] = x[s[b]], x[s[a]]
    return y


def fit(reference: SimulationResult, kind: str, *, side: str = "brdf", starts: int = 4, seed: int = 0,
        subcells: int | None = None, peak_subcells: int | None = None, weighting: str = "paper",
        max_nfev: int = 200, errors: bool = True,
        progress: Callable[[int, float], None] | None = None) -> FitResult:
    """Fit ``kind`` ("hp15", "ggx1", "ggx2") to every incident direction of ``reference``'s BRDF.

    ``starts``: number of optimiser starts (start 0 typical values, the others random from
    ``seed``); ggx2 adds one start at the best of a ggx1 fit with ``max(1, starts // 2)`` starts.
    ``subcells``/``peak_subcells``: sub-cells per axis inside the optimiser, away from / within
    8 degrees of the mirror direction (None: automatic, :func:`models.fitted.data.fit_data`).
    ``weighting``: "paper" (eq. 29, grazing directions left out) or "eq4". ``max_nfev``:
    evaluation budget per start. ``errors``: also integrate the fitted model (s = 5) and compute
    eq. 4 errors. ``progress(start, cost)`` is called after each start. Raises
    :class:`ModelError` for a BTDF request or a reference without BRDF slices, and
    :class:`models.compare.errors.NoCellsError` for a reference without a valid BRDF cell. A spectral reference
    is fitted in linear sRGB (:meth:`SimulationResult.rgb`, docs/spectral.md).
    """
    reference = reference.rgb()
    cls = model_class(kind)
    if side != "brdf":
        raise ModelError(f"{cls.name}: fitted models are BRDF models; cannot fit the {side.upper()}")
    if reference.brdf is None:
        raise ModelError(f"{cls.name}: the file has no BRDF slices to fit (fitted models are BRDF-only)")
    if starts < 1:
        raise ModelError(f"{cls.name}: starts = {starts} must be >= 1")
    try:
        cov = require_cells(reference, "brdf")
    except NoCellsError as e:
        raise NoCellsError(f"{cls.name}: {e}", e.coverage) from None
    t0 = time.perf_counter()
    data = fit_data(reference, subcells, weighting, peak_subcells=peak_subcells)
    family = FAMILIES[cls.kind]()
    problem = _Problem(family, data)
    rng = np.random.default_rng(seed)
    points = [family.start_point()] + [family.random_point(rng) for _ in range(starts - 1)]
    nfev = 0
    if cls.kind == "ggx2":
        g1 = FAMILIES["ggx1"]()
        n1 = max(1, starts // 2)
        sub = _run_starts(_Problem(g1, data), [g1.start_point()] + [g1.random_point(rng) for _ in range(n1 - 1)],
                          max_nfev, None)
        nfev += sum(r.nfev for r in sub)
        best1 = g1.to_natural(min(sub, key=lambda r: r.cost).x)
        s1, s2 = g1.slices(), family.slices()
        nested = family.start_point()
        for name in ("kd",):
            nested[s2[name]] = best1[s1[name]]
        for name in ("ks", "F0", "alpha"):
            nested[s2[name + "_1"]] = best1[s1[name]]
        nested[s2["ks_2"]] = 0.0
        nested[s2["alpha_2"]] = min(1.0, 4.0 * best1[s1["alpha"]][0])
        points.append(nested)
    results = _run_starts(problem, points, max_nfev, progress)
    best = _best(results)
    nfev += sum(r.nfev for r in results)
    z = best.x
    x = _sort_lobes(family, family.to_natural(z))
    z_sorted = family.to_internal(x)
    model = cls(x)
    se = _stderr(problem, z_sorted)
    converged = bool(best.status > 0)
    msg = str(best.message)
    if not converged:
        msg = f"did not converge: {msg}"
    if data.note:
        msg = f"{msg} ({data.note})"
    result = FitResult(
        kind=cls.kind, params=model.params, cost=problem.cost(z_sorted), converged=converged, message=msg,
        model=model, param_stderr=_stderr_dict(family, se), starts=len(points), nfev=int(nfev),
        n_cells=data.samples.n_cells, subcells=data.subcells, peak_subcells=data.peak_subcells, weighting=weighting,
        costs=[float(r.cost) for r in results], cells=cov.cells, cells_total=cov.cells_total,
    )
    if errors:
        ms = integrate(model, reference, "brdf", s=5)
        result.errors = compare(_finite_slices(reference.brdf), ms, drop_first_order=False,
                                cells_total=cov.cells_total)
    result.elapsed_s = time.perf_counter() - t0
    return result
