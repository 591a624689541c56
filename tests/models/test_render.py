"""Lit-sphere renderings (models/render/, gonio render; docs/render.md): the Lambert sphere in
closed form, symmetry about the light plane, exact interpolation at recorded directions, one
exposure across panels, and the command's one-line errors."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import goniometer as g
from goniometer.files import slices as store
from goniometer.grids.slice_grid import light_direction
from goniometer.cli import main as gonio
from models.render import (BTDF, ModelBSDF, SphereView, open_reference, render_spheres, slices_reference,
                           srgb_oetf)
from models.render.compare import REFERENCE, SphereSet
from models import registry

RHO = np.array([0.2, 0.5, 0.8])
INCIDENTS = (0.0, 30.0, 60.0)


def _simulate(stack: dict, parametrization: str, resolution=(9, 36)) -> g.SimulationResult:
    st = g.stack_from_dict(stack)
    return g.simulate(st, g.SimulationSettings(incident_deg=INCIDENTS, rays=20_000, resolution=resolution, seed=5,
                                               parametrization=parametrization, threads=1))


LAMBERT = {"name": "lambert", "category": "other", "layers": [{"type": "lambertian", "albedo": list(RHO)}]}
METAL = {"name": "metal", "category": "metal",
         "layers": [{"type": "interface", "roughness": 0.2, "ior": 1.5},
                    {"type": "medium", "optical_depth": [0.05, 0.1, 0.4]},
                    {"type": "interface", "roughness": 0.2, "ior": 1.2, "extinction": [1.0, 0.01, 0.01]}]}


@pytest.fixture(scope="module")
def lambert_classic():
    return _simulate(LAMBERT, "classic")


@pytest.fixture(scope="module")
def metal_half():
    return _simulate(METAL, "half", (12, 48))


def _pixels(size: int):
    """Pixel centres and sphere normals written from the definition (docs/render.md), independently
    of models.render.sphere."""
    c = (np.arange(size) + 0.5) / size * 2.0 - 1.0
    x, y = np.meshgrid(c, -c)
    inside = x * x + y * y < 1.0
    nz = np.sqrt(np.clip(1.0 - x * x - y * y, 0.0, None))
    return x, y, nz, inside


def test_lambertian_sphere_is_the_lambert_shading(lambert_classic, tmp_path):
    """A Lambertian reference (rho / pi in every cell) renders to rho / pi * max(0, n.L) * E with
    E = 1, for a light at 30 deg from the view in the y-z plane; lights beyond the recorded
    elevations (60 deg) have no value."""
    r = lambert_classic
    r.brdf.value[...] = (RHO / math.pi)[None, :, None, None]
    path = tmp_path / "lambert.h5"
    store.write(path, r)
    ref = open_reference(path)
    assert ref.side == "brdf" and ref.theta_range_deg == (0.0, 60.0)
    size, a = 64, math.radians(30.0)
    img = SphereView(size, 30.0).shade(ref.bsdf)
    x, y, nz, inside = _pixels(size)
    cos_l = y * math.sin(a) + nz * math.cos(a)
    theta_l = np.degrees(np.arccos(np.clip(cos_l, -1, 1)))
    expected = RHO[None, None, :] / math.pi * np.clip(cos_l, 0.0, None)[..., None]
    have = inside & (theta_l <= 60.0 - 1e-9)
    assert np.count_nonzero(have) > 0.6 * np.count_nonzero(inside)
    np.testing.assert_allclose(img[have], expected[have], rtol=1e-12, atol=1e-15)
    beyond = inside & (cos_l > 0) & (theta_l > 60.0 + 1e-9)
    assert beyond.any() and np.all(np.isnan(img[beyond]))
    assert np.all(img[inside & (cos_l <= 0)] == 0.0)


def test_backlit_sphere_is_the_lambert_shading_of_the_transmitted_side():
    """BTDF view: a constant BTDF c renders to c * max(0, -n.L_b) with the light behind the sphere,
    L_b = (0, sin a, -cos a); the BSDF sees the light above and the viewer below its surface."""
    c = np.array([0.3, 0.2, 0.1])
    seen = []

    def f(l, v):
        seen.append((l.copy(), v.copy()))
        return np.broadcast_to(c, l.shape)

    size, a = 48, math.radians(20.0)
    img = SphereView(size, 20.0, BTDF).shade(f)
    x, y, nz, inside = _pixels(size)
    cos_l = -(y * math.sin(a) - nz * math.cos(a))
    expected = c[None, None, :] * np.clip(cos_l, 0.0, None)[..., None]
    np.testing.assert_allclose(img[inside], expected[inside], rtol=1e-12, atol=1e-15)
    l, v = seen[0]
    assert np.all(l[:, 2] > 0) and np.all(v[:, 2] < 0)


def _mirror_symmetric(img: np.ndarray) -> None:
    np.testing.assert_allclose(img, img[:, ::-1], rtol=1e-9, atol=1e-12, equal_nan=True)


@pytest.mark.parametrize("name", ["ww09", "belcour-fwd"])
def test_model_image_is_symmetric_about_the_light_plane(metal_half, name):
    """Isotropic model: the image is its own mirror image about the plane of the light and the view."""
    f = ModelBSDF(registry.get(name), metal_half.stack, "brdf")
    img = SphereView(40, 45.0).shade(f)
    assert np.isfinite(img[SphereView(40).inside]).all() and img[SphereView(40).inside].max() > 0
    _mirror_symmetric(img)


@pytest.mark.parametrize("fixture", ["lambert_classic", "metal_half"])
def test_reference_image_is_symmetric_about_the_light_plane(fixture, request):
    """A file whose slices are symmetric about the plane of incidence (cell j and its mirror
    n_phi - 1 - j hold the same value; arbitrary otherwise) renders to a mirror-symmetric image:
    the interpolation itself treats both sides alike (classic and half slices)."""
    r = request.getfixturevalue(fixture)
    rng = np.random.default_rng(1)
    v = rng.uniform(0.1, 1.0, r.brdf.value.shape)
    r.brdf.value[...] = v + v[..., ::-1]
    ref = slices_reference(r)
    img = SphereView(48, 40.0).shade(ref.bsdf)
    assert np.isfinite(img).sum() > 1000
    _mirror_symmetric(img)


@pytest.mark.parametrize("fixture", ["lambert_classic", "metal_half"])
def test_interpolation_is_exact_at_a_recorded_incident_and_cell_centre(fixture, request):
    r = request.getfixturevalue(fixture)
    sd = r.brdf
    ref = slices_reference(r)
    grid = sd.grid
    rng = np.random.default_rng(2)
    th_c, ph_c = np.radians(grid.theta_centers_deg()), np.radians(grid.phi_centers_deg())
    checked = 0
    for m, theta in enumerate(r.theta_deg):
        l = light_direction(float(theta), float(r.phi_deg[m]))
        for _ in range(30):
            i, j = int(rng.integers(grid.n_theta)), int(rng.integers(grid.n_phi))
            if not sd.mask[m, i, j]:
                continue
            d = np.array([math.sin(th_c[i]) * math.cos(ph_c[j]), math.sin(th_c[i]) * math.sin(ph_c[j]),
                          math.cos(th_c[i])])
            v = d if grid.parametrization == "classic" else 2.0 * (l @ d) * d - l
            if v[2] <= 0:
                continue
            got = ref.bsdf(l[None, :], v[None, :])[0]
            np.testing.assert_allclose(got, sd.value[m, :, i, j], rtol=1e-9, atol=1e-12)
            checked += 1
    assert checked >= 40


def _percentile_exposure(img: np.ndarray, inside: np.ndarray) -> float:
    m = np.max(img[inside], axis=-1)
    return 0.9 / np.percentile(m[np.isfinite(m)], 99.0)


def test_one_exposure_across_panels(lambert_classic):
    """Every panel is displayed with the reference's exposure (its 99th percentile -> 0.9), whatever
    the models' brightness; a model equal to twice the reference shows exactly that."""
    r = lambert_classic
    r.brdf.value[...] = (RHO / math.pi)[None, :, None, None]
    ref = slices_reference(r)
    view = SphereView(48, 30.0)
    base = view.shade(ref.bsdf)
    s = SphereSet(view, ref, {REFERENCE: base, "double": 2.0 * base, "dim": 0.1 * base})
    k = _percentile_exposure(base, view.inside)
    assert s.exposure == pytest.approx(k, rel=1e-12)
    for name, factor in ((REFERENCE, 1.0), ("double", 2.0), ("dim", 0.1)):
        want = srgb_oetf(np.clip(k * factor * base, 0, 1))
        got = s.display(name)
        ok = np.isfinite(base)
        np.testing.assert_allclose(got[ok], want[ok], rtol=1e-12, atol=1e-15)
    assert s.rmse("double") == pytest.approx(k * np.sqrt(np.nanmean(base[view.inside] ** 2)), rel=1e-9)
    # the rendered comparison uses the same rule: the model refusing the stack is skipped, with a reason
    spheres = render_spheres(ref, ["ww09"], view)
    assert "ww09" in spheres.skipped and spheres.exposure == pytest.approx(k, rel=1e-12)


def _run(capsys, *argv) -> tuple[int, str, str]:
    code = gonio(["render", *map(str, argv)])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("flags,field", [
    (("--light-angle", "95"), "--light-angle"), (("--light-angle", "-1"), "--light-angle"),
    (("--light-angle", "abc"), "--light-angle"), (("--size", "0"), "--size"), (("--size", "5000"), "--size"),
    (("--size", "1.5"), "--size"), (("--model", "nope"), "unknown model"),
])
def test_cli_bad_input_is_one_line_and_exit_2(lambert_classic, tmp_path, capsys, flags, field):
    path = tmp_path / "lambert.h5"
    store.write(path, lambert_classic)
    code, out, err = _run(capsys, path, "--out", tmp_path / "s.png", *flags)
    assert code == 2 and out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"gonio: error: {field}"), err
    assert not (tmp_path / "s.png").exists()


def test_cli_writes_the_png(lambert_classic, tmp_path, capsys):
    path = tmp_path / "lambert.h5"
    store.write(path, lambert_classic)
    code, out, err = _run(capsys, path, "--out", tmp_path / "s.png", "--size", "32", "--model", "all")
    assert code == 0, err
    assert (tmp_path / "s.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "wrote" in out and "skipped ww09:" in out


class _FakeTable:
    """Stands for goniometer.run.results.TabulatedBRDF of an RGB tabulation: a stack, eval(l, v),
    and rgb() (an RGB table is its own linear sRGB)."""

    def __init__(self, stack):
        self.stack = stack

    def rgb(self):
        return self

    def eval(self, l, v):
        return np.broadcast_to(RHO / math.pi, l.shape)


def _tabulated_file(path: Path) -> Path:
    import h5py
    with h5py.File(path, "w") as f:
        f.attrs["format"] = "goniometer.tabulated"
    return path


def test_a_tabulated_file_goes_through_read_tabulated(tmp_path, monkeypatch):
    """A file whose format attribute is goniometer.tabulated is read by
    goniometer.files.tabulated.read_tabulated and rendered from its eval(l, v): a Lambertian table gives
    the Lambert sphere over the whole lit half (no recorded range)."""
    import sys
    import types
    fake = types.ModuleType("goniometer.files.tabulated")
    stack = g.stack_from_dict(LAMBERT)
    fake.TabulatedError = type("TabulatedError", (ValueError,), {})
    fake.read_tabulated = lambda p: _FakeTable(stack)
    monkeypatch.setitem(sys.modules, "goniometer.files.tabulated", fake)
    ref = open_reference(_tabulated_file(tmp_path / "t.h5"))
    assert ref.side == "brdf" and ref.theta_range_deg is None and ref.stack.name == "lambert"
    size, a = 40, math.radians(65.0)
    img = SphereView(size, 65.0).shade(ref.bsdf)
    x, y, nz, inside = _pixels(size)
    cos_l = y * math.sin(a) + nz * math.cos(a)
    expected = RHO[None, None, :] / math.pi * np.clip(cos_l, 0.0, None)[..., None]
    np.testing.assert_allclose(img[inside], expected[inside], rtol=1e-12, atol=1e-15)


def test_a_tabulated_file_without_its_reader_is_a_clear_error(tmp_path, monkeypatch, capsys):
    import sys
    monkeypatch.setitem(sys.modules, "goniometer.files.tabulated", None)   # import fails
    path = _tabulated_file(tmp_path / "t.h5")
    code, out, err = _run(capsys, path, "--out", tmp_path / "s.png")
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "goniometer.files.tabulated" in err and str(path) in err


def test_a_model_is_exact_at_its_light_nodes(metal_half):
    """ModelBSDF returns Model.evaluate itself when the light sits on a node (0.25 deg steps), for any
    azimuth of the light (isotropy) and on both sides of the plane of incidence."""
    model = registry.get("belcour-sym")
    f = ModelBSDF(model, metal_half.stack, "brdf", 0.25)
    rng = np.random.default_rng(3)
    for theta in (0.0, 20.25, 47.5, 71.0):
        v = rng.normal(size=(50, 3))
        v[:, 2] = np.abs(v[:, 2]) + 0.05
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        direct = model.evaluate(metal_half.stack, light_direction(theta), v).total
        phi = float(rng.uniform(0, 2 * math.pi))
        c, s = math.cos(phi), math.sin(phi)
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        l = np.broadcast_to(rot @ light_direction(theta), v.shape)
        np.testing.assert_allclose(f(l, v @ rot.T), direct, rtol=1e-9, atol=1e-12)


def test_a_black_reference_is_explained_not_an_error(lambert_classic, tmp_path):
    """A reference that is black on the sphere (a peak narrower than the grid) cannot set the exposure:
    the set says why, exposes the models by the same rule on their own pixels, gives no RMSE, and the
    figure is drawn; a BRDF's mirror point (normal halfway between light and view) is where such a
    peak would be a highlight."""
    from models.render import comparison_figure, write_png
    ref = slices_reference(lambert_classic)
    view = SphereView(32, 65.0)
    bright = view.shade(ref.bsdf)
    black = np.where(np.isfinite(bright), 0.0, np.nan)
    s = SphereSet(view, ref, {REFERENCE: black, "model": bright})
    assert "black" in s.reference_note and "mirror point" in s.reference_note
    assert math.isnan(s.rmse("model")) and s.to_json()["models"]["model"]["rmse"] is None
    assert s.exposure == pytest.approx(_percentile_exposure(bright, view.inside), rel=1e-12)
    write_png(tmp_path / "black.png", comparison_figure(s))
    assert (tmp_path / "black.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    x, y = view.mirror_point
    a = math.radians(65.0)
    h = np.array([0.0, math.sin(a), math.cos(a)]) + np.array([0.0, 0.0, 1.0])
    np.testing.assert_allclose([x, y, math.sqrt(1 - x * x - y * y)], h / np.linalg.norm(h), atol=1e-12)
    # a shown reference sets the exposure itself and has no note
    assert SphereSet(view, ref, {REFERENCE: bright}).reference_note is None
    # a backlit slab view has no mirror point: its straight-through peak is seen only at 0 degrees
    assert SphereView(32, 65.0, BTDF).mirror_point is None
