"""Statistical checks of Monte Carlo results: the ones the project's tests use, for plugin authors'
tests too (``docs/testing.md``; Mitsuba 3 ships its chi-square harness, ``mitsuba.chi2``, in its
library for the same reason: one set of statistics for the renderer's tests and its users').

Every check is a hypothesis test at one **false-alarm probability**, :data:`P_FALSE_ALARM` =
1e-6: a correct simulator (or model) fails a given check once in a million runs, so a suite of
thousands of checks stays quiet, while a real error of a few per cent on a well-sampled quantity is
many standard errors away and fails. :data:`Z_TOL` (about 4.9) is the matching number of standard
errors of a two-sided normal check, :func:`chi2_limit` the matching upper limit of a chi-square
statistic, :func:`chi2_interval` its two-sided band, :func:`noise_floor_ratio_limit` the largest ratio of
an RMSE to its noise floor that a perfect model shows.

**Cells against a model** (:func:`cell_chi2`, :func:`assert_cells_match`). A cell value of a slice
(``docs/slices-format.md``) is ``sum of exit weights / (N Omega)``: a sum of rare weighted exits.
The statistic is ``sum z^2`` over the judged cells, ``z = (sim - model) / sigma``, against
:func:`chi2_limit` of as many degrees of freedom as cells. Three rules make it honest:

* **Which cells.** A cell is judged where the *model* expects at least ``min_expected`` exits
  (about 20; :data:`MIN_EXPECTED` = 25 by default): ``N f Omega`` is the cell's expected weight,
  and with exit weights of at most 1 no fewer exits than that. Below about 20 exits a cell's
  estimate is skewed (a sum of a Poisson number of weights), ``z^2`` is no longer a chi-square of
  one degree and the false-alarm probability no longer holds. The selection uses the model, not the simulation, so
  it does not depend on the noise: selecting on the simulated value would keep cells that happened
  to be hit often and drop those hit rarely, and bias the statistic.
* **Sparse regions in aggregate** (:func:`sparse_flux`, :func:`assert_sparse_flux_matches`).
  The cells left out (a grazing tail, the dark side of a lobe) are not ignored: their total flux
  ``sum f Omega`` is compared with the model's, within :data:`Z_TOL` of its standard error plus
  one exit's worth (``1 / N``).
* **Whose sigma.** A cell's variance is taken under the model: ``Var ~ mean x (mean squared weight
  / mean weight) / (N Omega)``, the mean from the model, the weight ratio from the simulation, so
  ``sigma = stderr_sim sqrt(model / sim)`` (:func:`model_sigma`). The raw sample stderr is
  correlated with the deviation at low counts (a cell hit more often than expected also shows a
  larger sample variance) and biases the statistic upwards; a cell the simulation never hit gets
  the bound ``sqrt(model / (N Omega))`` (weights of at most 1). A stochastic model's own standard
  error, where it has one, adds in quadrature (``model_stderr``).

**Two simulations against each other** (:func:`two_sample_chi2`, :func:`assert_samples_match`):
``z = (a - b) / sqrt(sa^2 + sb^2)`` over cells the caller selects (by both samples' expected or
effective exits, :func:`effective_exits`, never by one sample's noise alone); raw sums of weights
and of squared weights become means and standard errors with :func:`mean_stderr`.

**Values and energies** (:func:`assert_z_close`, :func:`assert_energy_matches`,
:func:`energy_total`, :func:`assert_energy_conserved`). A value against a closed form or another
estimate: within :data:`Z_TOL` combined standard errors, plus a stated bound ``extra`` (a closed
form's own quadrature error, a documented bias). The energy books of a result (the terms of
:data:`~goniometer.run.results.ENERGY_TERMS`, the roulette balance and the capped weight) close
path by path, so they are checked to rounding, not within standard errors.

Shapes: a check works on arrays of any shape (per incident direction, channel and cell, or one of
them); ``omega`` (projected solid angles, ``SliceData.proj_solid_angle``) broadcasts against the
values, e.g. ``proj_solid_angle[:, None]`` for every channel. The library raises ``ValueError``
(naming the argument) on input it cannot judge and ``AssertionError`` when a check fails.
"""

from __future__ import annotations

import math
from numbers import Integral, Real
from typing import Any

import numpy as np
from scipy import optimize, stats

from goniometer.run.results import ENERGY_TERMS

#: false-alarm probability of every statistical check (one check in a million fails by chance)
P_FALSE_ALARM: float = 1e-6
#: standard errors of a two-sided normal check at P_FALSE_ALARM (about 4.9)
Z_TOL: float = float(stats.norm.isf(P_FALSE_ALARM / 2))
#: the least number of exits the model must expect in a cell for the cell to be judged on its own
MIN_EXPECTED: float = 25.0
#: the least number of judged cells for a check that means something (:func:`assert_cells_match`)
MIN_CELLS: int = 100

__all__ = [
    "P_FALSE_ALARM", "Z_TOL", "MIN_EXPECTED", "MIN_CELLS",
    "chi2_limit", "chi2_interval", "noise_floor_ratio_limit",
    "expected_exits", "model_sigma", "cell_chi2", "assert_cells_match", "flux", "sparse_flux",
    "assert_sparse_flux_matches",
    "mean_stderr", "effective_exits", "two_sample_chi2", "assert_samples_match",
    "assert_z_close", "energy_total", "assert_energy_conserved", "assert_energy_matches",
]


# ---------------------------------------------------------------------- argument checks


def _probability(p: float, name: str = "p") -> float:
    if not isinstance(p, Real) or not 0.0 < float(p) < 1.0:
        raise ValueError(f"{name}: a false-alarm probability must lie in (0, 1), got {p!r}")
    return float(p)


def _dof(dof: int) -> int:
    if isinstance(dof, bool) or not isinstance(dof, Integral) or dof < 1:
        raise ValueError(f"dof: degrees of freedom must be a whole number >= 1, got {dof!r}")
    return int(dof)


def _rays(rays: int, name: str = "rays") -> int:
    if isinstance(rays, bool) or not isinstance(rays, Integral) or rays < 1:
        raise ValueError(f"{name}: the number of paths must be a whole number >= 1, got {rays!r}")
    return int(rays)


def _positive(x: float, name: str) -> float:
    if isinstance(x, bool) or not isinstance(x, Real) or not np.isfinite(x) or x <= 0:
        raise ValueError(f"{name}: must be a finite number > 0, got {x!r}")
    return float(x)


def _array(x: Any, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if np.isnan(a).any():
        raise ValueError(f"{name}: holds NaN")
    return a


def _same_shape(name: str, a: np.ndarray, ref_name: str, ref: np.ndarray) -> None:
    if a.shape != ref.shape:
        raise ValueError(f"{name}: shape {a.shape} differs from {ref_name}'s {ref.shape}")


def _not_negative(a: np.ndarray, name: str) -> None:
    if (a < 0).any():
        raise ValueError(f"{name}: standard errors and solid angles must be >= 0 (found {a.min():.3g})")


def _cells(sim: Any, stderr: Any, model: Any, omega: Any, rays: int, where: Any
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int, np.ndarray]:
    """The checked arrays of a cell comparison: sim, stderr, model (all of sim's shape), omega and
    the mask broadcast to it, and rays."""
    sim, stderr, model = _array(sim, "sim"), _array(stderr, "stderr"), _array(model, "model")
    _same_shape("stderr", stderr, "sim", sim)
    _same_shape("model", model, "sim", sim)
    omega = _array(omega, "omega")
    try:
        omega = np.broadcast_to(omega, sim.shape)
        mask = np.broadcast_to(np.asarray(True if where is None else where, dtype=bool), sim.shape)
    except ValueError:
        raise ValueError(f"omega, where: shapes {np.shape(omega)}, {np.shape(where)} do not broadcast to the "
                         f"values' {sim.shape}") from None
    _not_negative(stderr, "stderr")
    _not_negative(omega, "omega")
    for name, a in (("sim", sim), ("stderr", stderr), ("model", model)):
        if not np.isfinite(a[mask]).all():
            raise ValueError(f"{name}: not finite in a cell being compared")
    return sim, stderr, model, omega, _rays(rays), mask


# ---------------------------------------------------------------------- limits


def chi2_limit(dof: int, p: float = P_FALSE_ALARM) -> float:
    """Upper limit of a chi-square statistic of ``dof`` degrees of freedom at false-alarm
    probability ``p`` (one-sided: a statistic above it fails)."""
    return float(stats.chi2.isf(_probability(p), _dof(dof)))


def chi2_interval(dof: int, p: float = P_FALSE_ALARM) -> tuple[float, float]:
    """Two-sided band ``(low, high)`` of a chi-square statistic of ``dof`` degrees of freedom,
    ``p / 2`` below and ``p / 2`` above: for a statistic that must be neither too large (errors
    underestimated, or a wrong model) nor too small (errors overestimated), e.g. replicate runs'
    scatter against their stated standard errors."""
    p, dof = _probability(p), _dof(dof)
    return float(stats.chi2.ppf(p / 2, dof)), float(stats.chi2.isf(p / 2, dof))


# ---------------------------------------------------------------------- cells against a model


def expected_exits(model: Any, omega: Any, rays: int) -> np.ndarray:
    """``rays * max(model, 0) * omega``: a cell's expected exit weight under the model, which with
    exit weights of at most 1 bounds its expected number of exits from below."""
    return _rays(rays) * np.maximum(_array(model, "model"), 0.0) * _array(omega, "omega")


def model_sigma(sim: Any, stderr: Any, model: Any, omega: Any, rays: int) -> np.ndarray:
    """Each cell's standard deviation under the model: ``stderr sqrt(model / sim)`` where the
    simulation hit the cell (its mean weight ratio, the model's mean), ``sqrt(model / (N Omega))``
    where it did not (weights of at most 1). Module docstring, "Whose sigma"."""
    sim, stderr, model, omega, rays, _ = _cells(sim, stderr, model, omega, rays, None)
    return _sigma(sim, stderr, np.maximum(model, 0.0), omega, rays)


def _sigma(sim: np.ndarray, stderr: np.ndarray, model: np.ndarray, omega: np.ndarray, rays: int) -> np.ndarray:
    """:func:`model_sigma` of checked arrays, ``model`` already clipped at 0."""
    bound = np.sqrt(model / (rays * np.where(omega > 0, omega, np.inf)))
    hit = (stderr > 0) & (sim > 0)
    return np.where(hit, stderr * np.sqrt(model / np.where(hit, sim, 1.0)), bound)


def cell_chi2(sim: Any, stderr: Any, model: Any, omega: Any, rays: int, min_expected: float = MIN_EXPECTED,
              where: Any = None, model_stderr: Any = None) -> tuple[float, int]:
    """Chi-square of simulated cell values against a model over the cells the model says are well
    hit, and its degrees of freedom (the number of those cells).

    ``sim``, ``stderr``: the simulation's cell values and standard errors (1/sr); ``model``: the
    model's cell means, same shape; ``omega``: the cells' projected solid angles (broadcast);
    ``rays``: paths per incident direction; a cell is judged where ``rays * model * omega >=
    min_expected`` (:func:`expected_exits`) and ``where`` (a mask, broadcast) holds. ``sigma`` is
    :func:`model_sigma`; ``model_stderr`` (a stochastic model's own standard errors, same shape)
    adds in quadrature. Module docstring for the reasons.
    """
    sim, stderr, model, omega, rays, mask = _cells(sim, stderr, model, omega, rays, where)
    min_expected = _positive(min_expected, "min_expected")
    model = np.maximum(model, 0.0)
    sel = (rays * model * omega >= min_expected) & mask
    sigma = _sigma(sim, stderr, model, omega, rays)
    if model_stderr is None:
        z = (sim - model)[sel] / sigma[sel]
    else:
        mse = _array(model_stderr, "model_stderr")
        _same_shape("model_stderr", mse, "sim", sim)
        _not_negative(mse, "model_stderr")
        z = (sim - model)[sel] / np.sqrt(sigma[sel] ** 2 + mse[sel] ** 2)
    return float(np.sum(z * z)), int(np.count_nonzero(sel))


def assert_cells_match(sim: Any, stderr: Any, model: Any, omega: Any, rays: int,
                       min_expected: float = MIN_EXPECTED, where: Any = None, min_cells: int = MIN_CELLS,
                       model_stderr: Any = None) -> tuple[float, int]:
    """:func:`cell_chi2` below :func:`chi2_limit`, over at least ``min_cells`` judged cells (fewer
    would make a check that cannot fail); raises ``AssertionError`` otherwise. Returns
    ``(chi2, dof)``."""
    chi2, dof = cell_chi2(sim, stderr, model, omega, rays, min_expected, where, model_stderr)
    if dof < min_cells:
        raise AssertionError(f"only {dof} cells are hit well enough for a test (at least {min_cells} wanted)")
    limit = chi2_limit(dof)
    if not chi2 < limit:
        raise AssertionError(f"chi2 = {chi2:.1f} over {dof} cells exceeds {limit:.1f} (chi2/dof = {chi2 / dof:.3f})")
    return chi2, dof


def noise_floor_ratio_limit(stderr: Any, weight: Any, axis: int | tuple[int, ...] | None = None,
                            p: float = P_FALSE_ALARM) -> np.ndarray:
    """The largest ratio of an RMSE to its noise floor (``docs/models.md`` §3, eq. 4: ``sqrt(sum w
    (ref - model)^2)`` against ``sqrt(sum w stderr^2)``, sums over ``axis``, all by default) that a
    perfect model exceeds with probability at most ``p``; NaN where the noise floor is 0.

    For a perfect model the differences are the reference's errors, independent and about normal
    with variances ``stderr^2``, so the squared ratio is ``Q = sum a_k chi2_1 / sum a_k`` with ``a_k
    = w_k stderr_k^2``. The limit bounds Q's tail by Chernoff's inequality, ``P(Q >= t) <= min_s
    exp(-s t) prod_k (1 - 2 s a_k / sum a)^(-1/2)``: rigorous whatever the spread of the ``a_k``
    (a moment-matched chi-square underestimates that tail when a few cells dominate), and within
    16 % (one cell) to 1 % (a thousand) of the exact chi-square limit of equal cells at
    :data:`P_FALSE_ALARM`. The cells' errors are close to normal where enough paths land (about 20
    exits); an aggregate dominated by sparse cells is not judged by it. ``weight`` (e.g. ``omega *
    mask``) broadcasts against ``stderr``."""
    stderr = _array(stderr, "stderr")
    _not_negative(stderr, "stderr")
    w = _array(weight, "weight")
    _not_negative(w, "weight")
    p = _probability(p)
    a = np.asarray(w * stderr ** 2, dtype=np.float64)
    axes = tuple(range(a.ndim)) if axis is None else tuple(int(k) % a.ndim for k in np.atleast_1d(axis))
    kept = [a.shape[k] for k in range(a.ndim) if k not in axes]
    rows = np.moveaxis(a, axes, tuple(range(a.ndim - len(axes), a.ndim))).reshape(int(np.prod(kept)), -1)
    out = np.array([_chernoff_ratio(r, p) for r in rows])
    return out.reshape(kept) if kept else out[0]


def _chernoff_ratio(a: np.ndarray, p: float) -> float:
    """:func:`noise_floor_ratio_limit` of one set of cell variances ``a`` (``w stderr^2``)."""
    a = a[a > 0.0]
    if a.size == 0:
        return float("nan")
    a = a / a.sum()
    s_max = 0.5 / a.max()

    def log_bound(t: float) -> float:
        def f(s: float) -> float:
            return -s * t - 0.5 * np.log1p(-2.0 * s * a).sum()
        return optimize.minimize_scalar(f, bounds=(0.0, s_max * (1.0 - 1e-12)), method="bounded",
                                        options={"xatol": 1e-10 * s_max}).fun
    hi = 2.0
    while log_bound(hi) > math.log(p):
        hi *= 2.0
    return math.sqrt(optimize.brentq(lambda t: log_bound(t) - math.log(p), 1.0, hi, xtol=1e-10))


def flux(values: Any, stderr: Any, omega: Any, axis: int | tuple[int, ...] | None = None
         ) -> tuple[np.ndarray, np.ndarray]:
    """``sum f Omega`` over ``axis`` (all axes by default) and its standard error, the cells'
    errors added in quadrature. Within one run the cells are negatively correlated (a path exits
    through one cell), so this bounds the error of the sum from above."""
    values, stderr = _array(values, "values"), _array(stderr, "stderr")
    _same_shape("stderr", stderr, "values", values)
    _not_negative(stderr, "stderr")
    w = _array(omega, "omega")
    return (values * w).sum(axis=axis), np.sqrt((stderr ** 2 * w ** 2).sum(axis=axis))


def sparse_flux(sim: Any, stderr: Any, model: Any, omega: Any, rays: int, min_expected: float = MIN_EXPECTED,
                where: Any = None) -> tuple[float, float, float]:
    """The cells :func:`cell_chi2` leaves out (``rays * model * omega < min_expected``, within
    ``where``) in aggregate: ``(simulated flux, model flux, error)``, the fluxes ``sum f Omega``
    over those cells and the error the simulated flux's standard error (:func:`flux`) plus one
    exit's worth, ``1 / rays`` (a region the simulation never hit has no sample error)."""
    sim, stderr, model, omega, rays, mask = _cells(sim, stderr, model, omega, rays, where)
    min_expected = _positive(min_expected, "min_expected")
    sparse = (rays * model * omega < min_expected) & mask
    got, se = flux(sim[sparse], stderr[sparse], omega[sparse])
    want = (model * omega)[sparse].sum()
    return float(got), float(want), float(se) + 1.0 / rays


def assert_sparse_flux_matches(sim: Any, stderr: Any, model: Any, omega: Any, rays: int,
                               min_expected: float = MIN_EXPECTED, where: Any = None) -> tuple[float, float, float]:
    """:func:`sparse_flux`'s two fluxes within :data:`Z_TOL` of its error; raises ``AssertionError``
    otherwise. Returns ``(simulated, model, error)``."""
    got, want, err = sparse_flux(sim, stderr, model, omega, rays, min_expected, where)
    if not abs(got - want) < Z_TOL * err:
        raise AssertionError(f"the sparse cells' flux {got:.6g} differs from the model's {want:.6g} by "
                             f"{abs(got - want) / err:.1f} errors of {err:.3g} (at most {Z_TOL:.2f})")
    return got, want, err


# ---------------------------------------------------------------------- two samples


def mean_stderr(sums: Any, squares: Any, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean per path and its standard error from the sums of ``n`` paths' weights and of their
    squares (the sample variance, ``n - 1`` in the denominator, as the simulator's estimates,
    :mod:`goniometer.run.results`)."""
    sums, squares = _array(sums, "sums"), _array(squares, "squares")
    _same_shape("squares", squares, "sums", sums)
    n = _rays(n, "n")
    mean = sums / n
    return mean, np.sqrt(np.maximum(squares / n - mean * mean, 0.0) / max(n - 1, 1))


def effective_exits(sums: Any, squares: Any) -> np.ndarray:
    """Effective number of exits, ``(sum w)^2 / sum w^2`` (the count for unit weights, fewer when a
    few large weights dominate); 0 for a cell without exits."""
    sums, squares = _array(sums, "sums"), _array(squares, "squares")
    _same_shape("squares", squares, "sums", sums)
    return sums ** 2 / np.maximum(squares, 1e-300)


def two_sample_chi2(a: Any, sa: Any, b: Any, sb: Any, where: Any = None) -> tuple[float, int]:
    """Chi-square of two independent estimates of the same cells (two simulations, or two
    kernels), ``z = (a - b) / sqrt(sa^2 + sb^2)`` over the cells ``where`` selects (all by
    default: select them by both samples' expected or :func:`effective_exits`, not by one sample's
    noise alone), and its degrees of freedom."""
    a, sa, b, sb = _array(a, "a"), _array(sa, "sa"), _array(b, "b"), _array(sb, "sb")
    for name, x in (("sa", sa), ("b", b), ("sb", sb)):
        _same_shape(name, x, "a", a)
    _not_negative(sa, "sa")
    _not_negative(sb, "sb")
    try:
        sel = np.broadcast_to(np.asarray(True if where is None else where, dtype=bool), a.shape)
    except ValueError:
        raise ValueError(f"where: shape {np.shape(where)} does not broadcast to the values' {a.shape}") from None
    var = (sa ** 2 + sb ** 2)[sel]
    if (var <= 0).any():
        raise ValueError("sa, sb: a selected cell has no standard error in either sample")
    z = (a - b)[sel] / np.sqrt(var)
    return float(np.sum(z * z)), int(np.count_nonzero(sel))


def assert_samples_match(a: Any, sa: Any, b: Any, sb: Any, where: Any = None, min_cells: int = MIN_CELLS
                         ) -> tuple[float, int]:
    """:func:`two_sample_chi2` below :func:`chi2_limit`, over at least ``min_cells`` cells; raises
    ``AssertionError`` otherwise. Returns ``(chi2, dof)``."""
    chi2, dof = two_sample_chi2(a, sa, b, sb, where)
    if dof < min_cells:
        raise AssertionError(f"only {dof} cells are selected (at least {min_cells} wanted)")
    limit = chi2_limit(dof)
    if not chi2 < limit:
        raise AssertionError(f"chi2 = {chi2:.1f} over {dof} cells exceeds {limit:.1f} (chi2/dof = {chi2 / dof:.3f})")
    return chi2, dof


# ---------------------------------------------------------------------- values and energies


def assert_z_close(a: Any, sa: Any, b: Any, sb: Any = 0.0, extra: Any = 0.0) -> None:
    """``|a - b| <= Z_TOL sqrt(sa^2 + sb^2) + extra`` elementwise (arrays broadcast): an estimate
    against a closed form (``sb = 0``) or another independent estimate, ``extra`` a stated bound
    (a closed form's quadrature error, a known bias); raises ``AssertionError`` otherwise."""
    a, sa, b, sb, extra = (_array(x, n) for x, n in ((a, "a"), (sa, "sa"), (b, "b"), (sb, "sb"), (extra, "extra")))
    for name, x in (("sa", sa), ("sb", sb), ("extra", extra)):
        _not_negative(x, name)
    tol = Z_TOL * np.sqrt(sa ** 2 + sb ** 2) + extra
    if not np.all(np.abs(a - b) <= tol):
        raise AssertionError(f"{a} vs {b}: |diff| {np.abs(a - b)} > {tol}")


def energy_total(result: Any) -> np.ndarray:
    """The energy books of a simulation or tabulation result: the terms of
    :data:`~goniometer.run.results.ENERGY_TERMS` plus the roulette balance and the weight stopped
    by the event cap, (M, C) or (C,). Every path books its unit weight, so this is 1 to rounding."""
    return sum(result.energy[k] for k in ENERGY_TERMS) + result.roulette + result.capped


def assert_energy_conserved(result: Any, atol: float = 1e-10) -> None:
    """:func:`energy_total` equal to 1 within ``atol`` (rounding: the books close path by path);
    raises ``AssertionError`` otherwise."""
    atol = _positive(atol, "atol")
    total = energy_total(result)
    if not np.all(np.abs(total - 1.0) <= atol):
        raise AssertionError(f"the energy terms sum to {total}, not 1 within {atol:g}")


def assert_energy_matches(result: Any, term: str, expected: Any, extra: Any = 0.0) -> None:
    """The energy ``term`` of a result (one of :data:`~goniometer.run.results.ENERGY_TERMS`)
    against a closed form ``expected`` (broadcast to (M, C)) within :data:`Z_TOL` of the result's
    standard error plus ``extra`` (:func:`assert_z_close`)."""
    if term not in ENERGY_TERMS:
        raise ValueError(f"term: one of {', '.join(ENERGY_TERMS)}, got {term!r}")
    try:
        assert_z_close(result.energy[term], result.energy_stderr[term], expected, extra=extra)
    except AssertionError as e:
        raise AssertionError(f"energy {term!r}: {e}") from None
