"""goniometer.optics against closed forms, identities, sampling statistics and Mitsuba 3."""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest
from scipy import integrate, stats

from goniometer import optics
from goniometer.kernel.rng import next_disk, stream_state
from goniometer.testing import P_FALSE_ALARM, chi2_limit

# ----------------------------------------------------------------------------- quadrature helpers


def _hemisphere_grid(ax: float, ay: float, n_psi: int = 400, n_phi: int = 256):
    """Quadrature over microfacet normals concentrated where GGX puts its mass:
    tan(theta) = a * tan(psi), psi Gauss-Legendre on [0, pi/2), phi uniform (periodic: exact-ish)."""
    a = math.sqrt(ax * ay)
    x, w = np.polynomial.legendre.leggauss(n_psi)
    psi = 0.25 * math.pi * (x + 1.0)
    wpsi = 0.25 * math.pi * w
    theta = np.arctan(a * np.tan(psi))
    dtheta = a / np.cos(psi) ** 2 / (1.0 + (a * np.tan(psi)) ** 2)
    phi = (np.arange(n_phi) + 0.5) * 2 * math.pi / n_phi
    T, P = np.meshgrid(theta, phi, indexing="ij")
    W = (wpsi * dtheta * np.sin(theta))[:, None] * (2 * math.pi / n_phi)
    m = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], axis=-1)
    return m, np.broadcast_to(W, T.shape)


@pytest.mark.parametrize("ax, ay", [(0.01, 0.01), (0.05, 0.05), (0.2, 0.2), (0.7, 0.7), (1.0, 1.0), (0.1, 0.4)])
def test_ggx_d_is_normalised(ax, ay):
    """Int D(m) m_z dm = 1 (the projected microfacet area equals the macro area)."""
    m, w = _hemisphere_grid(ax, ay)
    d = optics.np_ggx_d(m[..., 0], m[..., 1], m[..., 2], ax, ay)
    assert np.sum(d * m[..., 2] * w) == pytest.approx(1.0, abs=1e-6)


@pytest.mark.parametrize("ax, ay", [(0.05, 0.05), (0.3, 0.3), (0.9, 0.9), (0.1, 0.5)])
@pytest.mark.parametrize("theta_deg, phi_deg", [(0, 0), (30, 10), (60, 100), (85, 45), (89.5, 200)])
def test_lambda_matches_projected_area(ax, ay, theta_deg, phi_deg):
    """Smith's Lambda is defined by Int (v.m)+ D(m) dm = v_z (1 + Lambda(v)) (Heitz 2014, eq. 14):
    a quadrature of D checks the closed-form Lambda, hence G1 = 1 / (1 + Lambda)."""
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    v = np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])
    m, w = _hemisphere_grid(ax, ay, n_psi=800, n_phi=1024)
    d = optics.np_ggx_d(m[..., 0], m[..., 1], m[..., 2], ax, ay)
    proj = np.sum(np.maximum(m @ v, 0.0) * d * w)
    lam = optics.ggx_lambda(v[0], v[1], v[2], ax, ay)
    assert proj == pytest.approx(v[2] * (1.0 + lam), rel=2e-4, abs=2e-6)


def test_g1_closed_form_isotropic():
    """Walter 2007 eq. 34: G1 = 2 / (1 + sqrt(1 + alpha^2 tan^2 theta)) for isotropic GGX."""
    for alpha in (0.05, 0.3, 1.0):
        for th in np.radians([0.0, 20.0, 45.0, 70.0, 89.0]):
            v = (math.sin(th), 0.0, math.cos(th))
            g1 = optics.smith_g1(v[0], v[1], v[2], 1.0, alpha, alpha)
            assert g1 == pytest.approx(2.0 / (1.0 + math.sqrt(1.0 + alpha**2 * math.tan(th) ** 2)), rel=1e-12)
    # back-facing microfacet: chi+ kills it
    assert optics.smith_g1(0.0, 0.0, 1.0, -0.1, 0.3, 0.3) == 0.0


def test_height_correlated_transmission_is_beta_function():
    """G2 for transmission, height-correlated: Int_0^1 C^Li (1 - C)^Lo dC = B(1 + Li, 1 + Lo)."""
    for li, lo in [(0.0, 0.0), (0.3, 1.7), (2.5, 0.1)]:
        trans = integrate.quad(lambda c: c**li * (1 - c) ** lo, 0, 1, epsabs=1e-13)[0]
        refl = integrate.quad(lambda c: c ** (li + lo), 0, 1, epsabs=1e-13)[0]
        assert optics.smith_g2(li, lo, True, True) == pytest.approx(trans, rel=1e-9)
        assert optics.smith_g2(li, lo, False, True) == pytest.approx(refl, rel=1e-9)
        assert optics.smith_g2(li, lo, False, False) == pytest.approx(1 / ((1 + li) * (1 + lo)), rel=1e-15)


@numba.njit(cache=True)
def _sample_many(wx, wy, wz, ax, ay, u):
    out = np.empty((u.shape[0], 3))
    for i in range(u.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = optics.sample_vndf(wx, wy, wz, ax, ay, u[i, 0], u[i, 1])
    return out


@numba.njit(cache=True)
def _sample_many_disk(wx, wy, wz, ax, ay, n, seed):
    """sample_vndf_disk from disk points of the tracer's random streams (rejection, rng.next_disk)."""
    state = stream_state(np.uint64(seed), np.uint64(0), np.uint64(0))
    out = np.empty((n, 3))
    for i in range(n):
        x, y = next_disk(state)
        out[i, 0], out[i, 1], out[i, 2] = optics.sample_vndf_disk(wx, wy, wz, ax, ay, x, y)
    return out


@pytest.mark.parametrize("sampler", ["uniforms", "disk"])
@pytest.mark.parametrize("ax, ay, theta_deg, phi_deg", [(0.3, 0.3, 0.0, 0.0), (0.3, 0.3, 60.0, 0.0),
                                                       (0.1, 0.1, 80.0, 30.0), (0.2, 0.6, 45.0, 70.0)])
def test_vndf_samples_follow_visible_normal_density(ax, ay, theta_deg, phi_deg, sampler):
    """Chi-square test of sample_vndf (two uniforms) and of sample_vndf_disk fed by rng.next_disk
    (the tracer's trigonometry-free form) against the density G1(w) (w.m)+ D(m) / w_z integrated
    over bins."""
    rng = np.random.default_rng(7)
    n = 400_000
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    w = (math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t))
    if sampler == "disk":
        m = _sample_many_disk(w[0], w[1], w[2], ax, ay, n, 7)
    else:
        m = _sample_many(w[0], w[1], w[2], ax, ay, rng.random((n, 2)))
    assert np.allclose(np.linalg.norm(m, axis=1), 1.0)
    # bins: 24 in psi (tan theta_m = a tan psi) x 24 in phi
    a = math.sqrt(ax * ay)
    nb_t, nb_p = 24, 24
    psi = np.arctan(np.tan(np.arccos(np.clip(m[:, 2], -1, 1))) / a)
    phi = np.mod(np.arctan2(m[:, 1], m[:, 0]), 2 * math.pi)
    it = np.minimum((psi / (0.5 * math.pi) * nb_t).astype(int), nb_t - 1)
    ip = np.minimum((phi / (2 * math.pi) * nb_p).astype(int), nb_p - 1)
    observed = np.bincount(it * nb_p + ip, minlength=nb_t * nb_p).astype(float)
    # expected: 8 x 8 Gauss-Legendre points per bin
    x, gw = np.polynomial.legendre.leggauss(8)
    expected = np.zeros(nb_t * nb_p)
    for i in range(nb_t):
        p0, p1 = i * 0.5 * math.pi / nb_t, (i + 1) * 0.5 * math.pi / nb_t
        ps = 0.5 * (p1 - p0) * (x + 1) + p0
        wps = 0.5 * (p1 - p0) * gw
        th = np.arctan(a * np.tan(ps))
        dth = a / np.cos(ps) ** 2 / (1 + (a * np.tan(ps)) ** 2)
        for j in range(nb_p):
            q0, q1 = j * 2 * math.pi / nb_p, (j + 1) * 2 * math.pi / nb_p
            qs = 0.5 * (q1 - q0) * (x + 1) + q0
            wqs = 0.5 * (q1 - q0) * gw
            T, Q = np.meshgrid(th, qs, indexing="ij")
            mm = np.stack([np.sin(T) * np.cos(Q), np.sin(T) * np.sin(Q), np.cos(T)], -1)
            pdf = np.vectorize(lambda x_, y_, z_: optics.vndf_pdf(w[0], w[1], w[2], x_, y_, z_, ax, ay))(
                mm[..., 0], mm[..., 1], mm[..., 2])
            expected[i * nb_p + j] = np.sum(pdf * (wps * dth * np.sin(th))[:, None] * wqs[None, :])
    assert expected.sum() == pytest.approx(1.0, abs=1e-4)
    expected *= n
    keep = expected > 5
    chi2 = np.sum((observed[keep] - expected[keep]) ** 2 / expected[keep])
    dof = int(keep.sum()) - 1
    assert observed[~keep].sum() <= max(50.0, 3 * expected[~keep].sum())
    assert chi2 < chi2_limit(dof), f"chi2 {chi2:.1f} dof {dof}"


def test_vndf_smooth_limit_returns_normal():
    assert optics.sample_vndf(0.5, 0.1, math.sqrt(1 - 0.26), 0.0, 0.0, 0.3, 0.7) == pytest.approx((0.0, 0.0, 1.0))


# ----------------------------------------------------------------------------- Fresnel

def test_fresnel_dielectric_tabulated():
    """Glass n = 1.5: textbook values (Hecht, Optics): normal 0.04; 45 deg Rs = 0.0920, Rp = 0.0085;
    Brewster angle atan(1.5): Rp = 0, Rs = 0.1479; grazing -> 1; TIR from inside beyond 41.81 deg."""
    assert optics.fresnel_dielectric(1.0, 1.5) == pytest.approx(0.04, abs=1e-12)
    assert optics.fresnel_dielectric(math.cos(math.radians(45)), 1.5) == pytest.approx(0.5 * (0.092013 + 0.008466), abs=2e-6)
    brewster = math.atan(1.5)
    assert optics.fresnel_dielectric(math.cos(brewster), 1.5) == pytest.approx(0.5 * 0.147929, abs=2e-6)
    assert optics.fresnel_dielectric(0.0, 1.5) == pytest.approx(1.0)
    crit = math.asin(1 / 1.5)
    assert optics.fresnel_dielectric(math.cos(crit + 1e-6), 1 / 1.5) == 1.0
    assert optics.fresnel_dielectric(math.cos(crit - 1e-3), 1 / 1.5) < 1.0
    assert optics.fresnel_dielectric(0.3, 1.0) == pytest.approx(0.0, abs=1e-15)
    # Stokes: reflectance is the same from both sides at refracted-pair angles
    ci = math.cos(math.radians(35))
    ct = math.sqrt(1 - (1 - ci * ci) / 1.5**2)
    assert optics.fresnel_dielectric(ci, 1.5) == pytest.approx(optics.fresnel_dielectric(ct, 1 / 1.5), rel=1e-12)


def test_fresnel_conductor_tabulated():
    """Normal incidence closed form ((n-1)^2 + k^2) / ((n+1)^2 + k^2); at oblique incidence the
    complex-amplitude form rs = (cos - w)/(cos + w), rp = (n^2 cos - w)/(n^2 cos + w) with
    w = sqrt(n^2 - sin^2) (written here independently of the real-arithmetic code under test);
    kappa = 0 equals the dielectric formula, TIR included; grazing incidence reflects everything."""
    for n, k in [(0.958, 6.69), (1.45, 1.0), (0.2, 3.0), (1.2, 0.01), (1 / 1.5, 0.0), (0.9667, 0.6667)]:
        assert optics.fresnel_conductor(1.0, n, k) == pytest.approx(((n - 1) ** 2 + k**2) / ((n + 1) ** 2 + k**2), rel=1e-12)
        for c in np.linspace(0.02, 1.0, 17):
            nc = complex(n, k)
            w = np.sqrt(nc * nc - (1 - c * c) + 0j)
            if w.imag < 0:
                w = -w
            rs = abs((c - w) / (c + w)) ** 2
            rp = abs((nc * nc * c - w) / (nc * nc * c + w)) ** 2
            assert optics.fresnel_conductor(c, n, k) == pytest.approx(0.5 * (rs + rp), rel=1e-10)
    for c in np.linspace(0.0, 1.0, 23):
        for eta in (1.5, 1 / 1.5, 1.0, 2.4):
            assert optics.fresnel_conductor(c, eta, 0.0) == pytest.approx(optics.fresnel_dielectric(c, eta), abs=1e-12)
    assert optics.fresnel_conductor(0.0, 1.45, 1.0) == pytest.approx(1.0)
    # the degenerate index 0 is a perfect reflector at every angle
    for c in (1.0, 0.5, 1e-3):
        assert optics.fresnel_conductor(c, 0.0, 0.0) == pytest.approx(1.0)


def test_vector_log_gamma_and_height_correlated_g2():
    """The lane kernel's log-gamma (recurrence + Stirling) against libm's ``lgamma`` within
    1e-13 plus 4 ulp, and its height-correlated G2 against :func:`optics.smith_g2` within 1e-12
    relative, reflection and transmission, infinite Lambdas giving 0."""
    for x in np.concatenate([np.linspace(1.0, 12.0, 2201), np.geomspace(12.0, 200.0, 300)]):
        ref = math.lgamma(x)
        assert abs(optics.log_gamma_ge1(x) - ref) <= 1e-13 + 4 * math.ulp(ref), x
    lams = np.concatenate([[0.0], np.geomspace(1e-6, 99.0, 40)])
    for li in lams:
        for lo in lams:
            for tr in (False, True):
                ref = optics.smith_g2(li, lo, tr, True)
                assert optics.smith_g2_height_correlated(li, lo, tr) == pytest.approx(ref, rel=1e-12, abs=0.0)
    assert optics.smith_g2_height_correlated(math.inf, 0.5, True) == 0.0
    assert optics.smith_g2_height_correlated(0.5, math.inf, False) == 0.0


@pytest.mark.parametrize("g_is_r,b_is_g", [(False, False), (True, False), (False, True), (True, True)])
def test_conductor_channels_are_each_channels_fresnel(g_is_r, b_is_g):
    """The channels' Fresnel values with shared divisions equal each channel's own
    (``fresnel_conductor``) to rounding, for each way channels may share their index."""
    n = [0.2, 0.958, 1.45]
    k = [3.0, 6.69, 1.0]
    if g_is_r:
        n[1], k[1] = n[0], k[0]
    if b_is_g:
        n[2], k[2] = n[1], k[1]
    for c in np.linspace(0.0, 1.0, 21):
        got = optics.fresnel_conductor_channels(c, n[0], k[0], n[1], k[1], n[2], k[2], g_is_r, b_is_g)
        want = [optics.fresnel_conductor(c, n[j], k[j]) for j in range(3)]
        np.testing.assert_allclose(got, want, rtol=1e-14, atol=1e-16)


def test_refract_obeys_snell_and_reflect_is_mirror():
    w = np.array([0.3, -0.2, 0.0])
    w[2] = math.sqrt(1 - w[0] ** 2 - w[1] ** 2)
    m = np.array([0.1, 0.05, 0.0])
    m[2] = math.sqrt(1 - m[0] ** 2 - m[1] ** 2)
    for eta in (1.5, 0.9, 1.0):
        tx, ty, tz, ok = optics.refract(*w, *m, eta)
        t = np.array([tx, ty, tz])
        assert ok and np.linalg.norm(t) == pytest.approx(1.0)
        sin_i = np.linalg.norm(np.cross(w, m))
        sin_t = np.linalg.norm(np.cross(t, m))
        assert eta * sin_t == pytest.approx(sin_i, rel=1e-12)
        assert t @ m < 0  # far side
        assert np.dot(np.cross(m, w), t) == pytest.approx(0.0, abs=1e-12)  # coplanar
    assert optics.refract(*w, 0.0, 0.0, 1.0, 0.5)[3] is False or w[2] > 0  # shape of output
    r = np.array(optics.reflect(*w, *m))
    assert r @ m == pytest.approx(w @ m) and np.linalg.norm(r + w - 2 * (w @ m) * m) < 1e-15
    assert optics.refract(0.9, 0.0, math.sqrt(1 - 0.81), 0.0, 0.0, 1.0, 1 / 1.5)[3] is False


# ----------------------------------------------------------------------------- Mitsuba 3 as an independent oracle

def _random_dirs(rng, n, lower=False):
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1)[:, None]
    v[:, 2] = np.abs(v[:, 2]) * (-1 if lower else 1)
    return v


def test_microfacet_bsdf_matches_mitsuba():
    """Our Walter 2007 GGX BRDF/BTDF against Mitsuba 3 (scalar_rgb). Mitsuba's eval includes
    cos(theta_o); transmission compared in importance mode (flux based, wi = l), which is our
    convention, and in radiance mode, which differs by 1/eta^2."""
    mi = pytest.importorskip("mitsuba", reason="Mitsuba 3 is a test dependency: pip install mitsuba")
    mi.set_variant("scalar_rgb")
    rng = np.random.default_rng(3)
    imp = mi.BSDFContext(mi.TransportMode.Importance)
    rad = mi.BSDFContext(mi.TransportMode.Radiance)
    for alpha in (0.05, 0.2, 0.6):
        cond = mi.load_dict({"type": "roughconductor", "distribution": "ggx", "alpha": alpha,
                             "eta": 1.45, "k": 1.0, "sample_visible": True})
        diel = mi.load_dict({"type": "roughdielectric", "distribution": "ggx", "alpha": alpha,
                             "int_ior": 1.5, "ext_ior": 1.0})
        ls = _random_dirs(rng, 40)
        vs_up = _random_dirs(rng, 40)
        vs_dn = _random_dirs(rng, 40, lower=True)
        for l, vu, vd in zip(ls, vs_up, vs_dn):
            si = mi.SurfaceInteraction3f()
            si.wi = mi.Vector3f(*l)
            ours = optics.microfacet_reflection(*l, *vu, alpha, alpha, 1.45, 1.0, False) * vu[2]
            theirs = cond.eval(imp, si, mi.Vector3f(*vu))[0]
            assert ours == pytest.approx(theirs, rel=1e-4, abs=1e-6)
            ours = optics.microfacet_reflection(*l, *vu, alpha, alpha, 1.5, 0.0, False) * vu[2]
            theirs = diel.eval(imp, si, mi.Vector3f(*vu))[0]
            assert ours == pytest.approx(theirs, rel=1e-4, abs=1e-6)
            ours = optics.microfacet_transmission(*l, *vd, alpha, alpha, 1.5, False) * abs(vd[2])
            theirs = diel.eval(imp, si, mi.Vector3f(*vd))[0]
            assert ours == pytest.approx(theirs, rel=1e-4, abs=1e-6)
            theirs_rad = diel.eval(rad, si, mi.Vector3f(*vd))[0]
            assert ours / 1.5**2 == pytest.approx(theirs_rad, rel=1e-4, abs=1e-6)
            # light from inside the glass (wi below): relative index 1/1.5, TIR handled
            li = l * np.array([1, 1, -1])
            si.wi = mi.Vector3f(*li)
            vo = vu  # exits into air
            ours = optics.microfacet_transmission(*l, *(vo * np.array([1, 1, -1])), alpha, alpha, 1 / 1.5, False) * abs(vo[2])
            theirs = diel.eval(imp, si, mi.Vector3f(*vo))[0]
            assert ours == pytest.approx(theirs, rel=1e-4, abs=1e-6)


def test_vectorised_forms_equal_scalar():
    rng = np.random.default_rng(0)
    l = _random_dirs(rng, 50)
    v = _random_dirs(rng, 50)
    vec = optics.np_microfacet_reflection(l[:, 0], l[:, 1], l[:, 2], v[:, 0], v[:, 1], v[:, 2], 0.3, 0.3, 1.5, 0.0, False)
    for i in range(50):
        assert vec[i] == optics.microfacet_reflection(*l[i], *v[i], 0.3, 0.3, 1.5, 0.0, False)


def test_cos_sin_2pi_matches_libm():
    """The call-free sine/cosine of a turn fraction agrees with libm to a few ulp, quadrant edges included."""
    rng = np.random.default_rng(7)
    us = np.concatenate([rng.random(20000), np.linspace(0.0, 1.0, 4097), [1.0 - 2.0**-53, 2.0**-53]])
    for u in us:
        c, s = optics.cos_sin_2pi(float(u))
        assert abs(c - math.cos(2.0 * math.pi * u)) < 1e-15
        assert abs(s - math.sin(2.0 * math.pi * u)) < 1e-15
    assert optics.cos_sin_2pi(0.0) == (1.0, 0.0)


def test_exp_neg_and_log_pos_match_libm():
    """The call-free exponential (x <= 0) and logarithm (x > 0) agree with libm: exp_neg to a few
    ulp, log_pos within 1e-15 max(1, |log x|) (as their docstrings state), at table edges too."""
    rng = np.random.default_rng(8)
    xs = np.concatenate([rng.random(20000), 1.0 - rng.random(2000) * 1e-9, 1.0 + np.arange(65) / 64.0 - 0.5,
                         [1.0, 0.5, 2.0**-32, 2.0**-1022, 1e-300]])
    log_pos = numba.njit(lambda x: optics.log_pos(x))
    exp_neg = numba.njit(lambda x: optics.exp_neg(x))
    for x in xs:
        x = float(min(x, 1.0))
        assert abs(log_pos(x) - math.log(x)) <= 1e-15 * max(1.0, abs(math.log(x))), x
    assert log_pos(1.0) == 0.0
    for x in np.concatenate([-rng.random(20000) * 50.0, [0.0, -1e-300, -700.0]]):
        e = math.exp(float(x))
        assert abs(exp_neg(float(x)) - e) <= 4e-16 * e, x
    assert exp_neg(0.0) == 1.0


@numba.njit(cache=True)
def _disk_points(n, seed):
    state = stream_state(np.uint64(seed), np.uint64(1), np.uint64(2))
    out = np.empty((n, 3))
    for i in range(n):
        x, y = next_disk(state)
        out[i, 0], out[i, 1], out[i, 2] = optics.cosine_from_disk(x, y)
    return out


def test_disk_points_are_uniform_and_lift_to_cosine_density():
    """rng.next_disk: x^2 + y^2 uniform on [0, 1) and the azimuth uniform (Kolmogorov-Smirnov);
    cosine_from_disk: unit directions with cos theta distributed as 2 z dz, i.e. z^2 uniform."""
    d = _disk_points(200_000, 3)
    t = d[:, 0] ** 2 + d[:, 1] ** 2
    assert t.max() < 1.0
    assert stats.kstest(t, "uniform").pvalue > P_FALSE_ALARM
    assert stats.kstest(np.mod(np.arctan2(d[:, 1], d[:, 0]), 2 * math.pi) / (2 * math.pi), "uniform").pvalue > P_FALSE_ALARM
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-15)
    assert np.all(d[:, 2] > 0.0)
    assert stats.kstest(d[:, 2] ** 2, "uniform").pvalue > P_FALSE_ALARM


def test_smith_g1_dir_is_one_over_one_plus_lambda():
    rng = np.random.default_rng(5)
    for v in _random_dirs(rng, 200):
        for ax, ay in [(0.05, 0.05), (0.3, 0.7), (1.0, 0.2)]:
            assert optics.smith_g1_dir(*v, ax, ay) == pytest.approx(1.0 / (1.0 + optics.ggx_lambda(*v, ax, ay)), rel=1e-13)
    assert optics.smith_g1_dir(0.0, 0.0, 1.0, 0.3, 0.3) == 1.0
    assert optics.smith_g1_dir(1.0, 0.0, 0.0, 0.3, 0.3) == 0.0
