"""Polarized tabulations (docs/polarization.md section 4, docs/tabulated-format.md) and their export to
Mitsuba 3's measured_polarized: the file read by Mitsuba's own plugin in scalar_spectral_polarized,
evaluated at direction pairs, against Mitsuba's polarized roughconductor within our cells' noise;
the intensity of one interface against a scalar tabulation; the files, the command line and its
refusals."""

from __future__ import annotations

import math
from dataclasses import replace

import h5py
import numpy as np
import pytest

import goniometer as g
from goniometer.files.mitsuba_polarized import RECIPROCAL, export_pbsdf, pbsdf_fields, spectral_bins, wavelengths
from goniometer.files.rgl_tensor import read_tensor
from goniometer.files.tabulated import read_tabulated, write_tabulated
from goniometer.grids import halfdiff
from goniometer.grids.stokes import convert_mueller
from goniometer.run.tabulation import tabulate
from goniometer.stack import Interface, Stack
from goniometer.testing import MIN_EXPECTED, assert_samples_match, chi2_limit
from goniometer.testing.statistics import assert_sparse_flux_matches, expected_exits

METAL = Stack("metal", (Interface(0.15, (0.2, 0.9, 1.3), (3.5, 2.5, 2.0)),), "metal")
RAYS = 1_500_000
#: the (i, j) of a single microfacet reflection's Mueller matrix in the plane frames (its block form)
BLOCK = ((0, 0), (0, 1), (1, 0), (1, 1), (2, 2), (2, 3), (3, 2), (3, 3))


def _settings(**kw) -> g.TabulationSettings:
    base = dict(rays=RAYS, seed=11, threads=2, chunk_rays=1 << 15, polarized=True)
    base.update(kw)
    return g.TabulationSettings(**base)


@pytest.fixture(scope="module")
def metal_tab():
    return tabulate(METAL, _settings())


def _pair(theta_h, theta_d, phi_d, phi_h):
    """The directions ``(l, v)`` of half/difference angles (radians; docs/tabulated-format.md)."""
    d = np.array([math.sin(theta_d) * math.cos(phi_d), math.sin(theta_d) * math.sin(phi_d), math.cos(theta_d)])

    def turn(x):
        y = np.array([x[0] * math.cos(theta_h) + x[2] * math.sin(theta_h), x[1],
                      -x[0] * math.sin(theta_h) + x[2] * math.cos(theta_h)])
        return np.array([y[0] * math.cos(phi_h) - y[1] * math.sin(phi_h),
                         y[0] * math.sin(phi_h) + y[1] * math.cos(phi_h), y[2]])
    return turn(d), turn(np.array([-d[0], -d[1], d[2]]))


def _mitsuba():
    mi = pytest.importorskip("mitsuba")
    try:
        mi.set_variant("scalar_spectral_polarized")
    except (ImportError, AttributeError, ValueError) as e:
        pytest.skip(f"mitsuba's scalar_spectral_polarized variant is unavailable ({e})")
    return mi


def _evaluate(mi, bsdf, l, v, nm):
    """Mitsuba's eval at light ``l``, viewer ``v`` (its wo and si.wi), one wavelength, without the
    cosine, taken from its stokes_basis frames to our plane frames."""
    si = mi.SurfaceInteraction3f()
    si.wavelengths = [float(nm)] * 4
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    si.n = mi.Vector3f(0, 0, 1)
    si.wi = mi.Vector3f(*v)
    val = np.array(bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(*l)))[:, :, 0] / l[2]
    return convert_mueller(val, l, v, "mitsuba", "plane")


@pytest.fixture(scope="module")
def mitsuba_cells(metal_tab, tmp_path_factory):
    """Cells where Mitsuba's roughconductor expects MIN_EXPECTED paths (at most 400 of them, spread
    over the selection), each at its centre pair and at the exchanged pair (phi_d - 180 deg, the
    half the MERL grid folds): Mitsuba's measured_polarized reading our exported file, its
    roughconductor, our cell (C, n, 2, 4, 4) each."""
    mi = _mitsuba()
    path = export_pbsdf(metal_tab, tmp_path_factory.mktemp("pbsdf") / "metal.pbsdf")
    measured = mi.load_dict({"type": "measured_polarized", "filename": str(path)})
    layer = METAL.layers[0]
    wvls, ch = wavelengths(metal_tab)
    th = np.radians(halfdiff.theta_h_centers_deg())
    td = np.radians(halfdiff.theta_d_centers_deg())
    pd = np.radians(halfdiff.phi_d_centers_deg())
    # the model's expected exits (channel G, the lowest reflectance of the three) at every cell centre
    # of a coarse pre-selection: M00 of roughconductor without polarization is the scalar formula
    rc = [mi.load_dict({"type": "roughconductor", "distribution": "ggx", "alpha": layer.alpha_xy[0],
                        "sample_visible": True, "eta": layer.ior[c], "k": layer.extinction[c]}) for c in range(3)]
    omega = metal_tab.measure / np.pi
    candidates = np.argwhere(metal_tab.hits >= 5)          # (a pre-selection only: judged by the model below)
    selected = []
    for i, j, k in candidates:
        l, v = _pair(th[i], td[j], pd[k], 0.7)
        if l[2] <= 1e-3 or v[2] <= 1e-3:
            continue
        m00 = _evaluate(mi, rc[1], l, v, 550.0)[0, 0]
        if expected_exits(m00, omega[i, j, k], RAYS) >= MIN_EXPECTED:
            selected.append((i, j, k))
    assert len(selected) >= 100, len(selected)
    selected = [selected[q] for q in np.linspace(0, len(selected) - 1, min(400, len(selected))).astype(int)]
    n = len(selected)
    ours, model, stderr, expect = (np.zeros((3, n, 2, 4, 4)) for _ in range(4))
    for q, (i, j, k) in enumerate(selected):
        for side, phi in enumerate((pd[k], pd[k] - math.pi)):
            l, v = _pair(th[i], td[j], phi, 0.7)
            assert halfdiff.cell_indices(l, v) == np.ravel_multi_index((i, j, k), halfdiff.SHAPE)
            for c in range(3):
                nm = wvls[list(ch).index(c)]
                ours[c, q, side] = _evaluate(mi, measured, l, v, nm)
                model[c, q, side] = _evaluate(mi, rc[c], l, v, nm)
                se = metal_tab.mueller_stderr[c, i, j, k]
                stderr[c, q, side] = se if side == 0 else se.T
                expect[c, q, side] = metal_tab.mueller[c, i, j, k] if side == 0 else \
                    metal_tab.mueller[c, i, j, k].T * RECIPROCAL
    return ours, model, stderr, expect


def _chi2_ratio(ours, model, stderr, turn=None):
    """The largest chi-square over its Bonferroni limit, per block element and channel, of ``ours``
    against the model: z with the model's sigma (the cell's standard error times sqrt(model M00 /
    our M00), docs/testing.md); ``turn``: a 4 x 4 matrix applied as ``T M T`` to ours (a wrong frame
    convention)."""
    if turn is not None:
        ours = turn @ ours @ turn
    scale = np.sqrt(np.maximum(model[..., 0, 0], 0.0) / np.maximum(ours[..., 0, 0], 1e-300))
    p = 1e-6 / (len(BLOCK) * 3)
    worst = 0.0
    for i, j in BLOCK:
        for c in range(3):
            sig = stderr[c, ..., i, j] * scale[c]
            s = sig > 0
            z = (ours[c, ..., i, j] - model[c, ..., i, j])[s] / sig[s]
            worst = max(worst, float(np.sum(z * z)) / chi2_limit(int(np.count_nonzero(s)), p))
    return worst


def test_mitsubas_measured_polarized_reads_our_export_as_its_roughconductor(mitsuba_cells):
    """Mitsuba 3's own plugin, on the exported file, at direction pairs of both halves of phi_d,
    equals its polarized roughconductor within our cells' noise (one chi-square per block element
    and channel, Bonferroni); the elements outside a microfacet reflection's block stay 0 in the
    plane frames, and it reads back our cells (float32)."""
    ours, model, stderr, expect = mitsuba_cells
    assert _chi2_ratio(ours, model, stderr) < 1.0
    off = [(i, j) for i in range(4) for j in range(4) if (i, j) not in BLOCK]
    m00 = ours[..., 0, 0]
    for i, j in off:
        assert np.all(np.abs(ours[..., i, j]) <= 1e-5 * m00 + 1e-7)
    np.testing.assert_allclose(ours, expect, rtol=2e-5, atol=1e-6 * float(np.max(np.abs(expect))))


@pytest.mark.parametrize("name, turn", [("x in the plane (frames turned by 90 deg)", np.diag([1.0, -1.0, -1.0, 1.0])),
                                        ("left-handed frames (S2 reversed)", np.diag([1.0, 1.0, -1.0, 1.0]))])
def test_a_wrong_frame_convention_fails_the_comparison(mitsuba_cells, name, turn):
    """The comparison above detects a frame convention gone wrong in the file."""
    ours, model, stderr, _ = mitsuba_cells
    assert _chi2_ratio(ours, model, stderr, turn) > 1.0, name


def _pooled(tab):
    """M00 pooled over phi_d and bands of 10 theta_d cells (C, 90, 9): measure-weighted means, and a
    standard error bounding theirs (the cells' variances added)."""
    mu = tab.measure[None].reshape(1, 90, 9, 10, 180)
    v = tab.value.reshape(-1, 90, 9, 10, 180)
    se = tab.stderr.reshape(-1, 90, 9, 10, 180)
    tot = mu.sum(axis=(3, 4))
    return (v * mu).sum(axis=(3, 4)) / tot, np.sqrt(((se * mu) ** 2).sum(axis=(3, 4))) / tot, \
        tab.hits.reshape(90, 9, 10, 180).sum(axis=(2, 3))


@pytest.mark.parametrize("ior_scale, agrees", [(1.0, True), (1.15, False)])
def test_one_interfaces_intensity_is_the_scalar_tabulations(metal_tab, ior_scale, agrees):
    """M00 of one rough conductor's polarized tabulation is what a scalar tabulation of the same
    stack (another seed) gives, pooled over phi_d and theta_d bands where both have 200 paths
    (two-sample chi-square); a scalar stack whose index is 15 % higher is told apart."""
    layer = METAL.layers[0]
    other = Stack("metal", (Interface(0.15, tuple(x * ior_scale for x in layer.ior), layer.extinction),), "metal")
    sca = tabulate(other, _settings(polarized=False, seed=12))
    assert sca.mueller is None and not sca.polarized and metal_tab.polarized
    a, sa, ha = _pooled(metal_tab)
    b, sb, hb = _pooled(sca)
    where = np.broadcast_to((ha >= 200) & (hb >= 200), a.shape)
    if agrees:
        assert_samples_match(a, sa, b, sb, where=where)
    else:
        with pytest.raises(AssertionError):
            assert_samples_match(a, sa, b, sb, where=where)


def test_the_intensity_is_m00_and_the_sparse_cells_add_up(metal_tab):
    """``mueller[..., 0, 0]`` is ``value`` (and its standard error ``stderr``) bit for bit; the
    matrices are finite and zero where no path left."""
    t = metal_tab
    assert t.mueller.shape == t.value.shape + (4, 4) and t.mueller_stderr.shape == t.mueller.shape
    np.testing.assert_array_equal(t.mueller[..., 0, 0], t.value)
    np.testing.assert_array_equal(t.mueller_stderr[..., 0, 0], t.stderr)
    assert np.all(np.isfinite(t.mueller))
    assert not np.any(t.mueller[:, t.hits == 0])
    # the degree of polarization of light leaving a cell lit unpolarized is at most 1 (beyond noise)
    m = t.mueller[:, t.hits >= 50]
    dop = np.sqrt(m[..., 1, 0] ** 2 + m[..., 2, 0] ** 2 + m[..., 3, 0] ** 2) / m[..., 0, 0]
    assert np.all(dop <= 1.0 + 1e-9)


def test_a_polarized_tabulation_has_the_same_bits_on_one_and_two_threads():
    a = tabulate(METAL, _settings(rays=30_000, chunk_rays=4096, threads=1))
    b = tabulate(METAL, _settings(rays=30_000, chunk_rays=4096, threads=2))
    np.testing.assert_array_equal(a.mueller, b.mueller)
    np.testing.assert_array_equal(a.mueller_stderr, b.mueller_stderr)
    np.testing.assert_array_equal(a.value, b.value)


def test_the_files_and_the_export_layout(tmp_path, metal_tab):
    """The tabulated file keeps the matrices (and says so); the export's fields are the plugin's
    layout: 5 wavelengths (RGB at 465, 550, 610 nm, the ends repeated at 360 and 830 nm), phi_d over
    both halves, the folded half the reciprocal matrices."""
    p = write_tabulated(tmp_path / "t.h5", metal_tab)
    with h5py.File(p) as f:
        assert f["simulation"].attrs["polarized"] and f["brdf"].attrs["stokes_frames"] == "plane"
        assert f["brdf/mueller"].dims[4][0].name.endswith("mueller_row")
    back = read_tabulated(p)
    assert back.settings.polarized
    np.testing.assert_array_equal(back.mueller, metal_tab.mueller)
    np.testing.assert_array_equal(back.mueller_stderr, metal_tab.mueller_stderr)
    fields = pbsdf_fields(metal_tab)
    assert fields["wvls"].dtype == np.uint16 and list(fields["wvls"]) == [360, 465, 550, 610, 830]
    assert list(wavelengths(metal_tab)[1]) == [2, 2, 1, 0, 0]
    assert fields["M"].shape == (360, 90, 90, 5, 4, 4) and fields["M"].dtype == np.float32
    for k in ("theta_h", "theta_d", "phi_d"):
        assert fields[k].dtype == np.float32 and fields[k].ndim == 2 and np.all(np.diff(fields[k][0]) > 0)
    assert -math.pi < fields["phi_d"][0, 0] < 0.0 < fields["phi_d"][0, -1] < math.pi
    i, j, k = np.unravel_index(np.argmax(metal_tab.hits), halfdiff.SHAPE)
    np.testing.assert_array_equal(fields["M"][180 + k, j, i, 2], metal_tab.mueller[1, i, j, k].astype(np.float32))
    np.testing.assert_array_equal(fields["M"][k, j, i, 2],
                                  (metal_tab.mueller[1, i, j, k].T * RECIPROCAL).astype(np.float32))
    with pytest.raises(ValueError, match="tabulate with --polarized"):
        pbsdf_fields(replace(metal_tab, mueller=None, mueller_stderr=None))


def test_spectral_bins_are_spread_and_three_channels_are_padded():
    assert list(spectral_bins(30)) == [0, 7, 14, 22, 29]
    assert len(set(spectral_bins(6))) == 5


def _config(tmp_path, extra: str = "") -> str:
    p = tmp_path / "metal.toml"
    p.write_text('name = "metal"\ncategory = "metal"\n[[layers]]\ntype = "interface"\nroughness = 0.15\n'
                 'ior = [0.2, 0.9, 1.3]\nextinction = [3.5, 2.5, 2.0]\n' + extra)
    return str(p)


def test_gonio_tabulate_polarized_export_and_info(tmp_path, capsys):
    """The command line: --polarized (and the [simulation] key), gonio info says polarized, gonio
    export --format mitsuba-polarized writes the tensor file, refuses to overwrite it without
    --overwrite and refuses a scalar tabulation in one line."""
    from goniometer.cli import main
    out = tmp_path / "t.h5"
    assert main(["tabulate", _config(tmp_path), "--polarized", "--rays", "20000", "--threads", "1",
                 "--out", str(out)]) == 0
    assert read_tabulated(out).polarized
    assert main(["info", str(out)]) == 0
    assert "polarized: each cell holds its Mueller matrix" in capsys.readouterr().out
    x = tmp_path / "t.pbsdf"
    assert main(["export", str(out), "--format", "mitsuba-polarized", "--out", str(x)]) == 0
    f = read_tensor(x)
    assert f["M"].shape == (360, 90, 90, 5, 4, 4) and list(f["wvls"]) == [360, 465, 550, 610, 830]
    capsys.readouterr()
    assert main(["export", str(out), "--format", "mitsuba-polarized", "--out", str(x)]) == 2
    assert "--overwrite" in capsys.readouterr().err
    # the [simulation] key
    out2 = tmp_path / "t2.h5"
    assert main(["tabulate", _config(tmp_path, "[simulation]\npolarized = true\n"), "--rays", "2000", "--threads", "1",
                 "--out", str(out2)]) == 0
    assert read_tabulated(out2).polarized
    # a scalar tabulation is refused, naming what is needed
    sca = tmp_path / "s.h5"
    assert main(["tabulate", _config(tmp_path), "--rays", "2000", "--threads", "1", "--out", str(sca)]) == 0
    capsys.readouterr()
    assert main(["export", str(sca), "--format", "mitsuba-polarized", "--out", str(tmp_path / "s.pbsdf")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--polarized" in err and "gonio: error:" in err
    assert not (tmp_path / "s.pbsdf").exists()


def test_a_polarized_tabulation_on_cuda_is_refused_in_one_line(tmp_path, capsys):
    from goniometer.cli import main
    assert main(["tabulate", _config(tmp_path), "--polarized", "--device", "cuda", "--rays", "2000",
                 "--out", str(tmp_path / "c.h5")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "polarized" in err
    with pytest.raises(g.SettingsError, match="polarized"):
        g.TabulationSettings(polarized=True, device="cuda")
