"""Delta lobes judged on the cells (issue 33 item 5; docs/models.md §3, "Delta lobes"): Mitsuba's
smooth ``conductor`` and ``dielectric`` through the ``mitsuba:`` adapter against smooth stacks
(alpha = 0) simulated by the tracer, cell by cell within the Monte Carlo standard errors, for the
intensity and every Mueller element of a polarized file; the harness's deposit (``value / Omega``
in the cell the tracer bins the direction into) on its own."""

from __future__ import annotations

import json

import numpy as np
import pytest

import goniometer as g
from goniometer.cli import main
from goniometer.files import slices as store
from goniometer.grids.slice_grid import SliceGrid, light_direction
from goniometer.stack import Interface, Stack
from goniometer.testing.statistics import P_FALSE_ALARM, assert_z_close, noise_floor_ratio_limit
from models import registry
from models.base import DeltaLobe, Model, ModelFailure, ModelValue
from models.compare.integrate import integrate, integrate_mueller, integrate_slice

mi = pytest.importorskip("mitsuba", reason="Mitsuba 3 is a test dependency: pip install mitsuba")

#: Mitsuba computes in single precision: its values are within this fraction of the cell's largest
#: element (the simulator's conductor cells have no noise at all: every path carries F)
SINGLE = 1e-5
ETA, K = (0.2, 0.5, 1.3), (3.5, 2.5, 1.8)
GOLDISH = Stack("goldish", (Interface(0.0, ETA, K),), "metal")
GREY = Stack("grey", (Interface(0.0, (0.9,) * 3, (2.5,) * 3),), "metal")
GLASS = Stack("glass", (Interface(0.0, (1.5,) * 3),), "slab")
#: a glass plate in air: every exit leaves along the mirror or along -l (Mitsuba's thindielectric)
PLATE = Stack("plate", (Interface(0.0, (1.5,) * 3), Interface(0.0, (1.0,) * 3)), "slab")


def _rgb(x) -> dict:
    return {"type": "rgb", "value": list(x)}


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Smooth stacks simulated on small grids, lit in and out of the xz plane, and the Mitsuba files of
    the same interfaces (and of a wrong one)."""
    d = tmp_path_factory.mktemp("delta")
    out = {}
    for name, spec in (("conductor", {"type": "conductor", "eta": _rgb(ETA), "k": _rgb(K)}),
                       ("grey", {"type": "conductor", "eta": 0.9, "k": 2.5}),
                       ("dielectric", {"type": "dielectric", "int_ior": 1.5, "ext_ior": 1.0}),
                       ("wrong", {"type": "dielectric", "int_ior": 1.4, "ext_ior": 1.0}),
                       ("thin", {"type": "thindielectric", "int_ior": 1.5, "ext_ior": 1.0})):
        (d / f"{name}.json").write_text(json.dumps(spec))
        out[name] = f"mitsuba:{d / f'{name}.json'}"

    def run(stack, rays, polarized, parametrization="classic", resolution=(8, 9), incident=((55.0, 75.0), (30.0, 0.0))):
        return g.simulate(stack, g.SimulationSettings(
            rays=rays, resolution=resolution, parametrization=parametrization, polarized=polarized, seed=11,
            threads=2, incident_deg=tuple(t for t, _ in incident), incident_phi_deg=tuple(p for _, p in incident)))

    out["goldish"] = run(GOLDISH, 500, False)
    out["grey_run"] = run(GREY, 500, True, incident=((40.0, 30.0), (0.0, 0.0)))
    out["glass"] = run(GLASS, 20_000, True, incident=((60.0, 0.0), (35.0, 120.0)))
    out["glass_file"] = store.write(d / "glass.h5", out["glass"])
    out["plate"] = run(PLATE, 20_000, False)
    out["glass_half"] = run(GLASS, 20_000, False, "half", incident=((60.0, 0.0), (35.0, 120.0)))
    # every mirror direction on a cell border in theta and phi: 8 rows of 11.25 deg, 8 columns of 45 deg
    out["border"] = run(GOLDISH, 500, False, resolution=(8, 8), incident=((22.5, 0.0), (45.0, 45.0), (0.0, 0.0)))
    return out


def _sides(result):
    return [(s, sd) for s, sd in (("brdf", result.brdf), ("btdf", result.btdf)) if sd is not None]


def _delta_cos(result, side: str) -> np.ndarray:
    """|cos theta_v| of the delta cell's direction per incident direction, (M, 1, 1, 1) (the cosine a
    wrong measure would add or drop): the mirror's, the refracted one's (the stack's last index), or
    -l's (a plate)."""
    cos_l = np.cos(np.radians(result.theta_deg))
    n = result.stack.layers[-1].ior[0]
    c = cos_l if side == "brdf" else np.sqrt(1.0 - (1.0 - cos_l ** 2) / n ** 2)
    return c[:, None, None, None]


def _assert_cells(ref, stderr, model) -> None:
    """Every cell within the reference's standard errors (Z_TOL) plus single precision."""
    extra = SINGLE * np.max(np.abs(model), axis=(-1, -2), keepdims=True) if model.ndim == 6 else SINGLE * np.abs(model)
    assert_z_close(ref, stderr, model, 0.0, extra)


@pytest.mark.parametrize("key, spec", [("goldish", "conductor"), ("glass", "dielectric"), ("glass_half", "dielectric"),
                                       ("plate", "thin")])
def test_smooth_plugins_agree_with_smooth_stacks_cell_by_cell(files, key, spec):
    """The delta cell of each side holds the tracer's value within its standard errors (the
    conductor's to single precision: every path carries F), every other cell 0 on both; a value
    with the cosine counted twice or not at all is refused by the same check."""
    result, model = files[key], registry.get(files[spec])
    for side, sd in _sides(result):
        ms = integrate(model, result, side, 2)
        hit = ms.total[:, 0] > 0.0
        assert np.array_equal(hit, sd.value[:, 0] > 0.0), f"{side}: the delta lands where the tracer's exits do"
        assert np.all(np.count_nonzero(hit, axis=(1, 2)) == 1), "one cell per incident direction"
        _assert_cells(sd.value, sd.stderr, ms.total)
        cos = _delta_cos(result, side)
        for wrong in (ms.total * cos, ms.total / cos):
            with pytest.raises(AssertionError):
                _assert_cells(sd.value, sd.stderr, wrong)
        assert np.all(ms.top == 0.0), "a fixed Mitsuba BSDF has no top/internal split"


def test_a_wrong_index_is_refused(files):
    ms = integrate(registry.get(files["wrong"]), files["glass"], "btdf", 2)
    with pytest.raises(AssertionError):
        _assert_cells(files["glass"].btdf.value, files["glass"].btdf.stderr, ms.total)


@pytest.mark.parametrize("key, spec", [("grey_run", "grey"), ("glass", "dielectric")])
def test_every_mueller_element_agrees_in_the_files_frames(files, key, spec):
    """Mitsuba's polarized delta lobes taken from its stokes_basis frames to the file's s/p frames:
    all 16 elements of every cell within the standard errors (normal incidence and light out of
    the xz plane included); without the frames' conversion the elements that mix S1 and S2 leave
    them, and a missing cosine leaves them too."""
    result, model = files[key], registry.get(files[spec])
    assert model.mueller_reason(result.stack) is None
    for side, sd in _sides(result):
        mu = integrate_mueller(model, result, side, 2).mueller
        assert np.count_nonzero(mu[:, 0, ..., 0, 0]) == len(result.theta_deg)
        _assert_cells(sd.mueller, sd.mueller_stderr, mu)
        with pytest.raises(AssertionError):
            _assert_cells(sd.mueller, sd.mueller_stderr, mu / _delta_cos(result, side)[..., None, None])
        np.testing.assert_allclose(mu[..., 0, 0], integrate(model, result, side, 2).total, rtol=1e-5, atol=0.0)
    model.mueller_frames = "sp"            # read as if already in the file's frames
    try:
        mu = integrate_mueller(model, result, "brdf", 2).mueller
    finally:
        model.mueller_frames = "mitsuba"
    with pytest.raises(AssertionError):
        _assert_cells(result.brdf.mueller, result.brdf.mueller_stderr, mu)


def test_a_delta_on_cell_borders_falls_where_the_tracer_bins_it(files):
    """Mirror directions on a row and a column border (and at the pole): the cell is the tracer's,
    because the adapter takes Mitsuba's single-precision mirror for the exact one."""
    result = files["border"]
    ms = integrate(registry.get(files["conductor"]), result, "brdf", 2)
    assert np.array_equal(ms.total[:, 0] > 0.0, result.brdf.value[:, 0] > 0.0)
    _assert_cells(result.brdf.value, result.brdf.stderr, ms.total)


def test_exact_direction_takes_single_precision_to_the_tracers_directions():
    from models.production.mitsuba import exact_direction
    l = light_direction(22.5, 45.0)
    mirror = np.array([-l[0], -l[1], l[2]])
    got = exact_direction(l, mirror.astype(np.float32))
    assert np.array_equal(got, mirror)
    # a refraction: l's opposite azimuth exactly, its own polar angle
    t = np.array([-l[0], -l[1], 0.0]) / np.hypot(l[0], l[1]) * 0.4
    t[2] = -np.sqrt(1.0 - 0.16)
    t32 = t.astype(np.float32)
    got = exact_direction(l, t32)
    azimuth = np.arctan2(-l[1], -l[0])
    assert abs(np.arctan2(t32[1], t32[0]) - azimuth) > 1e-9, "single precision is off l's azimuth"
    assert abs(np.arctan2(got[1], got[0]) - azimuth) < 1e-15
    assert abs(np.linalg.norm(got) - 1.0) < 1e-12 and got[2] < 0 and abs(got[2] - t[2]) < 1e-6
    assert np.array_equal(exact_direction(np.array([0.0, 0.0, 1.0]), np.array([-0.0, -0.0, 1.0], np.float32)),
                          np.array([0.0, 0.0, 1.0]))
    assert np.array_equal(exact_direction(l, (-l).astype(np.float32)), -l)     # straight through
    other = np.array([0.3, 0.2, 0.5])
    np.testing.assert_allclose(exact_direction(l, other), other / np.linalg.norm(other), rtol=0, atol=1e-15)


def test_gonio_evaluate_judges_the_smooth_dielectric(files, capsys):
    """gonio evaluate on the polarized slab: the intensity and the Mueller matrices within their noise
    floors, notes that say the delta lobes were sampled; a wrong index far outside."""
    spec, wrong = files["dielectric"], files["wrong"]
    capsys.readouterr()
    assert main(["evaluate", str(files["glass_file"]), "--model", spec, "--model", wrong, "--subcells", "2",
                 "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["side"] == "btdf" and d["failed"] == {}
    e, w = d["models"][spec]["total"], d["models"][wrong]["total"]
    # the lobes land in a cell or two per direction: the RMSE-to-floor ratio a perfect model stays
    # under comes from those few cells' shares (noise_floor_ratio_limit; 3 channels + 18 elements)
    sd = files["glass"].btdf
    weight = (sd.proj_solid_angle * sd.mask)[:, None]
    p = P_FALSE_ALARM / (3 + 18)
    limit = noise_floor_ratio_limit(sd.stderr, weight, axis=(0, 2, 3), p=p)
    rmse, floor = np.array(e["rmse"]), np.array(e["noise_floor"])
    assert np.all(rmse <= limit * floor), rmse / floor / limit
    assert np.all(np.array(w["rmse"]) > 10.0 * limit * np.array(w["noise_floor"])), w
    assert "delta lobes (components 0, 1) are sampled by Mitsuba" in d["approximations"][spec]
    m = d["mueller"][spec]
    assert "delta lobes sampled by Mitsuba" in m["note"]
    rmse, noise = np.array(m["mueller_rmse"]), np.array(m["mueller_noise"])
    big = noise > 1e-6 * noise.max()          # the elements a dielectric leaves 0 are 0 to rounding on both sides
    assert np.count_nonzero(big) == 6 * 3     # a refraction's M00 M01 M10 M11 M22 M33 (no retardance)
    mlimit = noise_floor_ratio_limit(np.moveaxis(sd.mueller_stderr, (1, 4, 5), (3, 1, 2)), weight[:, :, None, None],
                                     axis=(0, 4, 5), p=p)     # (4, 4, C), as the errors' arrays
    assert np.all(rmse[big] <= mlimit[big] * noise[big]), rmse / np.maximum(noise, 1e-300) / mlimit


class _Lobes(Model):
    """A unit delta lobe (value 1 in each channel) along ``direction``, nothing else."""

    name = "lobes"
    sides = ("brdf", "btdf")
    polarized = True

    def __init__(self, direction, part="internal", value=(1.0, 1.0, 1.0)):
        self.direction, self.part, self.value = direction, part, value

    def support_reason(self, stack):
        return None

    def _evaluate(self, stack, l, v, side):
        z = np.zeros(v.shape[:-1] + (3,))
        return ModelValue(z, z)

    def delta_lobes(self, stack, l, side):
        return [DeltaLobe(np.asarray(self.direction, dtype=float), np.asarray(self.value), self.part)]

    def _evaluate_mueller(self, stack, l, v, side):
        return np.zeros(v.shape[:-1] + (3, 4, 4))


@pytest.mark.parametrize("parametrization", ["classic", "half"])
def test_a_lobe_carries_its_flux_value_over_the_cells_exact_projected_solid_angle(parametrization):
    """sum(value * Omega) over the cells is the lobe's flux fraction exactly, on classic and half
    grids (the exact Omega the simulator divides by, not the sub-cells' sum); a "top" lobe goes to
    top."""
    l = light_direction(35.0, 20.0)
    v = np.array([-0.3, 0.2, np.sqrt(1 - 0.13)])
    grid = SliceGrid(parametrization, 6, 10, "reflection")
    top, internal = integrate_slice(_Lobes(v, "top", (0.2, 0.5, 0.7)), GLASS, grid, l, 2)
    assert np.all(internal == 0.0) and np.count_nonzero(top[0]) == 1
    omega = grid.proj_solid_angle(l)
    np.testing.assert_allclose(np.sum(top * omega, axis=(1, 2)), [0.2, 0.5, 0.7], rtol=1e-14)
    assert top[(0, *grid.cell_of(l, v))] > 0.0


def test_lobes_off_the_side_add_nothing_and_bad_lobes_fail():
    l = light_direction(35.0, 20.0)
    grid = SliceGrid("classic", 6, 10, "transmission")
    top, internal = integrate_slice(_Lobes([0.0, 0.6, 0.8]), GLASS, grid, l, 2)
    assert np.all(top == 0.0) and np.all(internal == 0.0), "an upward lobe on the BTDF side"
    for bad, match in (([0.0, 0.6, 0.9], "not a unit vector"), ([0.0, np.nan, 1.0], "not a unit vector")):
        with pytest.raises(ModelFailure, match=match):
            integrate_slice(_Lobes(bad), GLASS, grid, l, 2)
    with pytest.raises(ModelFailure, match="lobe value of shape"):
        integrate_slice(_Lobes([0.0, 0.6, -0.8], value=(1.0, 1.0)), GLASS, grid, l, 2)
    with pytest.raises(ModelFailure, match="part 'both'"):
        integrate_slice(_Lobes([0.0, 0.6, -0.8], part="both"), GLASS, grid, l, 2)
