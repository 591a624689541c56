"""models.fitted: the HP15 distribution and shadowing, the fitted families, and the fits themselves."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy import integrate, special

from goniometer import optics
from goniometer.run.results import SimulationResult, SliceData
from goniometer.run.settings import SimulationSettings
from goniometer.run.loop import simulate
from goniometer.grids.slice_grid import SliceGrid, light_direction
from goniometer.stack import Interface, Lambertian, Medium, Stack
from models import fitted as F
from models.base import ModelError
from models.compare import integrate_slice, rmse
from models.fitted import fitting, hp15
from goniometer.testing import Z_TOL, chi2_interval

STACK = Stack("synthetic", (Interface(0.1, (1.5,) * 3), Lambertian((0.5,) * 3)), "plastic")
LAM = F.WAVELENGTHS_UM
#: a parameter estimate must lie within this many of its (sandwich) standard errors of the truth
Z_PARAM = 5.0


def lam_direct(a: float, p: float) -> float:
    return F.hp_lambda(a, p, hp15._QUAD_NODES, hp15._QUAD_WEIGHTS, hp15._QUAD_PANELS)


# ----------------------------------------------------------------------------- HP15 physics

@pytest.mark.parametrize("sigma,p", [(0.1, 1.0), (0.05, 0.5), (0.3, 0.3), (0.5, 2.0), (0.01, 0.6), (1.0, 5.0)])
def test_hp_distribution_is_normalised(sigma, p):
    """Eq. 26 with eq. 19's constant: Int D(m) cos(theta_m) dm = 1 (quadrature in theta, split at sigma scales)."""
    f = lambda th: F.hp_d(math.cos(th), sigma, p) * math.cos(th) * math.sin(th) * 2 * math.pi
    edges = np.unique(np.concatenate([[0.0], np.arctan(sigma * np.logspace(-3, 3, 30)), [math.pi / 2]]))
    total = sum(integrate.quad(f, a, b, limit=200, epsabs=0)[0] for a, b in zip(edges[:-1], edges[1:]))
    assert total == pytest.approx(1.0, rel=1e-9)


def test_hp_distribution_is_beckmann_at_p1():
    for th in np.radians([0.0, 5.0, 20.0, 45.0, 70.0, 89.0]):
        c = math.cos(th)
        beck = math.exp(-math.tan(th) ** 2 / 0.2**2) / (math.pi * 0.2**2 * c**4)
        assert F.hp_d(c, 0.2, 1.0) == pytest.approx(beck, rel=1e-12, abs=1e-300)
    assert F.hp_d(0.0, 0.2, 0.5) == 0.0 and F.hp_d(-0.3, 0.2, 0.5) == 0.0


@pytest.mark.parametrize("a", [0.3, 1.0, 3.0, 10.0, 100.0, 1e4])
def test_hp_lambda_is_beckmann_lambda_at_p1(a):
    mu = 1.0 / a
    beck = (special.erf(mu) - 1) / 2 + math.exp(-mu * mu) / (2 * mu * math.sqrt(math.pi))
    assert lam_direct(a, 1.0) == pytest.approx(beck, rel=1e-9)


def _lambda_projected_area(theta_v: float, sigma: float, p: float) -> float:
    """Smith Lambda from its definition over D itself: Int <v.m> D(m) dm / cos(theta_v) - 1.

    2D quadrature over the microfacet normal m (theta_m, phi_m), independent of the slope-space
    reduction used by the module.
    """
    sv, cv = math.sin(theta_v), math.cos(theta_v)

    def inner(tm):
        a, b = sv * math.sin(tm), cv * math.cos(tm)
        g = lambda ph: max(0.0, a * math.cos(ph) + b)
        upper = math.pi if b >= a else math.acos(-b / a)
        val = integrate.quad(g, 0.0, upper, epsabs=0, epsrel=1e-12)[0]
        return 2.0 * val * F.hp_d(math.cos(tm), sigma, p) * math.sin(tm)

    pts = np.unique(np.concatenate([[0.0], np.arctan(sigma * np.logspace(-2, 2, 15)),
                                    [math.pi / 2 - theta_v, math.pi / 2]]))
    pts = pts[(pts >= 0) & (pts <= math.pi / 2)]
    total = sum(integrate.quad(inner, a, b, epsabs=0, epsrel=1e-11, limit=200)[0] for a, b in zip(pts[:-1], pts[1:]))
    return total / cv - 1.0


@pytest.mark.parametrize("theta_deg,sigma,p", [(60, 0.3, 0.5), (75, 0.5, 1.5), (80, 0.2, 0.8), (45, 1.0, 0.3)])
def test_hp_lambda_matches_smith_integral_over_d(theta_deg, sigma, p):
    """The shadowing of eq. 20-21 equals Smith's Lambda computed numerically from D (eq. 26)."""
    th = math.radians(theta_deg)
    expected = _lambda_projected_area(th, sigma, p)
    assert lam_direct(sigma * math.tan(th), p) == pytest.approx(expected, rel=1e-8)
    assert F.hp_g1(math.cos(th), sigma, p) == pytest.approx(1.0 / (1.0 + expected), rel=1e-8)


def test_hp_lambda_limits():
    assert lam_direct(0.0, 0.5) == 0.0
    assert lam_direct(math.inf, 0.5) == math.inf
    assert lam_direct(1e-3, 2.0) == 0.0          # every slope far below 1/a
    assert F.hp_g1(0.0, 0.3, 0.5) == 0.0          # grazing: fully masked
    assert F.hp_g1(1.0, 0.3, 0.5) == 1.0


@pytest.mark.parametrize("p", [0.1, 0.3, 0.6, 1.0, 2.0, 5.0])
def test_lambda_table_matches_direct_quadrature(p):
    x0, dx, vals = F.HP15Family.table(p)
    worst = 0.0
    for ln_a in np.linspace(-20.0, 13.0, 1501):
        direct = 1.0 / (1.0 + lam_direct(math.exp(ln_a), p))
        table = 1.0 / (1.0 + F.hp_lambda_lookup(ln_a, x0, dx, vals))
        worst = max(worst, abs(direct - table))
    assert worst < 2e-5
    assert F.hp_lambda_lookup(-math.inf, x0, dx, vals) == 0.0
    assert F.hp_lambda_lookup(math.inf, x0, dx, vals) == math.inf


@pytest.mark.parametrize("a", [0.3, 1.0, 5.0])
def test_diffraction_normalisation(a):
    """E_{a,lambda} is Int S_z(f) cos dw_o at normal incidence (f = sin(theta_o) / lambda)."""
    for lam in LAM:
        s = lambda th: 2 * math.pi * math.sin(th) * math.cos(th) / (1 + (math.sin(th) / (lam * a)) ** 2) ** 2
        assert integrate.quad(s, 0, math.pi / 2, epsabs=0, epsrel=1e-12)[0] == pytest.approx(F.diffraction_norm(a, lam), rel=1e-10)


def _albedo(model, l, n_theta=400, n_phi=64):
    """Directional albedo Int f cos dw_o by midpoint quadrature (RGB)."""
    g = SliceGrid("classic", n_theta, n_phi)
    v, w = g.subcells(l, 1)
    f = model.evaluate(STACK, l, v.reshape(-1, 3)).total
    return np.einsum("kc,k->c", f, w.reshape(-1))


def test_diffraction_lobe_albedo_is_kw_over_lambda4():
    """A smooth-ish surface (G ~ 1 away from the horizon): the lobe's albedo at normal incidence is kw / lambda^4."""
    albedo = np.array([0.5, 0.3, 0.2])
    m = F.HP15Fit.from_params(dict(kd=0.0, ks=0.0, kw=list(albedo * LAM**4), F0=0.5, sigma=1e-4, p=1.0, a=1.5))
    np.testing.assert_allclose(_albedo(m, light_direction(0.0)), albedo, rtol=2e-3)


def test_ggx_lobe_uses_optics():
    l = light_direction(40.0)
    v = np.array([[0.3, 0.1, math.sqrt(1 - 0.1)], [-0.5, 0.2, math.sqrt(1 - 0.29)], [-0.6, 0.0, 0.8]])
    m = F.GGX1Fit.from_params(dict(kd=[0.1, 0.2, 0.3], ks=[0.5, 0.4, 0.3], F0=0.05, alpha=0.2))
    got = m.evaluate(STACK, l, v).total
    for k in range(len(v)):
        h = (l + v[k]) / np.linalg.norm(l + v[k])
        d = optics.ggx_d(*h, 0.2, 0.2)
        g = optics.smith_g2(optics.ggx_lambda(*l, 0.2, 0.2), optics.ggx_lambda(*v[k], 0.2, 0.2), False, True)
        fs = 0.05 + 0.95 * (1 - l @ h) ** 5
        want = np.array([0.1, 0.2, 0.3]) / math.pi + np.array([0.5, 0.4, 0.3]) * fs / 0.05 * d * g / (4 * l[2] * v[k, 2])
        np.testing.assert_allclose(got[k], want, rtol=1e-12)


# ----------------------------------------------------------------------------- models

def _models():
    return [
        F.GGX1Fit.from_params(dict(kd=[0.2, 0.4, 0.6], ks=[0.5, 0.4, 0.3], F0=0.1, alpha=0.15)),
        F.GGX2Fit.from_params(dict(kd=[0.2, 0.4, 0.6], ks_1=[0.5, 0.4, 0.3], F0_1=0.1, alpha_1=0.1,
                                   ks_2=[0.3, 0.3, 0.1], F0_2=0.5, alpha_2=0.4)),
        F.HP15Fit.from_params(dict(kd=[0.2, 0.3, 0.4], ks=[0.8, 0.7, 0.6], kw=list(np.array([0.3, 0.2, 0.1]) * LAM**4),
                                   F0=[0.9, 0.7, 0.5], sigma=0.1, p=0.6, a=1.0)),
    ]


@pytest.mark.parametrize("model", _models(), ids=lambda m: m.name)
def test_models_are_reciprocal_finite_and_zero_below_horizon(model):
    rng = np.random.default_rng(3)
    d = rng.normal(size=(200, 3))
    d[:, 2] = np.abs(d[:, 2])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    for l in d[:10]:
        a = model.evaluate(STACK, l, d).total
        b = np.stack([model.evaluate(STACK, x, l[None]).total[0] for x in d])
        np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-300)
        assert np.all(np.isfinite(a)) and np.all(a >= 0)
    out = model.evaluate(STACK, d[0], np.array([[0.6, 0.0, -0.8], [1.0, 0.0, 0.0], [np.nan, 0.0, 1.0]]))
    assert np.all(out.total == 0.0) and np.all(out.top == 0.0)
    val = model.evaluate(STACK, light_direction(30.0), d.reshape(10, 20, 3))
    assert val.total.shape == (10, 20, 3) and np.all(val.top == 0.0)


def test_model_parameters_round_trip_and_validation():
    for model in _models():
        cls = type(model)
        again = cls.from_params(model.params)
        np.testing.assert_array_equal(again.x, model.x)
        assert list(model.params) == cls.param_names()
        assert cls(model.x).name == model.name
    assert [F.HP15Fit.name, F.GGX1Fit.name, F.GGX2Fit.name] == ["hp15-fit", "ggx1-fit", "ggx2-fit"]
    assert len(F.HP15Fit.param_names()) == 7 and F.HP15Fit(np.r_[np.full(12, 0.5), 0.1, 0.5, 1.0]).x.size == 15
    with pytest.raises(ModelError, match="needs 15 parameters"):
        F.HP15Fit(np.ones(14))
    with pytest.raises(ModelError, match="sigma must be > 0"):
        F.HP15Fit(np.r_[np.full(12, 0.5), 0.0, 0.5, 1.0])
    with pytest.raises(ModelError, match="p must be > 0"):
        F.HP15Fit(np.r_[np.full(12, 0.5), 0.1, 0.0, 1.0])
    with pytest.raises(ModelError, match="kd must be >= 0"):
        F.GGX1Fit([-0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.04, 0.1])
    with pytest.raises(ModelError, match="finite"):
        F.GGX1Fit([0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.04, np.nan])
    with pytest.raises(ModelError, match="unknown fitted model"):
        F.model_class("ggx3")
    assert F.model_class("hp15-fit") is F.HP15Fit


# ----------------------------------------------------------------------------- synthetic references

def synthetic(model, thetas=(0.0, 30.0, 60.0), grid=SliceGrid("classic", 30, 60), rel=0.01, floor=1e-3,
              seed=1) -> tuple[SimulationResult, np.ndarray]:
    """A reference whose slices are ``model`` integrated onto ``grid`` (s = 5) plus Gaussian noise.

    The noise has the stated standard error ``rel * value + floor`` per cell and channel.
    Returns the reference and the noise-free values.
    """
    M = len(thetas)
    nt, nph = grid.shape
    value = np.zeros((M, 3, nt, nph))
    omega = np.zeros((M, nt, nph))
    mask = np.zeros((M, nt, nph), bool)
    for m, t in enumerate(thetas):
        l = light_direction(t)
        top, internal = integrate_slice(model, STACK, grid, l, 5)
        value[m] = top + internal
        omega[m] = grid.proj_solid_angle(l)
        mask[m] = grid.mask(l)
    se = rel * value + floor
    noisy = value + np.random.default_rng(seed).normal(size=value.shape) * se
    sd = SliceData(grid, noisy, se, noisy[:, None].copy(), mask, omega)
    z = np.zeros((M, 3))
    energy = {k: z for k in ("reflected", "transmitted", "absorbed", "masking_loss")}
    settings = SimulationSettings(incident_deg=tuple(thetas), rays=1, parametrization=grid.parametrization,
                                  resolution=grid.shape)
    ref = SimulationResult(STACK, settings, np.array(thetas, float), np.zeros(M), sd, None, energy, dict(energy),
                           z, z, np.zeros(M, int), np.zeros(M), np.zeros(M), 1)
    return ref, value


def _check_recovery(result, truth):
    """Every parameter within Z_PARAM sandwich standard errors of the truth, and those errors small."""
    for name, want in truth.params.items():
        got = np.atleast_1d(result.params[name])
        se = np.atleast_1d(result.param_stderr[name]).astype(float)
        want = np.atleast_1d(want)
        assert np.all(np.isfinite(se)), name
        # the tolerance must mean something: every parameter is pinned to better than 15 %
        assert np.all(se < 0.15 * np.abs(want)), (name, se, want)
        assert np.all(np.abs(got - want) <= Z_PARAM * se), (name, got, want, se)


@pytest.mark.parametrize("index", [0, 1, 2], ids=["ggx1", "ggx2", "hp15"])
def test_fit_recovers_known_parameters(index):
    """Slices generated by a family itself (noise 1 % + 1e-3 1/sr) give back its parameters.

    Parameters: within 5 standard errors propagated from the known noise through the weighted
    least squares (two-sided false alarm 5.7e-7 per parameter if the linearisation holds); those
    errors must be below 15 % of the values, so that the tolerance means something.
    Residuals: the fitted model sits at the noise floor -- sum ((ref - fit) / stderr)^2 over the
    N fitted cells and channels is a chi-square with about N - p degrees of freedom (tested at
    the suite's 1e-6 false-alarm level on both sides) -- and the fit's cost is not above the cost
    of the true parameters (the global minimum was found); the true model's eq. 4 error on the
    noisy data is the reported noise floor within its statistical spread.
    """
    truth = _models()[index]
    kind = truth.kind
    thetas = (0.0, 30.0, 60.0, 75.0) if kind == "hp15" else (0.0, 30.0, 60.0)
    ref, clean = synthetic(truth, thetas=thetas)
    result = F.fit(ref, kind, starts=4, seed=0)
    assert result.converged, result.message
    assert result.model.name == truth.name and result.kind == kind
    _check_recovery(result, truth)
    sd = ref.brdf
    fitted = np.stack([sum(integrate_slice(result.model, STACK, sd.grid, light_direction(t), 5)) for t in thetas])
    dof = sd.value.size - truth.x.size
    chi2 = float(np.sum(((sd.value - fitted) / sd.stderr) ** 2))
    lo, hi = chi2_interval(dof)
    assert lo < chi2 < hi
    # the optimiser found the global minimum: its cost is not above the true parameters' cost
    family = F.FAMILIES[kind]()
    true_cost = fitting._Problem(family, F.fit_data(ref)).cost(family.to_internal(truth.x))
    assert result.cost <= true_cost * (1 + 1e-9)
    assert result.errors["internal"] == result.errors["total"]
    e_true = rmse(sd.value, clean, sd.proj_solid_angle, sd.mask)
    # and the true-model error is the noise floor within its own statistical spread
    a = sd.stderr**2 * (sd.proj_solid_angle * sd.mask)[:, None]
    spread = np.sqrt(2 * np.sum(a**2, axis=(0, 2, 3))) / np.sum(a, axis=(0, 2, 3))
    nf = np.array(result.errors["total"]["noise_floor"])
    assert np.all(np.abs(e_true**2 / nf**2 - 1) < Z_TOL * spread)


def test_eq4_weighting_cost_is_the_reported_error():
    """With weighting="eq4" and 5 x 5 sub-cells the optimiser's cost is exactly half the sum of E_c^2."""
    truth = _models()[0]
    ref, _ = synthetic(truth)
    result = F.fit(ref, "ggx1", starts=1, weighting="eq4")
    assert result.subcells == 5
    e = np.array(result.errors["total"]["rmse"])
    assert 2 * result.cost == pytest.approx(np.sum(e**2), rel=1e-9)


def test_fit_is_deterministic():
    ref, _ = synthetic(_models()[0], rel=0.05)
    a = F.fit(ref, "ggx1", starts=3, seed=7, errors=False)
    b = F.fit(ref, "ggx1", starts=3, seed=7, errors=False)
    assert a.params == b.params and a.cost == b.cost


# ----------------------------------------------------------------------------- awkward data

def _awkward() -> dict[str, SimulationResult]:
    base = _models()[0]
    out = {}
    r, _ = synthetic(base)
    r.brdf.value[:] = 0.0
    r.brdf.stderr[:] = 0.0
    out["zeros"] = r
    r, _ = synthetic(base)
    r.brdf.value[:] = 0.0
    r.brdf.value[1, :, 10, 20] = 1e3
    out["spike"] = r
    r, _ = synthetic(base)
    theta = (np.arange(30) + 0.5) * 3.0
    r.brdf.value[:, :, theta < 81.0, :] = 0.0     # only cells beyond 1.4 rad hold light
    out["grazing-cells"] = r
    out["grazing-incident"] = synthetic(base, thetas=(85.0, 88.0))[0]
    r, _ = synthetic(base)
    r.brdf.value[0, :, 5, 5] = np.nan
    r.brdf.value[1, 0, 6, 6] = np.inf
    out["non-finite"] = r
    return out


AWKWARD = _awkward()


def _all_finite(obj) -> bool:
    json.dumps(obj, allow_nan=False)  # raises on NaN / inf
    return True


@pytest.mark.parametrize("kind", ["ggx1", "ggx2", "hp15"])
@pytest.mark.parametrize("case", list(AWKWARD))
def test_fit_never_returns_nan(kind, case):
    # a small evaluation budget keeps degenerate valleys (two lobes for one) from taking long;
    # whether the fit converged or not, every number must be finite
    result = F.fit(AWKWARD[case], kind, starts=2, max_nfev=40)
    assert isinstance(result.converged, bool) and isinstance(result.message, str) and result.message
    assert np.all(np.isfinite(result.model.x))
    assert math.isfinite(result.cost)
    out = result.to_json()
    assert _all_finite(out)
    assert out["model"] == f"{kind}-fit"
    if case == "grazing-incident":
        assert "no data left after excluding directions beyond 1.4 rad" in result.message


def test_fit_that_runs_out_of_evaluations_says_so():
    ref, _ = synthetic(_models()[2])
    result = F.fit(ref, "hp15", starts=1, max_nfev=1)
    assert result.converged is False
    assert result.message.startswith("did not converge")
    assert np.all(np.isfinite(result.model.x)) and _all_finite(result.to_json())


# ----------------------------------------------------------------------------- refusals

def test_refuses_btdf_and_missing_brdf():
    ref, _ = synthetic(_models()[0])
    with pytest.raises(ModelError) as e:
        F.fit(ref, "ggx1", side="btdf")
    assert "\n" not in str(e.value) and "BTDF" in str(e.value)
    ref.brdf = None
    for kind in ("hp15", "ggx1", "ggx2"):
        with pytest.raises(ModelError) as e:
            F.fit(ref, kind)
        msg = str(e.value)
        assert "\n" not in msg and "no BRDF slices" in msg and msg.startswith(f"{kind}-fit")
    with pytest.raises(ModelError, match="unknown fitted model"):
        F.fit(ref, "lambert")


# ----------------------------------------------------------------------------- a simulated file

@pytest.fixture(scope="module")
def simulated_plastic() -> SimulationResult:
    stack = Stack("plastic", (Interface(0.2, (1.5,) * 3), Medium((0.05, 0.1, 0.4)), Lambertian((0.2, 0.5, 0.8))),
                  "plastic")
    return simulate(stack, SimulationSettings(incident_deg=(0.0, 30.0, 60.0), rays=200_000, resolution=(30, 60),
                                              parametrization="classic", seed=5))


def test_simulated_plastic(simulated_plastic):
    """Two GGX lobes fit at least as well as one; HP15 gives finite results.

    With weighting="eq4" (objective = reported eq. 4 error on this grid) the nested start makes
    ggx2 <= ggx1 exact; with the paper's weighting the objectives differ from eq. 4, so 1 % slack.
    """
    ref = simulated_plastic
    g1 = F.fit(ref, "ggx1", weighting="eq4")
    g2 = F.fit(ref, "ggx2", weighting="eq4")
    s1 = np.sum(np.square(g1.errors["total"]["rmse"]))
    s2 = np.sum(np.square(g2.errors["total"]["rmse"]))
    assert s2 <= s1 * (1 + 1e-9)
    p1 = F.fit(ref, "ggx1")
    p2 = F.fit(ref, "ggx2")
    assert p2.errors["total"]["rmse_mean"] <= p1.errors["total"]["rmse_mean"] * 1.01
    for r in (g1, g2, p1, p2):
        assert r.converged, r.message
        # a plastic of roughness 0.2 and index 1.5: the sharpest fitted lobe is near alpha = 0.2
        alpha = r.params["alpha"] if r.kind == "ggx1" else r.params["alpha_1"]
        assert 0.1 < alpha < 0.35
    hp = F.fit(ref, "hp15")
    assert np.all(np.isfinite(hp.model.x)) and _all_finite(hp.to_json())
    assert hp.errors["total"]["rmse_mean"] < 10 * p1.errors["total"]["rmse_mean"]
