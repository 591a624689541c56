"""Thin films on interfaces in the simulator (``docs/material-format.md``, thin films): a smooth
film over a dielectric half-space reflects and transmits the Airy-summed R and T of
``goniometer.optics.film_rt`` (itself checked against ``tmm``) within the standard errors; a clear
film over a white conductor reflects everything (walks: path by path; single scattering: what
masking does not take); a clear film on a multiple-scattering dielectric conserves energy; a film
of thickness 0 is the bare interface bit for bit; the lane and per-path kernels agree on rough
film stacks (``tests/goniometer/kernel/test_two_kernels.py``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from goniometer import optics
from goniometer.run.loop import simulate
from goniometer.run.settings import SimulationSettings
from goniometer.stack import Film, Interface, Lambertian, Medium, Stack, StackError
from goniometer.testing import Z_TOL

WL = (450.0, 550.0, 650.0)


def _smooth_film(thickness, film_ior=(1.33, 1.38, 1.45), film_k=(0.0, 0.0, 0.0), below=1.5):
    return Stack("f", (Interface(0.0, (below,) * 3, film=Film(thickness, film_ior, film_k)),), "slab",
                 wavelengths_nm=WL)


@pytest.mark.parametrize("thickness, film_k", [(120.0, (0.0, 0.0, 0.0)), (480.0, (0.0, 0.02, 0.05))])
def test_smooth_film_reflects_and_transmits_airy(thickness, film_k):
    """Roughness 0 (a mirror: every microfacet normal is the macro normal): the reflected and
    transmitted fractions per channel are the film's R and T at the incident angle; an absorbing
    film's remainder is booked as absorbed."""
    st = _smooth_film(thickness, film_k=film_k)
    inc = (0.0, 35.0, 70.0)
    r = simulate(st, SimulationSettings(incident_deg=inc, rays=100_000, resolution=(3, 6), threads=1))
    fi = st.layers[0].film
    for m, deg in enumerate(inc):
        c = math.cos(math.radians(deg))
        for ch in range(3):
            rr, tt = optics.film_rt(c, 1.0, fi.ior[ch], fi.extinction[ch], 1.5, 0.0, thickness / WL[ch])
            for term, want in (("reflected", rr), ("transmitted", tt), ("absorbed", 1.0 - rr - tt)):
                got = r.energy[term][m, ch]
                se = r.energy_stderr[term][m, ch]
                assert abs(got - want) <= Z_TOL * se + 1e-12, (deg, ch, term, got, want, se)
        assert np.all(r.energy["masking_loss"][m] == 0.0)
    # the film colours the reflection: the channels differ by far more than their errors
    assert np.ptp(r.energy["reflected"][0]) > 10 * r.energy_stderr["reflected"][0].max()


WHITE = dict(ior=(1.0, 1.0, 1.0), extinction=(1e10, 2e10, 3e10))


@pytest.mark.parametrize("ms", [True, False], ids=["walk", "single"])
def test_white_furnace_film_on_conductor(ms):
    """A clear film over a perfect reflector reflects everything (to rounding), whatever the
    roughness; with walks nothing is lost to masking."""
    st = Stack("w", (Interface(0.4, film=Film(300.0, (1.33, 1.5, 1.7)), multiple_scattering=ms, **WHITE),), "metal",
               wavelengths_nm=WL)
    r = simulate(st, SimulationSettings(incident_deg=(0.0, 45.0, 80.0), rays=20_000, resolution=(3, 6), threads=1))
    kept = r.energy["reflected"] + (0.0 if ms else r.energy["masking_loss"])
    np.testing.assert_allclose(kept, 1.0, rtol=0, atol=1e-9)
    assert np.all(np.abs(r.energy["absorbed"]) < 1e-9) and np.all(r.energy["transmitted"] == 0.0)
    if ms:
        assert np.all(r.energy["masking_loss"] == 0.0)
    else:
        assert np.all(r.energy["masking_loss"][:, 0] > 0.0)


def test_clear_film_on_dielectric_conserves_energy():
    """A clear film on a multiple-scattering dielectric (light meets it from above and, inside
    the walk, from below): R + T = 1 per channel within the errors, absorption 0 in expectation
    (the estimator's per-channel factors R_c / P, T_c / (1 - P) book +- amounts path by path)."""
    st = Stack("d", (Interface(0.5, (1.5,) * 3, film=Film(350.0, (1.33, 1.38, 1.45)), multiple_scattering=True),),
               "slab", wavelengths_nm=WL)
    r = simulate(st, SimulationSettings(incident_deg=(0.0, 60.0), rays=60_000, resolution=(3, 6), threads=1))
    ab = r.energy["absorbed"]
    assert np.all(np.abs(ab) <= Z_TOL * r.energy_stderr["absorbed"] + 1e-12), ab
    total = r.energy["reflected"] + r.energy["transmitted"] + ab
    np.testing.assert_allclose(total, 1.0, rtol=0, atol=1e-9)


def test_thickness_zero_is_the_bare_interface_bit_for_bit():
    bare = Stack("p", (Interface(0.2, (1.5,) * 3), Medium((0.1, 0.2, 0.3)), Lambertian((0.2, 0.5, 0.8))), "plastic")
    zero = Stack("p", (Interface(0.2, (1.5,) * 3, film=Film(0.0, (1.33,) * 3)), Medium((0.1, 0.2, 0.3)),
                       Lambertian((0.2, 0.5, 0.8))), "plastic", wavelengths_nm=WL)
    s = SimulationSettings(incident_deg=(30.0,), rays=20_000, resolution=(6, 12), threads=1)
    a, b = simulate(bare, s), simulate(zero, s)
    assert np.array_equal(a.brdf.value, b.brdf.value) and np.array_equal(a.brdf.stderr, b.brdf.stderr)
    assert np.array_equal(a.brdf.orders, b.brdf.orders)
    for k in a.energy:
        assert np.array_equal(a.energy[k], b.energy[k]), k


def test_a_film_in_an_rgb_run_is_refused():
    st = Stack("f", (Interface(0.2, (1.5,) * 3, film=Film(300.0, (1.33,) * 3)),), "slab")
    with pytest.raises(StackError, match=r"layers\[0\].film: a thin film needs a spectral run"):
        simulate(st, SimulationSettings(incident_deg=(30.0,), rays=1000, resolution=(3, 6), threads=1))
