"""The polarized Fresnel events of goniometer.optics against independent references: tmm's complex
s and p amplitudes (a transfer-matrix code; its fields are exp(-i omega t), so its amplitudes are the
conjugates of ours: docs/polarization.md section 1), Born & Wolf's closed forms, and the Mueller
algebra's own identities."""

from __future__ import annotations

import math

import numpy as np
import pytest
import tmm

from goniometer import optics

COS = (1.0, 0.9, 0.6, 0.3, 0.08)


def _terms(rs: complex, rp: complex, factor: float = 1.0) -> np.ndarray:
    z = rs * np.conj(rp)
    return factor * np.array([0.5 * (abs(rs) ** 2 + abs(rp) ** 2), 0.5 * (abs(rs) ** 2 - abs(rp) ** 2), z.real,
                              z.imag])


def _tmm(pol: str, n: list, d: list, cos_i: float, lam: float = 550.0) -> dict:
    return tmm.coh_tmm(pol, n, d, math.acos(cos_i), lam)


def _tmm_event(n: list, d: list, cos_i: float, lam: float = 550.0) -> tuple[np.ndarray, np.ndarray]:
    """(reflection, transmission) terms (a, b, c, s) from tmm's amplitudes, conjugated."""
    s, p = _tmm("s", n, d, cos_i, lam), _tmm("p", n, d, cos_i, lam)
    rs, rp, ts, tp = (np.conj(x) for x in (s["r"], p["r"], s["t"], p["t"]))
    factor = s["T"] / abs(s["t"]) ** 2 if abs(s["t"]) > 0 else 0.0
    return _terms(rs, rp), _terms(ts, tp, factor)


@pytest.mark.parametrize("eta", [1.5, 1.33, 2.4])
@pytest.mark.parametrize("cos_i", COS)
def test_a_dielectric_from_outside_is_tmm_and_born_wolf(eta, cos_i):
    got = np.array(optics.fresnel_dielectric_mueller(cos_i, eta))
    r, t = _tmm_event([1.0, eta], [np.inf, np.inf], cos_i)
    assert np.allclose(got[:4], r, atol=1e-13) and np.allclose(got[4:], t, atol=1e-13)
    # Born & Wolf 1.5 (20): r_s, and r_p with Verdet's sign (-r_s at normal incidence)
    ct = math.sqrt(1 - (1 - cos_i ** 2) / eta ** 2)
    rs = (cos_i - eta * ct) / (cos_i + eta * ct)
    rp = (eta * cos_i - ct) / (eta * cos_i + ct)
    assert np.allclose(got[:4], [0.5 * (rs * rs + rp * rp), 0.5 * (rs * rs - rp * rp), rs * rp, 0.0], atol=1e-14)
    assert got[0] == pytest.approx(optics.fresnel_dielectric(cos_i, eta), abs=1e-15)
    # energy per polarization: R_s + T_s = R_p + T_p = 1
    assert got[0] + got[4] == pytest.approx(1.0, abs=1e-13) and got[1] + got[5] == pytest.approx(0.0, abs=1e-13)


@pytest.mark.parametrize("cos_i", [0.74, 0.5, 0.2, 0.01])
def test_total_internal_reflection_keeps_the_light_and_retards_p_against_s(cos_i):
    eta = 1.0 / 1.5                     # glass -> air: critical angle 41.8 deg
    got = np.array(optics.fresnel_dielectric_mueller(cos_i, eta))
    r, _ = _tmm_event([1.5, 1.0], [np.inf, np.inf], cos_i)
    assert np.allclose(got[:4], r, atol=1e-13)
    assert got[0] == pytest.approx(1.0) and got[1] == pytest.approx(0.0, abs=1e-15) and not got[4:].any()
    # Born & Wolf 1.5 (60) (whose r_parallel has Verdet's sign too): the relative phase delta of s and p,
    # tan(delta / 2) = cos sqrt(sin^2 - n^2) / sin^2; r_s r_p* = exp(i delta) up to the sign of the phase
    s2 = 1 - cos_i ** 2
    delta = 2 * math.atan(cos_i * math.sqrt(s2 - eta ** 2) / s2)
    assert got[2] == pytest.approx(math.cos(delta), abs=1e-12)
    assert abs(got[3]) == pytest.approx(math.sin(delta), abs=1e-12)
    assert got[2] ** 2 + got[3] ** 2 == pytest.approx(1.0)


@pytest.mark.parametrize("n, k", [(0.2, 3.0), (1.5, 0.1), (0.05, 4.2), (2.9, 3.1)])
@pytest.mark.parametrize("cos_i", COS)
def test_a_conductor_is_tmm(n, k, cos_i):
    got = np.array(optics.fresnel_conductor_mueller(cos_i, n, k))
    r, _ = _tmm_event([1.0, complex(n, k)], [np.inf, np.inf], cos_i)
    assert np.allclose(got, r, atol=1e-13)
    assert got[0] == pytest.approx(optics.fresnel_conductor(cos_i, n, k), abs=1e-14)
    # a pure reflection: c^2 + s^2 = R_s R_p (no depolarization)
    assert got[2] ** 2 + got[3] ** 2 == pytest.approx((got[0] + got[1]) * (got[0] - got[1]), abs=1e-14)


@pytest.mark.parametrize("film, d_nm, far", [((1.38, 0.0), 99.6, (1.5, 0.0)), ((2.0, 0.1), 250.0, (1.5, 0.0)),
                                             ((1.33, 0.0), 400.0, (1.0, 0.0)), ((1.45, 0.0), 150.0, (0.2, 3.0))])
@pytest.mark.parametrize("cos_i", COS)
def test_a_thin_film_is_tmm_in_amplitude_and_phase(film, d_nm, far, cos_i):
    nf, kf = film
    n3, k3 = far
    got = np.array(optics.film_mueller(cos_i, 1.0, nf, kf, n3, k3, d_nm / 550.0))
    r, t = _tmm_event([1.0, complex(nf, kf), complex(n3, k3)], [np.inf, d_nm, np.inf], cos_i)
    assert np.allclose(got[:4], r, atol=1e-12)
    if k3 == 0.0:
        assert np.allclose(got[4:], t, atol=1e-12)
    R, T = optics.film_rt(cos_i, 1.0, nf, kf, n3, k3, d_nm / 550.0)
    assert got[0] == pytest.approx(R, abs=1e-12) and (k3 != 0.0 or got[4] == pytest.approx(T, abs=1e-12))


def test_a_film_of_thickness_zero_is_the_bare_interface():
    for cos_i in COS:
        assert np.allclose(optics.film_mueller(cos_i, 1.0, 1.38, 0.0, 1.5, 0.0, 0.0),
                           optics.fresnel_dielectric_mueller(cos_i, 1.5), atol=1e-14)


def _matrix(a, b, c, s) -> np.ndarray:
    return np.array([[a, b, 0, 0], [b, a, 0, 0], [0, 0, c, s], [0, 0, -s, c]])


def test_the_mueller_algebra():
    # rotator(+45 deg) takes linear light along x to S2 = -1 (Mitsuba 3's test_mueller::test02_rotator)
    c2, s2 = optics.stokes_rotation(0.0, 0.0, 1.0, 1.0, 0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5), 0.0)
    m = np.zeros((1, 16))
    m[0, [0, 5, 10, 15]] = 1.0
    optics.mueller_rotate(m, 0, c2, s2)
    assert np.allclose(m[0].reshape(4, 4) @ [1, 1, 0, 0], [1, 0, -1, 0])
    # an event then another: the product of their matrices, left-multiplied in order
    rng = np.random.default_rng(3)
    m = rng.normal(size=(3, 16))
    e1, e2 = optics.fresnel_conductor_mueller(0.7, 0.2, 3.0), optics.fresnel_dielectric_mueller(0.4, 1.5)[:4]
    want = _matrix(*e2) @ (2.0 * _matrix(*e1)) @ m[1].reshape(4, 4)
    optics.mueller_event(m, 1, *e1, 2.0)
    optics.mueller_event(m, 1, *e2, 1.0)
    assert np.allclose(m[1].reshape(4, 4), want)
    d = m.copy()
    optics.mueller_depolarize(d, 2, 0.5)
    assert np.allclose(d[2, :4], 0.5 * m[2, :4]) and not d[2, 4:].any() and np.array_equal(d[:2], m[:2])
    # the normal frame: normal to k and z, along the limit at the normal
    assert np.allclose(optics.normal_frame(0.6, 0.0, -0.8, 1.0, 0.0), (0.0, 1.0, 0.0))
    assert np.allclose(optics.normal_frame(0.0, 0.0, -1.0, -1.0, 0.0), optics.normal_frame(-1e-9, 0.0, -1.0, 0, 0))


# ---------------------------------------------------------------------- frames: Mitsuba 3 as the reference

def _mat(a, b, c, s) -> np.ndarray:
    return np.array([[a, b, 0, 0], [b, a, 0, 0], [0, 0, c, s], [0, 0, -s, c]])


@pytest.mark.parametrize("theta_deg, phi_deg", [(50.0, 30.0), (20.0, 200.0), (80.0, 300.0), (5.0, 90.0)])
def test_smooth_events_are_mitsubas_in_its_frames(theta_deg, phi_deg):
    """Mitsuba 3's polarized smooth conductor and dielectric (scalar_spectral_polarized) against our
    Fresnel events taken from the s/p frames into its stokes_basis frames: the conventions (signs of
    r_p and of S3, the frames, which way the matrix acts) are Mitsuba's, to its float precision."""
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_spectral_polarized")
    from goniometer.grids.stokes import convert_mueller
    th, ph = math.radians(theta_deg), math.radians(phi_deg)
    v = np.array([math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)])   # to the viewer
    si = mi.SurfaceInteraction3f()
    si.wi = mi.Vector3f(*v)
    si.wavelengths = [550.0] * 4
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    si.n = mi.Vector3f(0, 0, 1)
    for bsdf, terms in ((mi.load_dict({"type": "conductor", "eta": 0.2, "k": 3.0}),
                         lambda c: (optics.fresnel_conductor_mueller(c, 0.2, 3.0), 1.0)),
                        (mi.load_dict({"type": "dielectric", "int_ior": 1.5, "ext_ior": 1.0}),
                         lambda c: (optics.fresnel_dielectric_mueller(c, 1.5)[:4],
                                    optics.fresnel_dielectric(c, 1.5)))):
        bs, weight = bsdf.sample(mi.BSDFContext(), si, 0.01, mi.Point2f(0.5, 0.5))   # the reflection
        l = np.array(bs.wo)                      # Mitsuba's wo is where the light comes from: our l
        assert l[2] > 0
        e, pdf = terms(l[2])
        ours = convert_mueller(_mat(*e), l, v, "sp", "mitsuba", phi_l_deg=phi_deg + 180.0, phi_v_deg=phi_deg) / pdf
        assert np.allclose(ours, np.array(weight)[:, :, 0], atol=2e-6), (ours, np.array(weight)[:, :, 0])
