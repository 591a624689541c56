"""Measured files as references (``docs/measured.md``): an RGL file read as Mitsuba 3's ``measured``
plugin reads it (also between its incident nodes), a MERL file as its cells hold it, and their
resampling onto slices: the energy of a simulated material exported and read back stays within the
resampling error of the simulation's own."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

import goniometer as g
from goniometer.files.measured import MeasuredError, measured_reference, read_measured
from goniometer.grids.rgl import grid_for

GOLD = {"name": "gold", "category": "metal", "layers": [
    {"type": "interface", "roughness": 0.3, "ior": [0.2, 0.35, 1.4], "extinction": [3.5, 2.6, 1.9]}]}


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    stack = g.stack_from_dict(GOLD)
    grid = grid_for(stack, 6, 1, 16)
    r = g.simulate(stack, g.SimulationSettings.on_rgl_grid(grid, rays=100_000, seed=11, threads=2))
    d = tmp_path_factory.mktemp("measured")
    return stack, g.export_rgl(r, d / "gold_rgb.bsdf"), g.export_rgl(r, d / "gold_spec.bsdf", spectral=True)


def test_the_rgl_file_reads_as_mitsubas_plugin_reads_it(exported):
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    stack, rgb, spec = exported
    ours = read_measured(rgb)
    assert ours.kind == "rgl" and ours.isotropic and len(ours.incident_deg) == 6
    theirs = mi.load_dict({"type": "measured", "filename": str(rgb)})
    si, ctx = mi.SurfaceInteraction3f(), mi.BSDFContext()
    rng = np.random.default_rng(2)
    for _ in range(200):
        t, ph = rng.uniform(0, 1.4), rng.uniform(-3, 3)   # off the nodes, any azimuth
        l = np.array([math.sin(t) * math.cos(ph), math.sin(t) * math.sin(ph), math.cos(t)])
        v = rng.normal(size=3)
        v[2] = abs(v[2]) + 0.05
        v /= np.linalg.norm(v)
        si.wi = mi.Vector3f(*l)
        want = np.array(theirs.eval(ctx, si, mi.Vector3f(*v)))
        got = ours.eval(l, v[None])[0] * v[2]
        np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-7)
    # the spectral file read at 610, 550, 465 nm: R and G are its nodes; 465 nm lies between the
    # 460 and 470 nm nodes, where the file's spectrum mixes in 1/34 of G - B
    sp = read_measured(spec)
    l = np.array([0.3, 0.1, 0.95])
    v = np.array([[-0.4, 0.2, 0.89], [0.1, -0.5, 0.86]])
    a, b = sp.eval(l, v), ours.eval(l, v)
    np.testing.assert_allclose(a[:, :2], b[:, :2], rtol=1e-5)
    np.testing.assert_allclose(a[:, 2], b[:, 2] + (b[:, 1] - b[:, 2]) * 5.0 / 85.0 / 2.0, rtol=1e-4)


def test_merl_reads_its_cells(tmp_path):
    stack = g.stack_from_dict({"name": "p", "category": "plastic", "layers": [
        {"type": "interface", "roughness": 0.2, "ior": 1.5}, {"type": "lambertian", "albedo": 0.5}]})
    tab = g.tabulate(stack, g.TabulationSettings(rays=50_000, threads=2))
    path = g.write_merl(tmp_path / "p.binary", tab)
    m = read_measured(path)
    rng = np.random.default_rng(3)
    l = np.array([0.2, 0.0, 0.98])
    v = rng.normal(size=(500, 3))
    v[:, 2] = np.abs(v[:, 2]) + 0.01
    got = m.eval(l, v)
    want = tab.eval(l, v / np.linalg.norm(v, axis=1, keepdims=True))
    has = np.isfinite(got[:, 0])
    assert has.sum() > 20 and not has.all()                   # cells without data are NaN
    np.testing.assert_allclose(got[has], want[has], rtol=1e-12)


def test_resampled_onto_slices_the_energy_is_the_simulations(exported):
    stack, rgb, _ = exported
    m = read_measured(rgb)
    s = g.SimulationSettings(incident_deg=m.incident_deg[1:3], rays=1000, resolution=(30, 60))
    ref = measured_reference(m, stack, s)
    sim = g.simulate(stack, s.with_overrides(rays=200_000, threads=2))
    # at the file's own nodes the measured energy is the simulated one within the resampling error
    # of the file (16 x 16 nodes) and the two runs' noise: 2 %
    np.testing.assert_allclose(ref.energy["reflected"], sim.energy["reflected"], rtol=0.02)
    assert np.isnan(ref.brdf.stderr).all() and ref.extra["measured"]["kind"] == "rgl"
    assert ref.brdf.mask.mean() > 0.9


def test_not_a_measured_file(tmp_path):
    p = tmp_path / "x.bin"
    p.write_bytes(b"\0" * 100)
    with pytest.raises(MeasuredError, match="neither a MERL"):
        read_measured(p)


def test_gonio_evaluate_and_fit_a_measured_file(exported, tmp_path, capsys):
    """A simulated material exported, then judged as a measurement: models' errors against it sit
    within the resampling error of their errors against the simulation's own slices; noise floors
    are unknown, not invented."""
    import json
    from goniometer.cli import main
    stack, rgb, _ = exported
    cfg = tmp_path / "gold.toml"
    cfg.write_text(stack.to_toml())
    capsys.readouterr()
    assert main(["evaluate", str(rgb), "--stack", str(cfg), "--resolution", "18x36", "--incident", "31,55",
                 "--model", "openpbr-coat", "--json"]) == 2      # a bare conductor: the coat model refuses it
    capsys.readouterr()
    assert main(["fit", str(rgb), "--stack", str(cfg), "--resolution", "18x36", "--incident", "31,55",
                 "--model", "ggx1", "--json", "--starts", "1"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["errors"]["total"]["noise_floor_mean"] is None and d["errors"]["total"]["rmse_mean"] > 0
    # the fitted GGX of a GGX conductor finds its roughness (alpha 0.3) within the resampling error
    assert abs(d["params"]["alpha"] - 0.3) < 0.03, d["params"]
    err = capsys.readouterr()
    assert main(["evaluate", str(rgb), "--resolution", "18x36"]) == 2
    assert "--stack" in capsys.readouterr().err


# ---------------------------------------------------------------------- what a file must hold

def _merl_bytes(value: float, bad: float | None = None) -> bytes:
    """A MERL file of a constant BRDF ``value`` (1/sr) in every cell, one cell of R set to ``bad``."""
    from goniometer.grids import halfdiff
    from goniometer.files.merl import MERL_SCALE
    data = np.stack([np.full(halfdiff.N_CELLS, value / s) for s in MERL_SCALE])
    if bad is not None:
        data[0, 12345] = bad
    return np.array(halfdiff.SHAPE, dtype="<i4").tobytes() + data.astype("<f8").tobytes()


def test_a_merl_file_with_broken_values_is_refused(tmp_path):
    ok = tmp_path / "ok.binary"
    ok.write_bytes(_merl_bytes(0.5 / np.pi, bad=-1.0))         # a Lambertian of albedo 0.5, one cell without data
    assert read_measured(ok).kind == "merl"
    cases = {"nan": (_merl_bytes(0.5 / np.pi, np.nan), "1 stored value(s) are not finite"),
             "inf": (_merl_bytes(0.5 / np.pi, np.inf), "1 stored value(s) are not finite"),
             "huge": (_merl_bytes(0.5 / np.pi, 1e30), "implausible values"),
             # every cell 3 / pi: a Lambertian of albedo 3 reflects three times the light it receives
             "bright": (_merl_bytes(3.0 / np.pi), "reflect 3 times the light")}
    for name, (content, needle) in cases.items():
        p = tmp_path / f"{name}.binary"
        p.write_bytes(content)
        with pytest.raises(MeasuredError, match=re.escape(needle)) as e:
            read_measured(p)
        assert str(e.value).startswith(str(p)) and "\n" not in str(e.value), name


def _broken_rgl(exported, tmp_path, name: str, field: str, index: tuple, value: float):
    from goniometer.files.rgl_tensor import read_tensor, write_tensor
    fields = dict(read_tensor(exported[1]).fields)
    a = fields[field].copy()
    a[index] = value
    fields[field] = a
    return write_tensor(tmp_path / f"{name}.bsdf", fields)


def test_an_rgl_file_with_broken_values_is_refused_and_info_says_so(exported, tmp_path, capsys):
    import json
    from goniometer.cli import main
    stack = exported[0]
    cfg = tmp_path / "gold.toml"
    cfg.write_text(stack.to_toml())
    cases = {"nan": ("rgb", (0, 2, 1, 3, 4), np.nan, "field rgb: 1 value(s) are not finite"),
             "huge": ("rgb", (0, 2, 1, 3, 4), 1e30, "implausible values: at theta_i ="),
             "negative": ("rgb", (0, 2, 1, 3, 4), -1.0, "negative beyond rounding"),
             "sigma": ("sigma", (3, 3), 0.0, "field sigma holds 0"),
             "vndf": ("vndf", (0, 1, 2, 2), np.inf, "field vndf: 1 value(s) are not finite")}
    for name, (field, index, value, needle) in cases.items():
        p = _broken_rgl(exported, tmp_path, name, field, index, value)
        with pytest.raises(MeasuredError, match=re.escape(needle)):
            read_measured(p)
        capsys.readouterr()
        assert main(["evaluate", str(p), "--stack", str(cfg), "--resolution", "6x12", "--incident", "31"]) == 2
        out, err = capsys.readouterr()
        assert out == "" and err.startswith(f"gonio: error: {p}: ") and needle in err and len(err.splitlines()) == 1
        assert main(["info", str(p)]) == 0
        assert f"as a measurement  refuses it: {p}: " in capsys.readouterr().out
    assert main(["info", str(exported[1]), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["as_measurement"] == {"reads": True, "why_not": None}
