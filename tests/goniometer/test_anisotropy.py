"""Anisotropic interfaces: rough conductor slices against the analytic anisotropic microfacet BRDF,
rotation covariance, the isotropic special case, and the material-file contract."""

from __future__ import annotations

import math

import numpy as np
import pytest

from goniometer import optics
from goniometer.run.settings import SimulationSettings
from goniometer.run.loop import simulate
from goniometer.grids.slice_grid import light_direction
from goniometer.stack import Interface, Stack, StackError, load_toml
from goniometer.testing import assert_cells_match, assert_samples_match, chi2_limit, two_sample_chi2

ETA, KAPPA = (1.45, 1.2, 0.9), (1.0, 0.5, 2.0)


def _aniso_model(ax, ay, rotation_deg):
    c, s = math.cos(math.radians(rotation_deg)), math.sin(math.radians(rotation_deg))

    def to_local(x, y):
        return c * x + s * y, -s * x + c * y

    def f(l, v):
        lx, ly = to_local(l[0], l[1])
        vx, vy = to_local(v[..., 0], v[..., 1])
        out = np.empty(v.shape[:-1] + (3,))
        for ch in range(3):
            out[..., ch] = optics.np_microfacet_reflection(lx, ly, l[2], vx, vy, v[..., 2], ax, ay, ETA[ch], KAPPA[ch], False)
        return out
    return f


@pytest.mark.parametrize("param", ["classic", "half"])
def test_anisotropic_conductor_matches_the_analytic_brdf(param):
    ax, ay, rot = 0.08, 0.3, 25.0
    st = Stack("aniso", (Interface(ax, ETA, KAPPA, roughness_y=ay, rotation_deg=rot),))
    s = SimulationSettings(incident_deg=(30.0, 50.0), incident_phi_deg=(0.0, 60.0), rays=1_500_000,
                           parametrization=param, resolution=(45, 90), seed=17)
    r = simulate(st, s)
    f = _aniso_model(ax, ay, rot)
    for m in range(2):
        l = light_direction(s.incident_deg[m], s.incident_phi_deg[m])
        model = np.moveaxis(r.brdf.grid.integrate(l, f, 7), -1, 0)
        om = r.brdf.proj_solid_angle[m]
        assert_cells_match(r.brdf.value[m], r.brdf.stderr[m], model, om, s.rays)
    # the isotropic model with the mean roughness is rejected by the same test
    iso = _aniso_model(0.5 * (ax + ay), 0.5 * (ax + ay), 0.0)
    l = light_direction(30.0)
    model = np.moveaxis(r.brdf.grid.integrate(l, iso, 7), -1, 0)
    with pytest.raises(AssertionError):
        assert_cells_match(r.brdf.value[0], r.brdf.stderr[0], model, r.brdf.proj_solid_angle[0], s.rays)


def test_rotating_interface_and_light_together_rotates_the_slice():
    """Rotate the tangent frame and phi_l by 30 degrees: the classic slice is the unrotated one
    shifted by 30 one-degree columns (a two-sample chi-square test over well-hit cells)."""
    base = dict(incident_deg=(40.0,), rays=1_000_000, resolution=(30, 360), seed=5)
    a = simulate(Stack("a", (Interface(0.1, ETA, KAPPA, roughness_y=0.35, rotation_deg=10.0),)),
                 SimulationSettings(incident_phi_deg=(0.0,), **base))
    b = simulate(Stack("b", (Interface(0.1, ETA, KAPPA, roughness_y=0.35, rotation_deg=40.0),)),
                 SimulationSettings(incident_phi_deg=(30.0,), **base))
    va, sa = a.brdf.value[0], a.brdf.stderr[0]
    vb, sb = np.roll(b.brdf.value[0], -30, axis=-1), np.roll(b.brdf.stderr[0], -30, axis=-1)
    sel = (sa > 0) & (sb > 0) & (va > 20 * sa / np.sqrt(20)) & (vb > 20 * sb / np.sqrt(20))
    assert_samples_match(va, sa, vb, sb, sel, min_cells=1001)
    # and it is not trivially so: the unrotated slice differs from the rotated one without the shift
    chi2, dof = two_sample_chi2(va, sa, b.brdf.value[0], sb, sel)
    assert chi2 > chi2_limit(dof)


def test_equal_roughnesses_reproduce_the_isotropic_path_bit_for_bit(tmp_path):
    p = tmp_path / "m.toml"
    p.write_text('name = "x"\n[[layers]]\ntype = "interface"\nroughness = [0.2, 0.2]\nior = 1.45\nextinction = 1.0\n')
    st, _ = load_toml(p)
    assert not st.layers[0].is_anisotropic and st.to_json() == Stack("x", (Interface(0.2, (1.45,) * 3, (1.0,) * 3),)).to_json()
    s = SimulationSettings(incident_deg=(35.0,), rays=50_000, resolution=(18, 36))
    a = simulate(st, s)
    b = simulate(Stack("x", (Interface(0.2, (1.45,) * 3, (1.0,) * 3),)), s)
    c = simulate(Stack("x", (Interface(0.2, (1.45,) * 3, (1.0,) * 3, roughness_y=0.2),)), s)
    assert np.array_equal(a.brdf.value, b.brdf.value) and np.array_equal(b.brdf.value, c.brdf.value)


@pytest.mark.parametrize("text, expected", [
    ("roughness = [0.1, 0.2, 0.3]", "[alpha_x, alpha_y], got 3"),
    ("roughness = [0.1]", "got 1"),
    ("roughness = [0.1, 1.2]", "outside [0.0, 1.0]"),
    ("roughness = 0.2\nrotation_deg = 30", "rotation needs an anisotropic"),
    ("roughness = [0.1, 0.3]\nrotation_deg = 400", "outside [0, 360)"),
])
def test_bad_anisotropic_input(tmp_path, text, expected):
    p = tmp_path / "bad.toml"
    p.write_text(f'name = "x"\n[[layers]]\ntype = "interface"\n{text}\nior = 1.5\n')
    with pytest.raises(StackError, match=r"layers\[0\]\.(roughness|rotation_deg)") as e:
        load_toml(p)
    assert expected in str(e.value)


def test_anisotropic_json_round_trip():
    st = Stack("a", (Interface(0.1, (1.5,) * 3, roughness_y=0.3, rotation_deg=15.0),))
    assert '"roughness":[0.1,0.3]' in st.to_json() and '"rotation_deg":15.0' in st.to_json()
    assert Stack.from_json(st.to_json()) == st
