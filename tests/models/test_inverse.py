"""models.inverse (Bati 2021): equations, classes, bounds, round trips through Belcour's forward model.

Tolerances
----------
* The inverse evaluates FGD at normal incidence with the forward model's own quadrature and alpha
  interpolation (:func:`models.inverse.solver.fgd_normal`), so on stacks whose FGD slices are unsplit the
  round trip is exact up to root-finding tolerances: ``ROUND_TRIP_EXACT = 1e-9`` relative.
* Where the forward model uses a *split* slice (an interface into a lower index whose critical
  angle is reachable) its quadrature and alpha interpolation differ from the unsplit ones the
  inverse uses; measured over eta_rel in (0.25, 1), alpha <= 0.7: FGD at normal incidence agrees
  to 1.44 % relative, hence ``SPLIT_RTOL = 0.015`` (both are within about 1.2 % of an exact 1-D
  quadrature of the microfacet albedo there; the lobe energies of the cases below move by < 1e-4).
* The paper's figure 25 tolerance is 1 % (``FIGURE25_RTOL``). Coloured lobes below an interface
  carry an inherent per-channel variance spread (the roughness is achromatic, the inter-reflection
  factor m of eq. 19 is not): no achromatic roughness brings every channel closer than half the
  spread of the channel variances (:func:`models.inverse.solver.inherent_variance_spread`). The round
  trips therefore require ``max(FIGURE25_RTOL, 1.05 x that bound)`` for sigma (the 5 % covers the
  O(m) slope differences), and below 1 % for every case whose bound is below 0.95 %; the cases
  where it is not are listed (strongly coloured conductors under a coat).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from goniometer.stack import Interface, Medium, Stack, load_toml
from models import belcour
from models import inverse as I
from models.inverse import equations, kernels
from models.tables import belcour as tables
from models.inverse.validation import forward_check, forward_lobes

ROUND_TRIP_EXACT = 1e-9
SPLIT_RTOL = 0.015
FIGURE25_RTOL = 0.01
L = I.Lobe


def max_errors(inv: I.Inversion) -> tuple[float, float]:
    checks = forward_check(inv)
    er = max(float(np.max(np.abs(c.R_rel_error))) for c in checks)
    es = max(float(np.max(np.abs(c.sigma_rel_error))) for c in checks)
    return er, es


# ----------------------------------------------------------------------------- eq. 1, 7, 8-10

@pytest.mark.parametrize("R", [0.001, 0.04, 0.1, 0.2, 0.35])
@pytest.mark.parametrize("eta0", [1.0, 1.5, 2.5])
def test_eq7_roots_reproduce_r01(R, eta0):
    lo, hi = I.eq7_roots(R, eta0)
    assert I.eq1_reflectance(eta0, hi) == pytest.approx(R, rel=1e-12)
    assert I.eq1_reflectance(eta0, lo) == pytest.approx(R, rel=1e-12)
    # the smaller root is physical (>= 1) exactly when eta0 > (1 + sqrt R) / (1 - sqrt R)
    s = math.sqrt(R)
    assert (lo >= 1.0) == (eta0 >= (1 + s) / (1 - s))


@pytest.mark.parametrize("R", [0.18, 0.3, 0.6, 0.9, 0.99])
@pytest.mark.parametrize("eta0", [1.0, 1.5])
def test_eq8_reproduces_r01_on_the_class(R, eta0):
    lo, hi = I.conductor_eta_bounds(R, eta0)
    assert lo == pytest.approx(I.eq10_eta_min(R, eta0))
    assert hi == pytest.approx(I.eq9_eta_max(R, eta0))
    for eta1 in np.linspace(lo, hi, 17):
        k = I.eq8_kappa(R, eta1, eta0)
        assert I.eq1_reflectance(eta0, eta1, k) == pytest.approx(R, rel=1e-12)
        assert k >= eta1 * (1 - 1e-12)          # a conductor: kappa >= eta (section 5.1.2)
    # eq. 9 is tight: just above it kappa < eta (no longer a conductor)
    assert I.eq8_kappa(R, hi * (1 + 1e-6), eta0) < hi * (1 + 1e-6)


def test_conductor_reflectance_bound_is_3_minus_2_sqrt2():
    r = I.CONDUCTOR_R_MIN
    assert r == pytest.approx(0.1716, abs=1e-4)
    assert I.conductor_eta_bounds(r * (1 + 1e-6)) is not None
    assert I.conductor_eta_bounds(r * (1 - 1e-6)) is None
    assert math.isnan(I.eq9_eta_max(r * (1 - 1e-6)))


# ----------------------------------------------------------------------------- eq. 2, 11, 13, 15

def test_eq11_inverts_the_adding_equation():
    rng = np.random.default_rng(3)
    r01 = rng.uniform(0.0, 0.6, 200)
    r12 = rng.uniform(0.0, 0.95, 200)
    r02 = I.eq2_adding(r01, r12)
    assert np.allclose(I.eq11_inverse_adding(r02, r01), r12, rtol=1e-12, atol=1e-15)


def test_eq13_and_eq2_with_absorption_match_the_smooth_oracle():
    """A smooth 2-interface stack with a medium: eq. 2 with R'12 = R12 exp(-2 tau1) equals the
    simulator's closed-form adding equations (goniometer.testing.smooth) at normal incidence; eq. 13
    recovers tau1."""
    from goniometer.testing import smooth
    eta1, eta2, tau = 1.6, 2.4, 0.3
    stack = Stack("s", (Interface(0.0, (eta1,) * 3), Medium((tau,) * 3), Interface(0.0, (eta2,) * 3)))
    r01 = I.eq1_reflectance(1.0, eta1)
    r12 = I.eq1_reflectance(eta1, eta2)
    r02 = float(I.eq2_adding(r01, r12 * math.exp(-2 * tau)))
    R, _ = smooth.adding_energies(stack, 0.0)
    assert r02 == pytest.approx(R[0], rel=1e-12)
    assert float(I.eq13_tau(r12, I.eq11_inverse_adding(r02, r01))) == pytest.approx(tau, rel=1e-10)


@pytest.mark.parametrize("eta1,alpha1", [(1.3, 0.05), (1.8, 0.1), (1.5, 0.2)])
def test_eq15_is_eq19_below_one_interface(eta1, alpha1):
    """Eq. 15 (2-layer lobe in air) equals the general eq. 19 evaluated below the first interface."""
    s02 = belcour.roughness_to_variance(alpha1)
    ctx, _ = I.Context.ambient().with_interface(alpha1, eta1)
    r12p = 0.2
    got = ctx.sigma_r(np.full(3, r12p), s02)
    r10 = float(ctx.Rn0[0])
    want = I.eq15_sigma_r12(s02, 1.0, eta1, alpha1, r10, r12p)
    assert got == pytest.approx(np.full(3, want), rel=1e-12)


def test_eta_sigma_max_is_a_necessary_bound():
    """choice 4: eq. 15 without inter-reflections vanishes at eta_sigma_max, and no eta1 above it
    is in N1 (the exact sigma_R12 >= 0 check finds N1 below it)."""
    for sigma in (0.01, 0.05, 0.15):
        a1 = belcour.variance_to_roughness(sigma)
        x = I.eta_sigma_max(a1)
        assert 1.9 < x < 2.3
        assert abs(equations._sigma_condition(x, a1, sigma)) < 1e-12
        cls = I.two_layer_class(L(0.05, sigma, 2))
        assert cls.achievable
        assert max(iv.hi for iv in cls.n1) <= x + 1e-9
    assert math.isinf(I.eta_sigma_max(0.0))


# ----------------------------------------------------------------------------- FGD at normal incidence

@pytest.mark.parametrize("eta,kappa", [(1.5, 0.0), (2.7, 0.0), (1.05, 0.0), (0.8, 0.0), (0.45, 0.0),
                                       (1.2, 2.5), (0.3, 3.0), (2.0, 0.5)])
def test_fgd_normal_matches_the_forward_models_slice(eta, kappa):
    """Unsplit slices (mu_min = 1: no split) are reproduced to rounding; split ones (the forward
    model's choice when the critical angle is reachable) within SPLIT_RTOL."""
    w1, xs = I.kernel_for(I.InverseOptions())
    alphas = np.concatenate([[0.0, 1e-3], np.random.default_rng(1).uniform(0, 0.6, 12)])
    mine = np.array([I.fgd_normal(w1, xs, a, eta, kappa) for a in alphas])
    sl = tables.fgd_slice(eta, kappa, mu_min=1.0 + 2 * tables.SPLIT_MARGIN)
    assert sl.mu_split == 0.0
    assert np.allclose(mine, sl(1.0, alphas), rtol=1e-13, atol=1e-16)
    split = tables.fgd_slice(eta, kappa, mu_min=0.0)
    if split.mu_split > 0.0:
        assert np.allclose(mine, split(1.0, alphas), rtol=SPLIT_RTOL)


def test_fgd_normal_grows_away_from_index_matching():
    """The root finders assume FGD(alpha, eta) increases with |eta - 1| on each side, for every alpha node."""
    w1, xs = I.kernel_for(I.InverseOptions())
    for a in tables.alpha_nodes()[::3]:
        up = [I.fgd_normal(w1, xs, a, e, 0.0) for e in np.linspace(1.0, 5.0, 120)]
        down = [I.fgd_normal(w1, xs, a, e, 0.0) for e in np.linspace(1.0, 0.2, 120)]
        assert np.all(np.diff(up) >= -1e-15) and np.all(np.diff(down) >= -1e-15)


def test_context_matches_belcour_at_normal_incidence():
    """The inverse's own statistics (alg. 3) are the forward model's, state by state."""
    layers = [(0.05, 1.4, 0.0, 0.0), (0.2, 1.9, 0.0, 0.3), (0.1, 2.6, 0.0, 0.0), (0.15, (1.3, 0.9, 0.6), (2.0, 2.5, 3.0), 0.1)]
    ctx = I.Context.ambient()
    st_layers = []
    subs = []
    for a, eta, kappa, tau in layers:
        if tau:
            ctx = ctx.with_medium(tau)
            st_layers.append(Medium((tau,) * 3))
        ctx, sub = ctx.with_interface(a, eta, kappa)
        subs.append(sub)
        e = eta if isinstance(eta, tuple) else (eta,) * 3
        k = kappa if isinstance(kappa, tuple) else (kappa,) * 3
        st_layers.append(Interface(a, e, k))
    s = belcour.stack_statistics(Stack("c", tuple(st_layers)), 1.0)
    for sub, lobe in zip(subs, s.lobes):
        assert np.allclose(sub.energy, lobe.energy, rtol=1e-12, atol=1e-15)
        assert np.allclose(sub.variance, lobe.variance, rtol=1e-12, atol=1e-15)
    assert np.allclose(ctx.R0n, s.R0N, rtol=1e-12)
    assert ctx.J0n == pytest.approx(s.J0N)


# ----------------------------------------------------------------------------- bounds are tight

def test_one_layer_dielectric_energy_bound_is_tight():
    rmax = I.eq1_reflectance(1.0, 4.0)
    assert rmax == pytest.approx(0.36)                                  # section 5.1.1
    assert I.one_layer_dielectric_class(L(rmax * (1 - 1e-6))).achievable
    c = I.one_layer_dielectric_class(L(rmax * (1 + 1e-6)))
    assert not c.achievable and "R_max=0.36" in c.reason


def test_conductor_energy_bound_is_tight():
    r = I.CONDUCTOR_R_MIN
    assert I.conductor_class(L(r * (1 + 1e-4), 0.0)).achievable
    c = I.conductor_class(L(r * (1 - 1e-4), 0.0))
    assert not c.achievable and "0.1716" in c.reason


def test_two_layer_smooth_energy_bound_matches_the_adding_equations():
    """Section 5.2.1: 0.53 with eta_max = 4. The class bound equals the maximum of eq. 2 (tau1 = 0)
    over (eta1, eta2) in [1, 4]^2, and is tight."""
    e = np.linspace(1.0, 4.0, 601)
    E1, E2 = np.meshgrid(e, e, indexing="ij")
    r01 = ((E1 - 1) / (E1 + 1)) ** 2
    r12 = ((E2 - E1) / (E2 + E1)) ** 2
    best = float(np.max(I.eq2_adding(r01, r12)))
    assert best == pytest.approx(0.53, abs=0.005)
    assert I.two_layer_class(L(best * (1 - 1e-4), 0.0, 2)).achievable
    assert not I.two_layer_class(L(best * (1 + 1e-3), 0.0, 2)).achievable
    assert I.two_layer_energy_max(0.0, I.Context.ambient()) == pytest.approx(best, rel=2e-4)


def test_n1_boundaries_are_tight():
    cls = I.two_layer_class(L((0.03, 0.06, 0.09), 0.05, 2))
    for iv in cls.n1:
        for edge, outward in ((iv.lo, -1), (iv.hi, +1)):
            inside = cls.at(edge - outward * 1e-7)
            assert inside.status == kernels.OK
            if 1.0 < edge + outward * 1e-6 < cls.context.options.eta_max:
                assert cls.at(edge + outward * 1e-6).status != kernels.OK


# ----------------------------------------------------------------------------- round trips (figure 25)

ROUND_TRIPS = {
    "1L dielectric smooth": ([L(0.04)], "dielectric"),
    "1L dielectric rough": ([L(0.1, 0.08)], "dielectric"),
    "1L conductor coloured (fig 14a)": ([L((0.9, 0.7, 0.5), 0.03)], "conductor"),
    "1L conductor achromatic": ([L(0.6, 0.1)], "conductor"),
    "2L dielectric achromatic smooth (fig 15a)": ([L(0.15, 0.0, 2)], "dielectric"),
    "2L dielectric coloured smooth (fig 15b)": ([L((0.09, 0.09, 0.15), 0.0, 2)], "dielectric"),
    "2L dielectric coloured rough (fig 15c)": ([L((0.09, 0.09, 0.15), 0.03, 2)], "dielectric"),
    "2L dielectric coloured rough (fig 18)": ([L((0.03, 0.06, 0.09), 0.05, 2)], "dielectric"),
    "2L conductor (fig 16)": ([L(0.45, 0.03, 2)], "conductor"),
    "2L conductor coloured": ([L((0.5, 0.4, 0.35), 0.02, 2)], "conductor"),
    "2L conductor strongly coloured": ([L((0.5, 0.35, 0.25), 0.02, 2)], "conductor"),
    "2 lobes: coat + conductor (fig 14a)": ([L(0.04), L((0.9, 0.7, 0.5), 0.03)], "conductor"),
    "2 lobes: haze (fig 19b)": ([L(0.1), L((0.35, 0.25, 0.3), 0.04)], "conductor"),
    "2 lobes: coat + 2L (fig 22 top)": ([L(0.03), L((0.1, 0.1, 0.06), 0.05, 2)], "dielectric"),
    "2 lobes: two rough 2L (fig 17)": (list(I.FIG17_LOBES), "dielectric"),
    "2 lobes: coat + 2L conductor": ([L(0.05, 0.01), L((0.5, 0.4, 0.3), 0.05, 2)], "conductor"),
    "3 lobes achromatic": ([L(0.03), L(0.05, 0.01), L(0.1, 0.05, 2)], "dielectric"),
    "3 lobes coloured": ([L(0.03), L((0.05, 0.05, 0.06), 0.01), L((0.1, 0.1, 0.09), 0.05, 2)], "dielectric"),
    "3 lobes, conductor base": ([L(0.04), L(0.06, 0.02, 2), L((0.7, 0.66, 0.63), 0.06)], "conductor"),
    "3 lobes, strongly coloured conductor base": ([L(0.04), L(0.06, 0.02, 2), L((0.7, 0.5, 0.4), 0.06)], "conductor"),
}
#: cases whose inherent channel spread exceeds the figure-25 tolerance (checked against their bound)
SPREAD_LIMITED = {"2L conductor strongly coloured", "2 lobes: coat + 2L conductor", "3 lobes, strongly coloured conductor base"}


@pytest.mark.parametrize("name", list(ROUND_TRIPS))
def test_round_trip_through_the_forward_model(name):
    lobes, base = ROUND_TRIPS[name]
    inv = I.solve(lobes, base)
    assert inv.achievable, inv.reason
    er, es = max_errors(inv)
    bound = max(sol.variance_spread(lobe.sigma) for sol, lobe in zip(inv.solutions, lobes))
    assert er < FIGURE25_RTOL, er
    assert es <= max(FIGURE25_RTOL, 1.05 * bound), (es, bound)
    assert (bound < 0.0095) == (name not in SPREAD_LIMITED), bound
    if name not in SPREAD_LIMITED:
        assert es < FIGURE25_RTOL
    # the inverse's own prediction is the forward model (exact unless a split FGD slice is involved)
    fw = forward_lobes(inv.stack(), inv.lobe_interfaces)
    for (pe, pv), (fe, fv) in zip(inv.predicted(), fw):
        assert np.allclose(pe, fe, rtol=SPLIT_RTOL, atol=1e-12)
        assert np.allclose(pv, fv, rtol=SPLIT_RTOL, atol=1e-12)
    # the top lobe is exact in every channel (no inter-reflection above it)
    c0 = forward_check(inv)[0]
    assert np.max(np.abs(c0.R_rel_error)) < ROUND_TRIP_EXACT or lobes[0].layers == 2


def test_top_lobes_are_exact():
    for lobes, base in ([[L(0.1, 0.08)], "dielectric"], [[L((0.9, 0.7, 0.5), 0.03)], "conductor"],
                        [[L((0.09, 0.09, 0.15), 0.0, 2)], "dielectric"], [[L(0.45, 0.03, 2)], "conductor"]):
        er, es = max_errors(I.solve(lobes, base))
        assert er < ROUND_TRIP_EXACT and es < ROUND_TRIP_EXACT


def test_coloured_stacked_variance_spread_is_inherent_and_minimax_halves_it():
    """Below another lobe a coloured lobe's forward variance differs between channels whatever the
    (achromatic) roughness: with the paper's choice (max channel) that channel is exact and the
    others are off; minimax never does worse on the worst channel."""
    lobes = [L(0.1), L((0.6, 0.25, 0.25), 0.07)]     # figure 21 right: strong colour under a coat
    paper = I.solve(lobes, "conductor", options=I.InverseOptions(variance_channel="max"))
    mm = I.solve(lobes, "conductor")
    cp = forward_check(paper)[1]
    cm = forward_check(mm)[1]
    assert abs(cp.sigma_rel_error[0]) < ROUND_TRIP_EXACT          # red: R' is largest there
    spread = float(np.ptp(cp.sigma_forward)) / lobes[1].sigma
    assert spread > 1e-3
    assert float(np.max(np.abs(cm.sigma_rel_error))) <= float(np.max(np.abs(cp.sigma_rel_error))) + 1e-12
    assert float(np.max(np.abs(cm.sigma_rel_error))) == pytest.approx(spread / 2, rel=0.05)


def test_paper_top_variance_option_differs_only_slightly():
    """choice 2: alg. 5 as printed gives the first interface of a stacked 2-layer lobe a variance
    slightly off sigma_k; the default solves eq. 19 with that interface's own R' (exact)."""
    lobes = [L(0.1, 0.02), L(0.12, 0.05, 2)]
    exact = I.solve(lobes)
    paper = I.solve(lobes, options=I.InverseOptions(top_variance="paper"))
    s = belcour.stack_statistics(exact.stack(), 1.0)
    sp = belcour.stack_statistics(paper.stack(), 1.0)
    k = exact.lobe_interfaces[1][0]
    assert s.lobes[k].variance == pytest.approx(np.full(3, 0.05), rel=1e-9)
    off = abs(sp.lobes[k].variance[0] / 0.05 - 1)
    assert 1e-6 < off < 0.05


# ----------------------------------------------------------------------------- classes

def test_every_sampled_point_of_a_two_layer_class_gives_the_lobe():
    lobe = L((0.09, 0.09, 0.15), 0.03, 2)
    cls = I.two_layer_class(lobe)
    smp = cls.sample(6, 4)
    assert smp["eta2"].size >= 10
    for e1, e2 in list(zip(smp["eta1_of_sample"], smp["eta2"]))[::3]:
        inv = I.solve([lobe], picks=[I.Pick(eta1=float(e1), eta2=float(e2))])
        assert inv.achievable, inv.reason
        er, es = max_errors(inv)
        assert er < FIGURE25_RTOL and es < FIGURE25_RTOL


def test_conductor_class_samples_reproduce_the_energy():
    lobe = L((0.9, 0.7, 0.5), 0.03)
    cls = I.conductor_class(lobe)
    smp = cls.sample(9)
    w1, xs = I.kernel_for(I.InverseOptions())
    for i in range(9):
        for c in range(3):
            e, k = smp["eta1"][i, c], smp["kappa1"][i, c]
            assert k >= e * (1 - 1e-9)
            assert I.fgd_normal(w1, xs, cls.alpha, e, k) == pytest.approx(lobe.rgb[c], rel=1e-10)


def test_one_layer_dielectric_two_roots_in_a_dense_medium():
    """Section 5.1.1 / figure 4a: below a medium of index 2, R = 0.04 has two valid roots."""
    cls = I.one_layer_dielectric_class(L(0.04), I.Context.ambient(2.0))
    assert set(cls.branches) == {"upper", "lower"}
    assert cls.branches["upper"].lo == pytest.approx(3.0, rel=1e-9)
    assert cls.branches["lower"].hi == pytest.approx(2.0 / 1.5, rel=1e-9)


def test_coloured_one_layer_dielectric_uses_tau0_with_the_max_channel():
    ctx = I.Context.ambient(1.5)
    cls = I.one_layer_dielectric_class(L((0.02, 0.03, 0.04)), ctx)
    sol = cls.pick()
    tau = np.array(sol.choices["tau0"])
    assert tau[2] == pytest.approx(0.0, abs=1e-12)
    assert tau == pytest.approx(0.5 * np.log(0.04 / np.array([0.02, 0.03, 0.04])), rel=1e-9)


def test_explicit_picks_are_honoured_and_checked():
    lobe = L((0.09, 0.09, 0.15), 0.03, 2)
    inv = I.solve([lobe], picks=[{"u1": 0.2, "u2": 0.9}])
    assert inv.solutions[0].choices["u1"] == pytest.approx(0.2)
    assert inv.solutions[0].choices["u2"] == pytest.approx(0.9)
    bad = I.solve([lobe], picks=[{"eta1": 3.9}])
    assert not bad.achievable and "outside N1" in bad.reason
    with pytest.raises(I.NotAchievable):
        I.invert([lobe], lobe1={"eta1": 3.9})
    st = I.invert([lobe], lobe1=I.Pick(u1=0.2))
    assert isinstance(st, Stack)


# ----------------------------------------------------------------------------- unachievable targets

@pytest.mark.parametrize("lobes,base,needle", [
    ([L(0.4)], "dielectric", "R_max=0.36"),
    ([L(0.1, 0.02)], "conductor", "3 - 2 sqrt 2 = 0.1716"),
    ([L(0.6, 0.05, 2)], "dielectric", "R_max="),
    ([L((0.02, 0.04, 0.06))], "dielectric", "coloured 1-layer dielectric"),
    ([L(0.04, 0.07), L((0.6, 0.25, 0.25), 0.03)], "conductor", "sigma_min=0.031"),
    ([L(0.3, 0.0, 2), L(0.5, 0.001, 2)], "dielectric", "reflectance >= 1 below it"),
    ([L(0.1, 0.0, 2), L(0.38, 0.001, 2)], "dielectric", "R_max="),
])
def test_unachievable_targets_say_why(lobes, base, needle):
    inv = I.solve(lobes, base)
    assert not inv.achievable
    assert needle in inv.reason, inv.reason
    with pytest.raises(I.NotAchievable) as e:
        I.invert(lobes, base)
    assert needle in str(e.value)


def test_sigma_min_is_the_variance_with_a_smooth_base():
    """The bound reported for figure 21 (left) is what the forward model gives when the conductor is
    perfectly smooth (sigma_R = 0 in eq. 19): nothing sharper exists below that coat."""
    lobes = [L(0.04, 0.07), L((0.6, 0.25, 0.25), 0.07)]
    inv = I.solve(lobes, "conductor")
    layers = list(inv.layers)
    layers[-1] = I.Layer(layers[-1].tau, 0.0, layers[-1].eta, layers[-1].kappa)
    smooth = I.layers_to_stack(layers)
    v = belcour.stack_statistics(smooth, 1.0).lobes[1].variance
    reason = I.solve([lobes[0], L((0.6, 0.25, 0.25), 0.03)], "conductor").reason
    got = float(reason.split("sigma_min=")[1].split(",")[0])
    assert got == pytest.approx(float(v[0]), rel=2e-3)          # red, the channel of maximal R'


# ----------------------------------------------------------------------------- input

@pytest.mark.parametrize("text", ["", "R=", "R=0.1,0.2", "R=abc", "sigma=0.1", "R=0.1 sigma=-0.1", "R=1.0",
                                  "R=-0.1", "R=0.1 layers=3", "R=0.1 layers=1.5", "R=0.1 foo=2", "R=0.1 R=0.2",
                                  "R=0.1,0,0.1", "R=0.1 sigma=x", "R 0.1"])
def test_malformed_lobes_are_rejected(text):
    with pytest.raises(I.InverseError):
        I.parse_lobe(text)


def test_parse_lobe_and_picks():
    lobe = I.parse_lobe("R=0.03,0.06,0.09 sigma=0.05 layers=2")
    assert lobe == L((0.03, 0.06, 0.09), 0.05, 2)
    picks = I.parse_picks("1.u1=0.2 2.tau1=0,0.3,0 2.root=upper", 2)
    assert picks[0].u1 == 0.2 and picks[1].tau1 == (0.0, 0.3, 0.0) and picks[1].root == "upper"
    for bad in ("1.x=2", "3.u1=0.1", "1.u1=2", "u1=0.1", "1.u1=0.1 1.u1=0.2", "1.u1=0.1 1.eta1=1.5"):
        with pytest.raises(I.InverseError):
            I.parse_picks(bad, 2)


def test_stack_file_follows_the_material_contract(tmp_path):
    stack = I.invert([L(0.04), L((0.1, 0.2, 0.1), 0.03, 2)])
    p = tmp_path / "s.toml"
    p.write_text(stack.to_toml())
    back, _ = load_toml(p)
    assert back == stack
    assert np.allclose([x[0] for x in forward_lobes(back, [[0], [1, 2]])][1], [0.1, 0.2, 0.1], rtol=1e-3)


# ----------------------------------------------------------------------------- speed

def test_figure17_inversion_is_fast():
    """The benchmark (make bench) requires <= 50 ms on one core; here a 4x margin for busy machines."""
    assert I.bench_invert(repeat=5) < 0.2


def test_t0_bound_is_tight():
    """Eq. 16: below a coat, the optical depth above a 2-layer lobe is bounded by the lobe's largest
    reachable energy; just inside the bound the class exists, just outside it does not."""
    ctx, _ = I.Context.ambient().with_interface(0.0, 1.5)
    lobe = L(0.1, 0.02, 2)
    t0 = I.two_layer_class(lobe, ctx).T0()
    hi = t0[0].hi
    assert hi > 0 and all(iv.hi == pytest.approx(hi) for iv in t0)
    assert I.two_layer_class(lobe, ctx, tau0=hi * 0.99).achievable
    assert not I.two_layer_class(lobe, ctx, tau0=hi * 1.02, diagnose=True).achievable
    # at the top of a stack in air there is no medium above: T0 = {0}
    assert [iv.hi for iv in I.two_layer_class(lobe).T0()] == [0.0, 0.0, 0.0]


def test_equivalence_classes_follow_the_stack():
    lobes = [L(0.04), L((0.1, 0.2, 0.1), 0.03, 2)]
    classes = I.equivalence_classes(lobes)
    assert [c.kind for c in classes] == ["dielectric-1", "dielectric-2"]
    assert classes[1].context.interfaces == 1 and classes[1].context.eta == pytest.approx(1.5, rel=1e-6)
    assert classes[1].sample(4, 3)["eta2"].size > 0
