"""goniometer.testing.statistics (docs/testing.md): the false-alarm conventions, cells against a
model, the sparse cells in aggregate, two samples, values and energies -- each check passes on the
truth and fails on a model a few per cent off (a check that cannot fail is a defect), and refuses
input it cannot judge with a ValueError naming the argument.

The synthetic runs below draw what the simulator's estimator draws: every path exits at most once,
with a weight in [0.3, 1], into a cell with probability proportional to the BRDF times the cell's
projected solid angle; cell values and standard errors are made from the sums of weights and of
squared weights as the simulator makes them (goniometer.run.results)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import stats

from goniometer.testing import (MIN_EXPECTED, P_FALSE_ALARM, Z_TOL, assert_cells_match, assert_energy_conserved,
                                assert_energy_matches, assert_samples_match, assert_sparse_flux_matches,
                                assert_z_close, cell_chi2, chi2_interval, chi2_limit, effective_exits, energy_total,
                                expected_exits, flux, mean_stderr, model_sigma, noise_floor_ratio_limit, sparse_flux,
                                two_sample_chi2)

RHO = np.array([0.2, 0.35, 0.5])
#: mean exit weight of the synthetic runs (weights uniform in [0.3, 1])
MEAN_W = 0.65


def _omega(n_theta: int = 9, n_phi: int = 18) -> np.ndarray:
    """Projected solid angles of a classic grid over the upper hemisphere (they sum to pi)."""
    t = np.linspace(0.0, math.pi / 2, n_theta + 1)
    ring = 0.5 * np.diff(np.sin(t) ** 2)
    return np.repeat(ring[:, None] * (2 * math.pi / n_phi), n_phi, axis=1)


def _run(rng: np.random.Generator, rho: np.ndarray, omega: np.ndarray, rays: int
         ) -> tuple[np.ndarray, np.ndarray]:
    """Cell values and standard errors (C, n_theta, n_phi) of a Lambertian of albedo ``rho``."""
    value, stderr = [], []
    for r in rho:
        p = (r / (math.pi * MEAN_W)) * omega.ravel()
        cells = rng.choice(p.size + 1, size=rays, p=np.append(p, 1.0 - p.sum()))
        w = rng.uniform(0.3, 1.0, rays)
        s = np.bincount(cells, w, minlength=p.size + 1)[:-1].reshape(omega.shape)
        q = np.bincount(cells, w * w, minlength=p.size + 1)[:-1].reshape(omega.shape)
        mean, se = mean_stderr(s, q, rays)
        value.append(mean / omega)
        stderr.append(se / omega)
    return np.array(value), np.array(stderr)


def _lambertian(rho: np.ndarray, omega: np.ndarray) -> np.ndarray:
    return np.broadcast_to((rho / math.pi)[:, None, None], (len(rho),) + omega.shape).copy()


@pytest.fixture(scope="module")
def runs():
    """Two independent synthetic runs of the same Lambertian, 200 000 paths per channel."""
    rng = np.random.default_rng(7)
    omega = _omega()
    return omega, _run(rng, RHO, omega, 200_000), _run(rng, RHO, omega, 200_000), 200_000


# ---------------------------------------------------------------------- conventions


def test_the_false_alarm_conventions():
    assert P_FALSE_ALARM == 1e-6
    assert 2 * stats.norm.sf(Z_TOL) == pytest.approx(P_FALSE_ALARM, rel=1e-9)
    assert 4.89 < Z_TOL < 4.90
    for dof in (1, 10, 1000):
        assert stats.chi2.sf(chi2_limit(dof), dof) == pytest.approx(P_FALSE_ALARM, rel=1e-6)
        lo, hi = chi2_interval(dof)
        assert stats.chi2.cdf(lo, dof) == pytest.approx(P_FALSE_ALARM / 2, rel=1e-6)
        assert stats.chi2.sf(hi, dof) == pytest.approx(P_FALSE_ALARM / 2, rel=1e-6)
    assert chi2_limit(50, 0.01) < chi2_limit(50)
    assert MIN_EXPECTED == 25.0


@pytest.mark.parametrize("call, field", [
    (lambda: chi2_limit(0), "dof"), (lambda: chi2_limit(2.5), "dof"), (lambda: chi2_limit(True), "dof"),
    (lambda: chi2_limit(10, 0.0), "p"), (lambda: chi2_limit(10, 1.0), "p"), (lambda: chi2_interval(0), "dof"),
])
def test_limits_refuse_what_they_cannot_mean(call, field):
    with pytest.raises(ValueError, match=rf"^{field}: "):
        call()


def test_the_noise_floor_ratio_limit_bounds_the_false_alarm_rate():
    """A perfect model's RMSE over unequal cells (weights and errors spread over two decades)
    exceeds its noise floor times the limit no more often than the stated rate (a rigorous bound);
    a model whose errors are twice the noise, far more often. Equal cells: at most 16 % above the
    exact chi-square limit of their number at P_FALSE_ALARM, never below it."""
    rng = np.random.default_rng(5)
    n, trials, p = 60, 40_000, 1e-3
    w = rng.exponential(1.0, n)
    se = 10.0 ** rng.uniform(-1.0, 1.0, n)
    floor = np.sqrt((w * se ** 2).sum())
    limit = float(noise_floor_ratio_limit(se, w, p=p))
    d = rng.standard_normal((trials, n)) * se
    ratio = np.sqrt((w * d ** 2).sum(axis=1)) / floor
    assert np.mean(ratio > limit) <= p + Z_TOL * math.sqrt(p / trials)
    assert np.mean(2.0 * ratio > limit) > 100 * p
    for cells in (1, 15, 60, 1000):
        exact = math.sqrt(stats.chi2.isf(P_FALSE_ALARM, cells) / cells)
        assert exact <= noise_floor_ratio_limit(np.ones(cells), 2.0) <= 1.16 * exact
    both = noise_floor_ratio_limit(np.ones((2, 25)), np.ones(25), axis=1)
    assert both.shape == (2,) and both[0] == both[1]
    assert np.isnan(noise_floor_ratio_limit(np.zeros(4), np.ones(4)))
    with pytest.raises(ValueError, match=r"^weight: "):
        noise_floor_ratio_limit(np.ones(4), -np.ones(4))


# ---------------------------------------------------------------------- cells against a model


def test_the_true_model_passes_with_a_chi2_per_cell_near_one(runs):
    omega, (value, stderr), _, rays = runs
    model = _lambertian(RHO, omega)
    chi2, dof = assert_cells_match(value, stderr, model, omega, rays)
    assert dof == np.count_nonzero(expected_exits(model, omega, rays) >= MIN_EXPECTED) > 300
    assert abs(chi2 / dof - 1.0) < Z_TOL * math.sqrt(2.0 / dof)


@pytest.mark.parametrize("factor", [1.1, 0.9])
def test_a_model_off_by_ten_per_cent_fails(runs, factor):
    omega, (value, stderr), _, rays = runs
    wrong = factor * _lambertian(RHO, omega)
    chi2, dof = cell_chi2(value, stderr, wrong, omega, rays)
    assert chi2 > chi2_limit(dof)
    with pytest.raises(AssertionError, match=r"chi2 = .* over \d+ cells exceeds"):
        assert_cells_match(value, stderr, wrong, omega, rays)


def test_one_channel_off_by_five_per_cent_fails(runs):
    omega, (value, stderr), _, rays = runs
    wrong = _lambertian(RHO * np.array([1.0, 1.05, 1.0]), omega)
    with pytest.raises(AssertionError, match="chi2"):
        assert_cells_match(value, stderr, wrong, omega, rays)


def test_cells_are_selected_by_the_model_not_by_the_noise(runs):
    omega, (value, stderr), _, rays = runs
    model = _lambertian(RHO, omega)
    _, dof = cell_chi2(value, stderr, model, omega, rays)
    # the same cells whatever the simulated values: the selection is the model's expected exits
    _, dof_noise = cell_chi2(value * 3.0, stderr, model, omega, rays)
    assert dof_noise == dof == np.count_nonzero(rays * model * omega >= MIN_EXPECTED)
    # min_expected and where narrow it
    assert cell_chi2(value, stderr, model, omega, rays, min_expected=400.0)[1] < dof
    where = np.zeros(omega.shape, bool)
    where[4] = True
    assert cell_chi2(value, stderr, model, omega, rays, where=where)[1] == 3 * omega.shape[1]


def test_a_cell_never_hit_is_judged_with_the_bound():
    """No exit where the model expects 100: z^2 = N f Omega = 100 (sigma = sqrt(f / (N Omega)))."""
    omega = np.array([1e-3, 1e-3])
    model = np.array([1.0, 1.0])
    sim, se = np.array([0.0, 1.0]), np.array([0.0, 0.1])
    np.testing.assert_allclose(model_sigma(sim, se, model, omega, 100_000), [math.sqrt(1e-2), 0.1])
    chi2, dof = cell_chi2(sim, se, model, omega, 100_000, where=[True, False])
    assert dof == 1 and chi2 == pytest.approx(100.0)


def test_sigma_is_taken_under_the_model():
    """sigma = stderr sqrt(model / sim): a cell above the model counts by the model's variance,
    not by its own larger sample variance."""
    sim, se = np.array([2.0]), np.array([0.2])
    sigma = model_sigma(sim, se, np.array([1.0]), np.array([1e-3]), 10_000)
    assert sigma[0] == pytest.approx(0.2 * math.sqrt(0.5))
    chi2, _ = cell_chi2(sim, se, np.array([1.0]), np.array([1e-3]), 10_000, min_expected=1.0)
    assert chi2 == pytest.approx((1.0 / sigma[0]) ** 2)


def test_a_stochastic_models_error_adds_in_quadrature(runs):
    omega, (value, stderr), _, rays = runs
    model = _lambertian(RHO, omega)
    noise = 0.5 * stderr
    chi2, dof = cell_chi2(value, stderr, model, omega, rays, model_stderr=noise)
    sel = expected_exits(model, omega, rays) >= MIN_EXPECTED
    sigma = model_sigma(value, stderr, model, omega, rays)
    z = (value - model)[sel] / np.sqrt(sigma[sel] ** 2 + noise[sel] ** 2)
    assert dof == sel.sum() and chi2 == pytest.approx(float(np.sum(z * z)), rel=1e-12)
    assert chi2 < cell_chi2(value, stderr, model, omega, rays)[0]


def test_too_few_judged_cells_is_a_failure_not_a_pass(runs):
    omega, (value, stderr), _, rays = runs
    model = _lambertian(RHO, omega)
    with pytest.raises(AssertionError, match=r"only \d+ cells are hit well enough"):
        assert_cells_match(value, stderr, model, omega, rays, min_cells=10_000)


# ---------------------------------------------------------------------- the sparse cells in aggregate


def test_the_sparse_cells_in_aggregate():
    """A short run: the rows near the pole and the horizon fall below MIN_EXPECTED. Their flux
    matches the truth; a model twice too bright where it expects fewer than 12 exits (so fewer than
    25 once doubled) passes the per-cell check, which never judges those cells, and fails the
    aggregate."""
    rng = np.random.default_rng(3)
    omega = _omega(18, 36)
    rays = 40_000
    value, stderr = _run(rng, RHO, omega, rays)
    model = _lambertian(RHO, omega)
    sparse = expected_exits(model, omega, rays) < MIN_EXPECTED
    assert 0 < np.count_nonzero(sparse) < sparse.size
    got, want, err = assert_sparse_flux_matches(value, stderr, model, omega, rays)
    assert want == pytest.approx((model * omega)[sparse].sum())
    assert err == pytest.approx(flux(value[sparse], stderr[sparse], np.broadcast_to(omega, value.shape)[sparse])[1]
                                + 1.0 / rays)
    bright = np.where(expected_exits(model, omega, rays) < 12.0, 2.0 * model, model)
    assert_cells_match(value, stderr, bright, omega, rays, min_cells=50)
    with pytest.raises(AssertionError, match="sparse cells' flux"):
        assert_sparse_flux_matches(value, stderr, bright, omega, rays)
    # where narrows the region; a region the run never reached has an error of one exit
    none = sparse_flux(np.zeros_like(value), np.zeros_like(stderr), model, omega, rays, where=np.zeros_like(sparse))
    assert none == (0.0, 0.0, 1.0 / rays)


def test_flux_adds_the_cells_and_their_errors_in_quadrature():
    values, se, omega = np.array([[1.0, 2.0], [3.0, 4.0]]), np.array([[0.1, 0.2], [0.3, 0.4]]), np.array([0.5, 0.25])
    total, err = flux(values, se, omega, axis=1)
    np.testing.assert_allclose(total, [1.0, 2.5])
    np.testing.assert_allclose(err, [math.hypot(0.05, 0.05), math.hypot(0.15, 0.1)])


# ---------------------------------------------------------------------- two samples


def test_two_runs_of_the_same_material_agree(runs):
    omega, (a, sa), (b, sb), rays = runs
    sel = (sa > 0) & (sb > 0)
    chi2, dof = assert_samples_match(a, sa, b, sb, sel)
    assert dof == sel.sum() and abs(chi2 / dof - 1.0) < Z_TOL * math.sqrt(2.0 / dof)


def test_two_runs_ten_per_cent_apart_fail(runs):
    omega, (a, sa), _, rays = runs
    b, sb = _run(np.random.default_rng(11), 1.1 * RHO, omega, rays)
    chi2, dof = two_sample_chi2(a, sa, b, sb, (sa > 0) & (sb > 0))
    assert chi2 > chi2_limit(dof)
    with pytest.raises(AssertionError, match="chi2"):
        assert_samples_match(a, sa, b, sb, (sa > 0) & (sb > 0))
    with pytest.raises(AssertionError, match=r"only \d+ cells are selected"):
        assert_samples_match(a, sa, a, sa, np.zeros(a.shape, bool))


def test_mean_stderr_and_effective_exits_from_sums():
    rng = np.random.default_rng(5)
    w = rng.exponential(0.5, 1000) * (rng.random(1000) < 0.4)
    mean, se = mean_stderr(w.sum(), (w * w).sum(), w.size)
    assert mean == pytest.approx(w.mean()) and se == pytest.approx(w.std(ddof=1) / math.sqrt(w.size))
    ones = np.ones(37)
    assert effective_exits(ones.sum(), (ones ** 2).sum()) == pytest.approx(37.0)
    assert effective_exits(np.array([0.0]), np.array([0.0]))[0] == 0.0
    assert effective_exits(np.array([1.0 + 0.01 * 9]), np.array([1.0 + 9e-4]))[0] < 2.0   # one weight dominates


# ---------------------------------------------------------------------- values and energies


def test_a_value_against_a_closed_form():
    assert_z_close(1.0 + 4.0 * 0.01, 0.01, 1.0)
    assert_z_close([1.0, 2.0], [0.01, 0.01], [1.0, 2.0 + 0.06], sb=[0.0, 0.01])    # combined errors
    with pytest.raises(AssertionError, match="diff"):
        assert_z_close(1.0 + 5.0 * 0.01, 0.01, 1.0)
    assert_z_close(1.0 + 5.0 * 0.01, 0.01, 1.0, extra=0.002)                       # a stated bound


def _result(reflected=0.6, transmitted=0.3, absorbed=0.1, roulette=0.0, capped=0.0, se=0.001):
    terms = dict(reflected=reflected, transmitted=transmitted, absorbed=absorbed, masking_loss=0.0)
    return SimpleNamespace(energy={k: np.full((2, 3), v) for k, v in terms.items()},
                           energy_stderr={k: np.full((2, 3), se) for k in terms},
                           roulette=np.full((2, 3), roulette), capped=np.full((2, 3), capped))


def test_energy_books():
    np.testing.assert_allclose(energy_total(_result(absorbed=0.09, roulette=0.004, capped=0.006)), 1.0, atol=1e-15)
    assert_energy_conserved(_result())
    with pytest.raises(AssertionError, match="sum to"):
        assert_energy_conserved(_result(absorbed=0.1 + 1e-8))
    assert_energy_conserved(_result(absorbed=0.1 + 1e-8), atol=1e-7)


def test_an_energy_term_against_a_closed_form():
    r = _result(se=0.001)
    assert_energy_matches(r, "reflected", 0.6 + 0.004)
    with pytest.raises(AssertionError, match="energy 'reflected'"):
        assert_energy_matches(r, "reflected", 0.6 + 0.006)
    assert_energy_matches(r, "transmitted", [[0.3, 0.3, 0.3]])          # broadcast over (M, C)
    with pytest.raises(ValueError, match="^term: one of reflected"):
        assert_energy_matches(r, "albedo", 0.9)


def test_a_real_run_of_a_lambertian(tmp_path):
    """The simulator's own result: a bare Lambertian's cells are rho / pi (within the noise, and
    not 1.1 rho / pi), its books close and its reflected energy is rho."""
    from goniometer.run.loop import simulate
    from goniometer.run.settings import SimulationSettings
    from goniometer.stack import Lambertian, Stack
    rho = np.array([0.2, 0.5, 0.8])
    r = simulate(Stack("lambertian", (Lambertian(tuple(rho)),)),
                 SimulationSettings(incident_deg=(30.0,), rays=100_000, resolution=(9, 18), seed=3, threads=1))
    sd = r.brdf
    model = _lambertian(rho, sd.proj_solid_angle[0])
    assert_cells_match(sd.value[0], sd.stderr[0], model, sd.proj_solid_angle[0], r.settings.rays)
    with pytest.raises(AssertionError, match="chi2"):
        assert_cells_match(sd.value[0], sd.stderr[0], 1.1 * model, sd.proj_solid_angle[0], r.settings.rays)
    assert_energy_conserved(r)
    assert_energy_matches(r, "reflected", rho[None], extra=1e-12)


# ---------------------------------------------------------------------- refusals


def _cells_args(**change):
    args = dict(sim=np.ones((2, 3)), stderr=np.full((2, 3), 0.1), model=np.ones((2, 3)), omega=np.full(3, 0.01),
                rays=10_000)
    args.update(change)
    return args


@pytest.mark.parametrize("change, field", [
    (dict(rays=0), "rays"), (dict(rays=1.5), "rays"), (dict(rays=True), "rays"),
    (dict(stderr=np.ones((2, 4))), "stderr"), (dict(model=np.ones(3)), "model"),
    (dict(sim=np.full((2, 3), np.nan)), "sim"), (dict(model=np.full((2, 3), np.inf)), "model"),
    (dict(stderr=np.full((2, 3), -0.1)), "stderr"), (dict(omega=np.full(3, -0.01)), "omega"),
    (dict(omega=np.ones(4)), "omega, where"), (dict(min_expected=0.0), "min_expected"),
    (dict(where=np.ones(5, bool)), "omega, where"), (dict(model_stderr=np.ones(3)), "model_stderr"),
])
def test_cell_checks_refuse_input_they_cannot_judge(change, field):
    for check in (cell_chi2, assert_cells_match):
        with pytest.raises(ValueError, match=rf"^{field}: "):
            check(**_cells_args(**change))
    if "model_stderr" not in change:
        with pytest.raises(ValueError, match=rf"^{field}: "):
            sparse_flux(**_cells_args(**change))


@pytest.mark.parametrize("call, field", [
    (lambda: two_sample_chi2(np.ones(3), np.ones(2), np.ones(3), np.ones(3)), "sa"),
    (lambda: two_sample_chi2(np.ones(3), np.ones(3), np.ones(3), -np.ones(3)), "sb"),
    (lambda: two_sample_chi2(np.ones(3), np.zeros(3), np.ones(3), np.zeros(3)), "sa, sb"),
    (lambda: two_sample_chi2(np.ones(3), np.ones(3), np.ones(3), np.ones(3), np.ones(2, bool)), "where"),
    (lambda: mean_stderr(np.ones(3), np.ones(3), 0), "n"),
    (lambda: mean_stderr(np.ones(3), np.ones(2), 10), "squares"),
    (lambda: effective_exits(np.ones(3), np.ones(2)), "squares"),
    (lambda: flux(np.ones(3), np.ones(2), 1.0), "stderr"),
    (lambda: assert_z_close(1.0, -0.1, 1.0), "sa"),
    (lambda: assert_z_close(1.0, 0.1, np.nan), "b"),
    (lambda: assert_energy_conserved(_result(), atol=0.0), "atol"),
])
def test_the_other_checks_refuse_input_they_cannot_judge(call, field):
    with pytest.raises(ValueError, match=rf"^{field}: "):
        call()
