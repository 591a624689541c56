"""Polarized transport (docs/polarization.md) against independent references: the polarized adding
of smooth stacks (checked against tmm in test_smooth.py), the closed Fresnel and thin-film Mueller
matrices of a smooth interface, Mitsuba 3's polarized roughconductor cell by cell, the scalar run
where scalar light is exact, and the physics every Mueller matrix obeys (degree of polarization,
reciprocity)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import goniometer as g
from goniometer import optics
from goniometer.files import slices as store
from goniometer.grids.stokes import convert_mueller
from goniometer.run.settings import SettingsError
from goniometer.stack import Film, Interface, Lambertian, Medium, Stack
from goniometer.testing import Z_TOL, assert_energy_conserved, assert_samples_match, chi2_limit
from goniometer.testing.smooth import adding_energies, adding_mueller

SLAB = Stack("slab", (Interface(0.0, (1.5,) * 3), Medium((0.0, 0.5, 1.0)), Interface(0.0, (1.0,) * 3)), "slab")
METAL = Stack("metal", (Interface(0.3, (0.2, 0.9, 1.3), (3.5, 2.5, 2.0)),), "metal")


def _settings(**kw) -> g.SimulationSettings:
    base = dict(rays=100_000, resolution=(3, 12), polarized=True, seed=5, threads=2)
    base.update(kw)
    return g.SimulationSettings(**base)


def _hemisphere(sd, m: int) -> tuple[np.ndarray, np.ndarray]:
    """The Mueller matrix summed over one side's cells (C, 4, 4), and a standard error that bounds
    the sum's (the cells' variances added: a path exits through one cell, so the cells'
    contributions are anticorrelated and this overestimates)."""
    om = sd.proj_solid_angle[m][None, :, :, None, None]
    total = (sd.mueller[m] * om).sum(axis=(1, 2))
    se = np.sqrt(((sd.mueller_stderr[m] * om) ** 2).sum(axis=(1, 2)))
    return total, se


def _block(terms: np.ndarray) -> np.ndarray:
    """The Mueller matrices (C, 4, 4) of an event's (a, b, c, s) per channel ((4, C))."""
    a, b, c, s = terms
    out = np.zeros((a.shape[0], 4, 4))
    out[:, 0, 0] = out[:, 1, 1] = a
    out[:, 0, 1] = out[:, 1, 0] = b
    out[:, 2, 2] = out[:, 3, 3] = c
    out[:, 2, 3] = s
    out[:, 3, 2] = -s
    return out


@pytest.fixture(scope="module")
def slab_run():
    return g.simulate(SLAB, _settings(incident_deg=(0.0, 60.0, 80.0), rays=150_000))


def test_a_smooth_slab_is_the_polarized_adding_and_not_the_scalar_one(slab_run):
    """Every element of a smooth slab's reflection and transmission Mueller matrices (every order
    of internal reflection, s and p added separately, absorption per channel) is the closed form of
    goniometer.testing.smooth.adding_mueller; the scalar adding (every event unpolarized) is refused
    at oblique incidence by the same tolerance."""
    r = slab_run
    assert r.brdf.polarized and r.btdf.polarized
    assert np.allclose(r.brdf.mueller[..., 0, 0], r.brdf.value, rtol=1e-12, atol=0)   # (summed otherwise)
    assert_energy_conserved(r)
    scalar_seen = 0
    for m, theta in enumerate(r.theta_deg):
        R, T = adding_mueller(SLAB, theta)
        scalar_R, scalar_T = adding_energies(SLAB, theta)
        for sd, want, scalar in ((r.brdf, R, scalar_R), (r.btdf, T, scalar_T)):
            got, se = _hemisphere(sd, m)
            ref = _block(want)
            assert np.all(np.abs(got - ref) <= Z_TOL * se + 1e-12), (theta, got - ref, se)
            # the scalar value lies outside the polarized estimate's band where the two differ
            far = np.abs(got[:, 0, 0] - scalar) > Z_TOL * se[:, 0, 0]
            scalar_seen += int(np.sum(far))
    assert scalar_seen >= 6


@pytest.mark.parametrize("theta", [20.0, 70.0])
def test_a_smooth_conductor_and_a_filmed_interface_are_their_fresnel_mueller_matrices(theta):
    """One event: the closed matrices of goniometer.optics (themselves checked against tmm and
    Mitsuba 3), for a conductor and for a dielectric under a thin film, reflection and refraction."""
    c = math.cos(math.radians(theta))
    cond = Stack("m", (Interface(0.0, (0.2, 0.9, 1.3), (3.5, 2.5, 2.0)),), "metal")
    r = g.simulate(cond, _settings(incident_deg=(theta,), rays=20_000))
    got, se = _hemisphere(r.brdf, 0)
    want = _block(np.array([optics.fresnel_conductor_mueller(c, n, k) for n, k in
                            zip((0.2, 0.9, 1.3), (3.5, 2.5, 2.0))]).T)
    assert np.allclose(got, want, atol=1e-12)      # a smooth mirror: every path the same
    film = Stack("f", (Interface(0.0, (1.5,) * 3, film=Film(350.0, (1.38,) * 3)),), "other",
                 wavelengths_nm=(450.0, 550.0, 650.0))
    r = g.simulate(film, _settings(incident_deg=(theta,), rays=200_000))
    assert_energy_conserved(r)
    terms = np.array([optics.film_mueller(c, 1.0, 1.38, 0.0, 1.5, 0.0, 350.0 / lam) for lam in (450, 550, 650)]).T
    for sd, part in ((r.brdf, terms[:4]), (r.btdf, terms[4:])):
        got, se = _hemisphere(sd, 0)
        assert np.all(np.abs(got - _block(part)) <= Z_TOL * se + 1e-12), (got - _block(part), se)


def test_one_interface_gives_the_scalar_runs_intensity():
    """Unpolarized light meeting one Fresnel event: M00 is what scalar light gives (two independent
    runs, a two-sample chi-square)."""
    s = dict(incident_deg=(0.0, 40.0, 75.0), rays=200_000, resolution=(9, 18), threads=2)
    pol = g.simulate(METAL, g.SimulationSettings(polarized=True, seed=2, **s))
    sca = g.simulate(METAL, g.SimulationSettings(seed=3, **s))
    assert sca.brdf.mueller is None and pol.settings.polarized and not sca.settings.polarized
    assert_samples_match(pol.brdf.value, pol.brdf.stderr, sca.brdf.value, sca.brdf.stderr,
                         where=np.broadcast_to(sca.brdf.mask[:, None], sca.brdf.value.shape))


def _mitsuba_cells(r, m: int, stack: Stack = METAL, sub: int = 6) -> np.ndarray:
    """Cell means (C, nt, nph, 4, 4) of Mitsuba 3's polarized roughconductor (scalar_spectral_polarized,
    GGX, separable masking, each channel's complex index; ``alpha_u`` along the stack's x, Mitsuba's
    local frame for the normal z), taken from its stokes_basis frames to the
    s/p frames of each sub-cell direction and weighted by |cos| dw (``sub x sub`` midpoints)."""
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_spectral_polarized")
    layer = stack.layers[0]
    assert layer.rotation_deg == 0.0
    grid = r.brdf.grid
    te, pe = np.radians(grid.theta_edges_deg()), np.radians(grid.phi_edges_deg())
    nt, nph = len(te) - 1, len(pe) - 1
    f = (np.arange(sub) + 0.5) / sub
    tl, pl = math.radians(r.theta_deg[m]), math.radians(r.phi_deg[m])
    light = np.array([math.sin(tl) * math.cos(pl), math.sin(tl) * math.sin(pl), math.cos(tl)])
    out = np.zeros((3, nt, nph, 4, 4))
    ctx = mi.BSDFContext()
    for ch in range(3):
        bsdf = mi.load_dict({"type": "roughconductor", "distribution": "ggx", "alpha_u": layer.alpha_xy[0],
                             "alpha_v": layer.alpha_xy[1], "sample_visible": True, "eta": layer.ior[ch], "k": layer.extinction[ch]})
        si = mi.SurfaceInteraction3f()
        si.wavelengths = [550.0] * 4
        si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
        si.n = mi.Vector3f(0, 0, 1)
        for i in range(nt):
            for j in range(nph):
                acc = np.zeros((4, 4))
                den = 0.0
                for a in te[i] + (te[i + 1] - te[i]) * f:
                    for b in pe[j] + (pe[j + 1] - pe[j]) * f:
                        v = np.array([math.sin(a) * math.cos(b), math.sin(a) * math.sin(b), math.cos(a)])
                        si.wi = mi.Vector3f(*v)             # Mitsuba's wi: towards the viewer, our v
                        val = np.array(bsdf.eval(ctx, si, mi.Vector3f(*light)))[:, :, 0]   # f cos(theta_l)
                        ours = convert_mueller(val / light[2], light, v, "mitsuba", "sp", r.phi_deg[m],
                                               math.degrees(b))
                        w = math.sin(a) * math.cos(a)
                        acc += ours * w
                        den += w
                out[ch, i, j] = acc / den
    return out


#: rough conductors of several roughnesses and complex indices, one anisotropic (the first in the
#: regular suite, the others in ``make test-slow``)
ROUGH_CONDUCTORS = [
    pytest.param(METAL, id="alpha0.3"),
    pytest.param(Stack("m1", (Interface(0.15, (0.15, 0.4, 1.2), (3.6, 2.9, 2.3)),), "metal"), id="alpha0.15",
                 marks=pytest.mark.slow),
    pytest.param(Stack("m5", (Interface(0.6, (2.8, 2.9, 3.0), (3.0, 3.1, 3.3)),), "metal"), id="alpha0.6",
                 marks=pytest.mark.slow),
    pytest.param(Stack("ma", (Interface(0.15, (1.1, 0.6, 0.3), (2.0, 2.6, 3.2), roughness_y=0.45),), "metal"),
                 id="anisotropic", marks=pytest.mark.slow),
]


@pytest.mark.parametrize("stack", ROUGH_CONDUCTORS)
def test_a_rough_conductor_is_mitsubas_polarized_roughconductor_cell_by_cell(stack):
    """All 16 elements, cell by cell, per channel, at two incidences (one out of the xz plane).
    One chi-square per element and channel over the cells where 200 paths are expected (a cell's
    paths are its own: the cells are independent; the channels and elements of one cell share
    them, so each gets its own test, at the suite's false-alarm probability split among them). Each
    element's standard error is the cell's own estimate: a ratio of estimates has heavier tails
    than a normal one (about 1 + 2 / n for n paths), hence the 200. A sign convention gone wrong
    (S2 reversed on the way out) fails."""
    r = g.simulate(stack, _settings(incident_deg=(30.0, 60.0), incident_phi_deg=(0.0, 40.0), rays=400_000,
                                    resolution=(8, 16)))
    models = [_mitsuba_cells(r, m, stack) for m in range(2)]
    sel = np.stack([r.settings.rays * mo[..., 0, 0] * r.brdf.proj_solid_angle[m][None] >= 200
                    for m, mo in enumerate(models)])                       # (M, C, nt, nph)
    model = np.stack(models)
    sim, se = r.brdf.mueller, r.brdf.mueller_stderr
    tests = [(i, j, c) for i in range(4) for j in range(4) for c in range(3) if np.any(se[:, c, ..., i, j][sel[:, c]])]
    p = 1e-6 / len(tests)
    worst = 0.0
    flipped = 0.0
    for i, j, c in tests:
        s = sel[:, c] & (se[:, c, ..., i, j] > 0)
        z = (sim[:, c, ..., i, j] - model[:, c, ..., i, j])[s] / se[:, c, ..., i, j][s]
        n = int(np.count_nonzero(s))
        assert n >= 100
        ratio = float(np.sum(z * z)) / chi2_limit(n, p)
        worst = max(worst, ratio)
        sign = -1.0 if i == 2 else 1.0
        zf = (sim[:, c, ..., i, j] - sign * model[:, c, ..., i, j])[s] / se[:, c, ..., i, j][s]
        flipped = max(flipped, float(np.sum(zf * zf)) / chi2_limit(n, p))
    assert len(tests) == 14 * 3     # M03, M30 stay 0 for a conductor's block matrices: no test
    assert worst < 1.0, worst
    assert flipped > 1.0


def test_the_degree_of_polarization_is_never_above_one(slab_run):
    """Each cell's Mueller matrix sends unpolarized and fully polarized light to a degree of
    polarization of at most 1, within its standard errors (a coated conductor and the slab)."""
    coated = Stack("cm", (Interface(0.2, (1.5,) * 3), Medium((0.2,) * 3),
                          Interface(0.3, (0.2, 0.9, 1.3), (3.5, 2.5, 2.0))), "metal")
    runs = [slab_run, g.simulate(coated, _settings(incident_deg=(50.0,), rays=60_000, resolution=(6, 12)))]
    inputs = np.array([[1, 0, 0, 0], [1, 1, 0, 0], [1, -1, 0, 0], [1, 0, 1, 0], [1, 0, 0, 1], [1, 0, 0, -1.0]])
    for r in runs:
        for sd in (r.brdf, r.btdf):
            if sd is None:
                continue
            out = sd.mueller @ inputs.T                      # (..., 4, inputs)
            se = np.sqrt(sd.mueller_stderr ** 2 @ (inputs.T ** 2))
            pol = np.sqrt(np.sum(out[..., 1:, :] ** 2, axis=-2))
            # |S_pol| - S0, with the standard error of the difference bounded by the components' sum
            excess = pol - out[..., 0, :]
            bound = Z_TOL * np.sum(se, axis=-2)
            assert np.all(excess <= bound + 1e-12), float(np.max(excess - bound))


def test_reflection_is_reciprocal_with_the_transpose_relation():
    """Helmholtz reciprocity of Mueller matrices in the s/p frames: M(v -> l) = D M(l -> v)^T D,
    D = diag(1, 1, -1, 1), on a coated diffuse stack (a rough coat polarizes what the base
    depolarized): the cell around v lit from l against the cell around l lit from v, cells small
    beside the BRDF's variation."""
    plastic = Stack("p", (Interface(0.3, (1.5,) * 3), Medium((0.1,) * 3), Lambertian((0.8,) * 3)), "plastic")
    a_deg, b_deg = (40.5, 3.0), (61.5, 153.0)      # cell centres of the 3 x 6 degree grid
    res = (30, 60)
    runs = {}
    for (t1, p1), (t2, p2) in ((a_deg, b_deg), (b_deg, a_deg)):
        s = _settings(incident_deg=(t1,), incident_phi_deg=(p1,), rays=1_500_000, resolution=res, seed=11)
        r = g.simulate(plastic, s)
        i = int(t2 / (90.0 / res[0]))
        j = int(p2 / (360.0 / res[1]))
        runs[(t1, p1)] = (r.brdf.mueller[0, :, i, j], r.brdf.mueller_stderr[0, :, i, j])
    (m1, s1), (m2, s2) = runs[a_deg], runs[b_deg]
    D = np.diag([1.0, 1.0, -1.0, 1.0])
    rev = D @ np.swapaxes(m1, -1, -2) @ D
    se = np.hypot(np.swapaxes(s1, -1, -2), s2)
    zero = se == 0.0                          # elements no path changes (0 on both sides)
    assert np.all(m2[zero] == 0.0) and np.all(rev[zero] == 0.0)
    assert np.all(np.abs(m2 - rev)[~zero] <= Z_TOL * se[~zero]), (m2 - rev) / np.where(zero, 1.0, se)
    # the relation is not empty: the coat's polarization is seen in the off-diagonal block
    assert np.all(np.abs(m1[:, 1, 0]) > Z_TOL * s1[:, 1, 0])


def test_polarized_files_and_settings(tmp_path, slab_run):
    """A polarized result writes /brdf/mueller and reads back bit for bit; a polarized run's
    identity says so; integrating order 1 is refused (it is the intensity's closed form)."""
    p = store.write(tmp_path / "s.h5", slab_run)
    back = g.read(p)
    assert back.settings.polarized
    for a, b in ((back.brdf, slab_run.brdf), (back.btdf, slab_run.btdf)):
        assert np.array_equal(a.mueller, b.mueller) and np.array_equal(a.mueller_stderr, b.mueller_stderr)
    assert "polarized" in slab_run.settings.to_dict()
    assert "polarized" not in g.SimulationSettings().to_dict()
    with pytest.raises(SettingsError, match="first_order: integrated is for scalar runs"):
        g.SimulationSettings(polarized=True, first_order="integrated")
    with pytest.raises(SettingsError, match="polarized: 'yes' is not a boolean"):
        g.SimulationSettings(polarized="yes")


def test_gonio_simulate_polarized_and_info(tmp_path, capsys):
    """--polarized, or [simulation] polarized = true, writes a polarized file that info describes;
    --first-order integrated with it is one line, exit 2."""
    from goniometer.cli import main
    from tests.conftest import PLASTIC_TOML
    cfg = tmp_path / "p.toml"
    cfg.write_text(PLASTIC_TOML + "[simulation]\nincident_deg = [30]\nrays = 3000\nresolution = [3, 6]\n")
    out = tmp_path / "p.h5"
    assert main(["simulate", str(cfg), "--out", str(out), "--polarized", "--threads", "1"]) == 0
    assert g.read(out).brdf.mueller.shape == (1, 3, 3, 6, 4, 4)
    capsys.readouterr()
    assert main(["info", str(out)]) == 0
    assert "polarized: each cell holds its Mueller matrix" in capsys.readouterr().out
    cfg.write_text(cfg.read_text() + "polarized = true\n")
    assert main(["simulate", str(cfg), "--out", str(tmp_path / "q.h5"), "--threads", "1"]) == 0
    assert g.read(tmp_path / "q.h5").settings.polarized
    capsys.readouterr()
    assert main(["simulate", str(cfg), "--out", str(tmp_path / "r.h5"), "--first-order", "integrated"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "first_order: integrated is for scalar runs" in err, err


def test_a_polarized_run_on_cuda_is_accepted():
    """The CUDA kernel traces polarized light (tests/goniometer/kernel/test_cuda.py runs it)."""
    s = g.SimulationSettings(polarized=True, device="cuda")
    assert s.to_dict()["polarized"] and s.to_dict()["device"] == "cuda"
