"""Multiple scattering on rough interfaces (Heitz et al. 2016) against independent references.

* White furnace: a perfectly reflecting conductor (Fresnel exactly 1: extinction 1e10) has
  albedo 1 at every roughness and angle, and a non-absorbing dielectric keeps R + T = 1, path by
  path (so exactly, to rounding), from above and from below.
* The walk's first bounce (exits after one microfacet bounce, histogrammed here from
  :func:`goniometer.kernel.steps.microsurface_walk`) equals, cell by cell, what the simulator gives for
  the single-scattering interface with height-correlated masking (reflection and transmission).
* Energy: the single-scattering masking loss (height-correlated) equals what the walk's
  higher orders (two or more microfacet bounces) add back, for a Fresnel = 1 conductor.
* Reciprocity of the multiple-scattering conductor BRDF, determinism for 1 and 2 threads,
  the stack key (canonical JSON, bad input: one line, exit status 2) and the CLI flag.

Tolerances are statistical: z-scores within Z_TOL (false-alarm probability P_FALSE_ALARM = 1e-6,
two-sided) of the combined Monte Carlo standard errors and chi-square limits at the same
probability (:mod:`goniometer.testing`, docs/testing.md); quantities that hold path by path are
checked to 1e-9.
"""

from __future__ import annotations

import json
import math

import numba
import numpy as np
import pytest

from goniometer.cli import main
from goniometer.kernel.rng import stream_state
from goniometer.run.loop import simulate
from goniometer.run.settings import SimulationSettings
from goniometer.grids.slice_grid import boundary_tables, cell_index_fast, light_direction
from goniometer.stack import Interface, Lambertian, Medium, Stack, StackError, stack_from_dict
from goniometer.kernel.steps import microsurface_walk
from goniometer.testing import Z_TOL, assert_samples_match, assert_z_close

#: a conductor whose Fresnel reflectance is exactly 1.0 in double precision at every angle
MIRROR = dict(ior=(1.0,) * 3, extinction=(1e10,) * 3)


def mirror(alpha, ms=True, rotation=0.0) -> Stack:
    ax, ay = (alpha, None) if np.isscalar(alpha) else alpha
    return Stack("mirror", (Interface(ax, roughness_y=ay, rotation_deg=rotation, multiple_scattering=ms, **MIRROR),))


# ----------------------------------------------------------------------------- the walk, histogrammed


#: MIRROR's complex index as the walk takes it (n per channel, then k per channel)
_FRESNEL_ONE = np.array(MIRROR["ior"] + MIRROR["extinction"])
#: the film row of an interface without a film (the walk compiled without films does not read it)
_NO_FILM = np.zeros(0)


@numba.njit(cache=True)
def _walk_cells(lx, ly, lz, ax, ay, eta, conductor, n_rays, seed, param, nt, nph, row_cos, col_cos, col_sin):
    """Walk ``n_rays`` times from ``l`` (Fresnel-1 conductor, or a dielectric of relative index
    ``eta``); returns per side (0 reflected, 1 transmitted) and walk order (0: one microfacet
    bounce, 1: two or more) the hit counts per cell (all weights are 1), and the exits per order."""
    state = stream_state(np.uint64(seed), np.uint64(0), np.uint64(0))
    h = np.zeros((2, 2, nt, nph))
    per_order = np.zeros(2)
    for _ in range(n_rays):
        ox, oy, oz, f0, f1, f2, n, transmitted = microsurface_walk(
            lx, ly, lz, ax, ay, conductor, _FRESNEL_ONE, True, True, eta, 1.0 / eta, 10_000, state, None, _NO_FILM,
            True)
        o = 0 if n == 1 else 1
        side = 1 if transmitted else 0
        i, j = cell_index_fast(param, transmitted, lx, ly, lz, ox, oy, oz, nt, nph, row_cos, col_cos, col_sin)
        h[side, o, i, j] += f0
        per_order[o] += f0
    return h, per_order


def walk_cells(theta, phi, ax, ay, eta, conductor, rays, resolution, seed=11):
    l = light_direction(theta, phi)
    tables = boundary_tables("classic", *resolution)
    return _walk_cells(l[0], l[1], l[2], ax, ay, eta, conductor, rays, seed, 0, resolution[0], resolution[1],
                       *tables)


# ----------------------------------------------------------------------------- white furnace


@pytest.mark.parametrize("alpha, rotation", [(0.0, 0.0), (0.05, 0.0), (0.3, 0.0), (1.0, 0.0), ((0.1, 0.9), 30.0)])
def test_white_furnace_conductor(alpha, rotation):
    """Fresnel = 1: every path is reflected with weight 1 (no masking loss, nothing capped), while
    single scattering loses energy at the same roughness (except the smooth mirror)."""
    inc = (0.0, 45.0, 80.0, 89.0)
    s = SimulationSettings(incident_deg=inc, incident_phi_deg=(0.0, 10.0, 100.0, 0.0), rays=20_000,
                           resolution=(9, 18), threads=1)
    r = simulate(mirror(alpha, True, rotation), s)
    np.testing.assert_allclose(r.energy["reflected"], 1.0, rtol=0, atol=1e-9)
    for k in ("masking_loss", "transmitted", "absorbed"):
        assert np.all(r.energy[k] == 0.0), k
    assert np.all(r.roulette == 0.0) and np.all(r.capped == 0.0) and np.all(r.capped_paths == 0)
    if alpha != 0.0:
        ss = simulate(mirror(alpha, False, rotation), s.with_overrides(masking="height-correlated"))
        assert np.all(ss.energy["masking_loss"][:, 0] > 0.0)


@pytest.mark.parametrize("stack", [
    Stack("d", (Interface(0.5, (1.5,) * 3, multiple_scattering=True),)),
    Stack("d", (Interface(1.0, (1.5,) * 3, multiple_scattering=True),)),
    Stack("d", (Interface(0.4, (0.6,) * 3, multiple_scattering=True),)),
    Stack("d", (Interface(0.2, (1.33,) * 3, roughness_y=0.8, rotation_deg=60.0, multiple_scattering=True),)),
    # a slab: the second interface is met from above and (after reflections) the first from below
    Stack("slab", (Interface(0.7, (1.5,) * 3, multiple_scattering=True),
                   Interface(0.3, (1.0,) * 3, multiple_scattering=True))),
], ids=["a0.5", "a1", "eta0.6", "aniso", "slab"])
def test_white_furnace_dielectric(stack):
    """A non-absorbing dielectric keeps R + T = 1 path by path at every roughness and angle."""
    s = SimulationSettings(incident_deg=(0.0, 40.0, 75.0, 89.0), rays=20_000, resolution=(9, 18), threads=1)
    r = simulate(stack, s)
    np.testing.assert_allclose(r.energy["reflected"] + r.energy["transmitted"], 1.0, rtol=0, atol=1e-9)
    for k in ("masking_loss", "absorbed"):
        assert np.all(r.energy[k] == 0.0), k
    assert np.all(r.roulette == 0.0) and np.all(r.capped == 0.0) and np.all(r.capped_paths == 0)
    assert np.all(r.energy["reflected"] > 0.0) and np.all(r.energy["transmitted"] > 0.0)


# ----------------------------------------------------------------------------- first bounce = single scattering


@pytest.mark.parametrize("case", [
    dict(alpha=(0.6, 0.6), eta=1.0, conductor=True, theta=40.0, phi=0.0),
    dict(alpha=(1.0, 1.0), eta=1.0, conductor=True, theta=75.0, phi=0.0, power=True),
    dict(alpha=(0.2, 0.7), eta=1.0, conductor=True, theta=60.0, phi=30.0),
    dict(alpha=(0.5, 0.5), eta=1.5, conductor=False, theta=50.0, phi=0.0),
    dict(alpha=(0.5, 0.5), eta=1 / 1.5, conductor=False, theta=20.0, phi=0.0),
], ids=["conductor", "conductor-grazing", "aniso-conductor", "dielectric", "dielectric-inverted"])
def test_first_bounce_is_single_scattering(case):
    """The walk's exits after one microfacet bounce, cell by cell, against the simulator's
    single-scattering interface with height-correlated masking (same stack, flag off):
    two-sample chi-square over the cells where both have >= 25 expected hits, reflection and
    (dielectric) transmission; the first-bounce energy within Z_TOL combined standard errors. At
    grazing incidence on alpha = 1 the same energy test rejects separable masking (a check of its
    power: elsewhere the two masking models differ by less than the noise of 400 000 rays)."""
    ax, ay = case["alpha"]
    rays, res = 400_000, (18, 36)
    if case["conductor"]:
        layer = Interface(ax, roughness_y=ay if ay != ax else None, **MIRROR)
    else:
        layer = Interface(ax, (case["eta"],) * 3, roughness_y=ay if ay != ax else None)
    ref = simulate(Stack("ss", (layer,)), SimulationSettings(
        incident_deg=(case["theta"],), incident_phi_deg=(case["phi"],), rays=rays, resolution=res, threads=1,
        masking="height-correlated", seed=5))
    h, per_order = walk_cells(case["theta"], case["phi"], ax, ay, case["eta"], case["conductor"], rays, res)
    sides = [(ref.brdf, h[0, 0])] + ([] if case["conductor"] else [(ref.btdf, h[1, 0])])
    first = 0.0
    for sl, counts in sides:
        om = sl.proj_solid_angle[0]
        a, sa = sl.value[0][0], sl.stderr[0][0]
        with np.errstate(divide="ignore", invalid="ignore"):
            b = np.where(om > 0, counts / (rays * om), 0.0)
            sb = np.where(om > 0, np.sqrt(counts) / (rays * om), 0.0)
        sel = ((a + b) * rays * om >= 50.0) & (om > 0)
        assert_samples_match(a, sa, b, sb, sel, min_cells=60)
        first += counts.sum() / rays
    ss = ref.energy["reflected"][0, 0] + ref.energy["transmitted"][0, 0]
    ss_se = math.hypot(ref.energy_stderr["reflected"][0, 0], ref.energy_stderr["transmitted"][0, 0])
    assert_z_close(first, math.sqrt(first * (1 - first) / rays), ss, ss_se)
    if not case.get("power"):
        return
    # the test can tell the masking models apart: separable masking's energy is rejected
    sep = simulate(Stack("ss", (layer,)), SimulationSettings(
        incident_deg=(case["theta"],), incident_phi_deg=(case["phi"],), rays=rays, resolution=(1, 1), threads=1,
        masking="separable", seed=6))
    sep_e = sep.energy["reflected"][0, 0] + sep.energy["transmitted"][0, 0]
    assert abs(first - sep_e) > Z_TOL * math.hypot(math.sqrt(first * (1 - first) / rays), ss_se)


# ----------------------------------------------------------------------------- energy


@pytest.mark.parametrize("alpha", [0.3, 1.0, (0.1, 0.9)])
def test_masking_loss_is_what_higher_orders_add_back(alpha):
    """Fresnel = 1: the single-scattering masking loss (height-correlated) at each angle equals the
    fraction of walks that leave after two or more microfacet bounces, within Z_TOL combined
    standard errors; and the simulator's reflected energy with the flag on is 1 = order 1 + the rest."""
    ax, ay = (alpha, alpha) if np.isscalar(alpha) else alpha
    inc = (0.0, 50.0, 80.0)
    rays = 200_000
    ss = simulate(mirror(alpha, False), SimulationSettings(
        incident_deg=inc, rays=rays, resolution=(3, 4), threads=1, masking="height-correlated", seed=3))
    for m, theta in enumerate(inc):
        _, per_order = walk_cells(theta, 0.0, ax, ay, 1.0, True, rays, (3, 4), seed=20 + m)
        assert per_order.sum() == rays
        higher = per_order[1] / rays
        loss, loss_se = ss.energy["masking_loss"][m, 0], ss.energy_stderr["masking_loss"][m, 0]
        assert_z_close(higher, math.sqrt(higher * (1 - higher) / rays), loss, loss_se)


# ----------------------------------------------------------------------------- reciprocity


def test_multiple_scattering_brdf_is_reciprocal():
    """f(l, v) = f(v, l) for a rough coloured conductor with multiple scattering: slices at 21 and
    51 deg compared at the reciprocal cells column by column (as the scattering-media test does),
    chi-square over cells both slices hit."""
    st = Stack("r", (Interface(0.9, (0.2, 0.9, 1.5), (3.0, 2.0, 1.0), multiple_scattering=True),))
    r = simulate(st, SimulationSettings(incident_deg=(21.0, 51.0), rays=1_500_000, resolution=(45, 90), seed=4))
    a, sa = r.brdf.value[0][:, 25, :], r.brdf.stderr[0][:, 25, :]
    b, sb = r.brdf.value[1][:, 10, :], r.brdf.stderr[1][:, 10, :]
    sel = (sa > 0) & (sb > 0)
    assert_samples_match(a, sa, b, sb, sel, min_cells=200)
    # the higher orders matter here: the reflected energy exceeds single scattering's
    ss = simulate(st.with_multiple_scattering(False), SimulationSettings(
        incident_deg=(51.0,), rays=100_000, resolution=(3, 4), masking="height-correlated"))
    assert r.energy["reflected"][1, 0] > ss.energy["reflected"][0, 0] + 0.05


# ----------------------------------------------------------------------------- determinism


def test_same_bits_for_any_thread_count():
    st = Stack("p", (Interface(0.5, (1.5,) * 3, multiple_scattering=True), Medium((0.1, 0.2, 0.3)),
                     Interface(0.3, (1.1, 0.9, 0.5), (2.0, 2.5, 3.0), roughness_y=0.6, rotation_deg=20.0,
                               multiple_scattering=True)))
    s = SimulationSettings(incident_deg=(30.0, 70.0), rays=60_000, resolution=(9, 18), chunk_rays=4096, seed=9)
    a = simulate(st, s.with_overrides(threads=1))
    b = simulate(st, s.with_overrides(threads=2))
    for x, y in ((a.brdf.value, b.brdf.value), (a.brdf.stderr, b.brdf.stderr), (a.btdf is None, b.btdf is None)):
        assert np.array_equal(x, y)
    for k in a.energy:
        assert np.array_equal(a.energy[k], b.energy[k]), k
    assert np.array_equal(a.roulette, b.roulette) and np.array_equal(a.capped, b.capped)


# ----------------------------------------------------------------------------- stack key, CLI


def test_canonical_json_omits_the_default():
    layer = {"type": "interface", "roughness": 0.05, "ior": 1.5}
    st = stack_from_dict({"name": "x", "layers": [layer]})
    assert st.to_json() == '{"category":"other","layers":[{"ior":1.5,"roughness":0.05,"type":"interface"}],"name":"x"}'
    assert stack_from_dict({"name": "x", "layers": [dict(layer, multiple_scattering=False)]}).to_json() == st.to_json()
    on = stack_from_dict({"name": "x", "layers": [dict(layer, multiple_scattering=True)]})
    assert '"multiple_scattering":true' in on.to_json()
    assert Stack.from_json(on.to_json()) == on == st.with_multiple_scattering()
    assert on.with_multiple_scattering(False) == st


GOOD = """name = "ms"
[[layers]]
type = "interface"
roughness = 0.3
ior = 1.5
[[layers]]
type = "medium"
optical_depth = 0.1
[[layers]]
type = "interface"
roughness = 0.4
ior = 1.0
extinction = 3.0
"""

BAD = [
    (GOOD.replace("ior = 1.5\n", "ior = 1.5\nmultiple_scattering = 1\n"),
     "layers[0].multiple_scattering: 1 is not a boolean (true or false)"),
    (GOOD.replace("ior = 1.5\n", 'ior = 1.5\nmultiple_scattering = "yes"\n'),
     "layers[0].multiple_scattering: 'yes' is not a boolean"),
    (GOOD.replace("optical_depth = 0.1\n", "optical_depth = 0.1\nmultiple_scattering = true\n"),
     "layers[1].multiple_scattering: only an interface layer takes multiple_scattering (this layer is a medium)"),
]


@pytest.mark.parametrize("text, expected", BAD)
def test_bad_input_is_one_line_exit_2(tmp_path, capsys, text, expected):
    cfg = tmp_path / "bad.toml"
    cfg.write_text(text)
    out = tmp_path / "out.h5"
    assert main(["simulate", str(cfg), "--out", str(out), "--multiple-scattering"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("gonio: error: ") and expected in err and "\n" not in err, err
    assert not out.exists()


def test_python_stack_refuses_a_non_boolean():
    with pytest.raises(StackError, match=r"multiple_scattering: 'yes' is not a boolean"):
        Stack("x", (Interface(0.1, (1.5,) * 3, multiple_scattering="yes"),))


def test_cli_flag_switches_every_interface_and_the_file_records_it(tmp_path, capsys):
    cfg = tmp_path / "ms.toml"
    cfg.write_text(GOOD)
    out = tmp_path / "ms.h5"
    assert main(["simulate", str(cfg), "--out", str(out), "--rays", "2000", "--incident", "30",
                 "--resolution", "4x8", "--multiple-scattering"]) == 0
    capsys.readouterr()
    assert main(["info", str(out), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    layers = info["material"]["config"]["layers"]
    assert [x.get("multiple_scattering") for x in layers] == [True, None, True]
    assert info["energy"][0]["masking_loss"] == [0.0, 0.0, 0.0]


def test_masking_setting_does_not_touch_a_multiple_scattering_interface():
    """The walk is height-correlated by construction: with only multiple-scattering interfaces,
    --masking separable and height-correlated give the same bits."""
    st = Stack("p", (Interface(0.5, (1.5,) * 3, multiple_scattering=True), Medium((0.1, 0.2, 0.3)),
                     Interface(0.4, (1.1, 0.9, 0.5), (2.0, 2.5, 3.0), multiple_scattering=True)))
    s = SimulationSettings(incident_deg=(60.0,), rays=20_000, resolution=(9, 18), threads=1)
    a = simulate(st, s.with_overrides(masking="separable"))
    b = simulate(st, s.with_overrides(masking="height-correlated"))
    assert np.array_equal(a.brdf.value, b.brdf.value)
    assert all(np.array_equal(a.energy[k], b.energy[k]) for k in a.energy)
