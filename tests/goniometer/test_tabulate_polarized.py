"""Polarized tabulations (docs/polarization.md section 5, docs/tabulated-format.md) and their export to
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
from goniometer.files.rgl_export import CHANNEL_NM
from goniometer.files.mitsuba_polarized import RECIPROCAL, export_pbsdf, pbsdf_fields, spectral_bins, wavelengths
from goniometer.files.rgl_tensor import read_tensor
from goniometer.files.tabulated import read_tabulated
from goniometer.grids import halfdiff
from goniometer.grids.stokes import convert_mueller
from goniometer.run.tabulation import tabulate
from goniometer.stack import Interface, Stack
from goniometer.testing import assert_samples_match, chi2_limit
from goniometer.testing.statistics import assert_sparse_flux_matches, expected_exits

#: a narrow lobe: the MERL cells are small (1.46 M of them), and the comparison wants cells where
#: 20 paths are expected: about 2000 of them at these rays
METAL = Stack("metal", (Interface(0.03, (0.2, 0.5, 0.9), (3.5, 3.0, 2.8)),), "metal")
RAYS = 4_000_000
#: the paths a judged cell expects (docs/testing.md: about 20, below which a cell's z is no longer normal)
EXPECTED = 20.0
#: the (i, j) of a single microfacet reflection's Mueller matrix in the plane frames (its block form)
BLOCK = ((0, 0), (0, 1), (1, 0), (1, 1), (2, 2), (2, 3), (3, 2), (3, 3))


def _settings(**kw) -> g.TabulationSettings:
    base = dict(rays=RAYS, seed=11, threads=2, chunk_rays=1 << 15, polarized=True)
    base.update(kw)
    return g.TabulationSettings(**base)


@pytest.fixture(scope="module")
def metal_tab():
    return tabulate(METAL, _settings())


def _pair(theta_h, theta_d, phi_d, phi_h=0.7):
    """The directions ``(l, v)`` (..., 3) of half/difference angles (radians, arrays broadcast;
    docs/tabulated-format.md section 2: ``l = d`` and ``v = (-d_x, -d_y, d_z)`` in the frame of ``h``)."""
    theta_h, theta_d, phi_d = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (theta_h, theta_d, phi_d)))
    d = np.stack([np.sin(theta_d) * np.cos(phi_d), np.sin(theta_d) * np.sin(phi_d), np.cos(theta_d)], axis=-1)

    def turn(x):
        ct, st, cp, sp = np.cos(theta_h), np.sin(theta_h), math.cos(phi_h), math.sin(phi_h)
        y0 = x[..., 0] * ct + x[..., 2] * st
        y2 = -x[..., 0] * st + x[..., 2] * ct
        return np.stack([y0 * cp - x[..., 1] * sp, y0 * sp + x[..., 1] * cp, y2], axis=-1)
    return turn(d), turn(d * np.array([-1.0, -1.0, 1.0]))


def _ggx_conductor(l, v, alpha, n, k):
    """The intensity BRDF (1/sr) of a GGX conductor with separable Smith masking and the unpolarized
    Fresnel reflectance of the index ``n + ik`` (Walter et al. 2007; what Mitsuba's roughconductor
    evaluates), 0 at or below the horizon."""
    h = l + v
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    a2 = alpha * alpha
    D = a2 / (np.pi * (h[..., 2] ** 2 * (a2 - 1.0) + 1.0) ** 2)

    def g1(w):
        c2 = np.clip(w[..., 2] ** 2, 1e-300, 1.0)
        return 2.0 / (1.0 + np.sqrt(1.0 + a2 * (1.0 - c2) / c2))
    c = np.sum(l * h, axis=-1)
    eta2 = complex(n, k) ** 2
    root = np.sqrt(eta2 - (1.0 - c * c) + 0j)
    rs = (c - root) / (c + root)
    rp = (eta2 * c - root) / (eta2 * c + root)
    F = 0.5 * (np.abs(rs) ** 2 + np.abs(rp) ** 2)
    up = (l[..., 2] > 0) & (v[..., 2] > 0)
    lz, vz = np.where(up, l[..., 2], 1.0), np.where(up, v[..., 2], 1.0)
    return np.where(up, F * D * g1(l) * g1(v) / (4.0 * lz * vz), 0.0)


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
def model_m00():
    """The roughconductor's intensity (C, 90, 90, 180), each cell's mean weighted by cos theta_l
    cos theta_v as our cells' (docs/tabulated-format.md section 3): a midpoint rule of 4 x 2 x 2
    points per cell in (sqrt(theta_h), theta_d, phi_d) with the Jacobian ``4 cos theta_d sin
    theta_h sin theta_d``; the narrow lobe's curvature across a row would otherwise show in the
    sparse cells' total."""
    layer = METAL.layers[0]
    n_h, n_d, n_p = 4, 2, 2
    u = (np.arange(halfdiff.N_THETA_H * n_h) + 0.5) / (halfdiff.N_THETA_H * n_h)
    th = 0.5 * np.pi * u * u
    td = (np.arange(halfdiff.N_THETA_D * n_d) + 0.5) * (0.5 * np.pi / (halfdiff.N_THETA_D * n_d))
    pd = (np.arange(halfdiff.N_PHI_D * n_p) + 0.5) * (np.pi / (halfdiff.N_PHI_D * n_p))
    out = np.zeros((3,) + halfdiff.SHAPE)
    for i in range(halfdiff.N_THETA_H):
        h, d, p = np.meshgrid(th[i * n_h:(i + 1) * n_h], td, pd, indexing="ij")
        l, v = _pair(h, d, p)
        w = np.cos(d) * np.sin(h) * np.sin(d) * u[i * n_h:(i + 1) * n_h, None, None] \
            * np.clip(l[..., 2], 0.0, None) * np.clip(v[..., 2], 0.0, None)
        wsum = w.reshape(n_h, halfdiff.N_THETA_D, n_d, halfdiff.N_PHI_D, n_p).sum(axis=(0, 2, 4))
        for c in range(3):
            f = _ggx_conductor(l, v, layer.alpha_xy[0], layer.ior[c], layer.extinction[c]) * w
            fsum = f.reshape(n_h, halfdiff.N_THETA_D, n_d, halfdiff.N_PHI_D, n_p).sum(axis=(0, 2, 4))
            out[c, i] = np.divide(fsum, wsum, out=np.zeros_like(fsum), where=wsum > 0)
    return out


@pytest.fixture(scope="module")
def mitsuba_cells(metal_tab, model_m00, tmp_path_factory):
    """The cells where the roughconductor expects EXPECTED paths in every channel (400 of them,
    spread over the selection), each at its centre pair and at the exchanged pair (phi_d - 180 deg,
    the half the MERL grid folds): Mitsuba's measured_polarized reading our exported file, its
    polarized roughconductor, our cell's standard errors and our cell (C, n, 2, 4, 4) each."""
    mi = _mitsuba()
    path = export_pbsdf(metal_tab, tmp_path_factory.mktemp("pbsdf") / "metal.pbsdf")
    measured = mi.load_dict({"type": "measured_polarized", "filename": str(path)})
    layer = METAL.layers[0]
    th = np.radians(halfdiff.theta_h_centers_deg())
    td = np.radians(halfdiff.theta_d_centers_deg())
    pd = np.radians(halfdiff.phi_d_centers_deg())
    rc = [mi.load_dict({"type": "roughconductor", "distribution": "ggx", "alpha": layer.alpha_xy[0],
                        "sample_visible": True, "eta": layer.ior[c], "k": layer.extinction[c]}) for c in range(3)]
    expected = expected_exits(model_m00, metal_tab.measure[None] / np.pi, RAYS).min(axis=0)
    selected = np.argwhere(expected >= EXPECTED)
    assert len(selected) >= 200, len(selected)
    selected = selected[np.linspace(0, len(selected) - 1, 400).astype(int)]
    n = len(selected)
    ours, model, stderr, expect = (np.zeros((3, n, 2, 4, 4)) for _ in range(4))
    for q, (i, j, k) in enumerate(selected):
        for side, phi in enumerate((pd[k], pd[k] - math.pi)):
            l, v = _pair(th[i], td[j], phi)
            assert halfdiff.cell_indices(l, v) == np.ravel_multi_index((i, j, k), halfdiff.SHAPE)
            for c in range(3):
                ours[c, q, side] = _evaluate(mi, measured, l, v, CHANNEL_NM[c])
                model[c, q, side] = _evaluate(mi, rc[c], l, v, CHANNEL_NM[c])
                se = metal_tab.mueller_stderr[c, i, j, k]
                stderr[c, q, side] = se if side == 0 else se.T
                expect[c, q, side] = metal_tab.mueller[c, i, j, k] if side == 0 else \
                    metal_tab.mueller[c, i, j, k].T * RECIPROCAL
    return ours, model, stderr, expect


def _chi2_ratio(ours, model, stderr, turn=None):
    """The largest chi-square over its Bonferroni limit, per block element, channel and half, of ``ours``
    against the model: z with the model's sigma (the cell's standard error times sqrt(model M00 /
    our M00), docs/testing.md); ``turn``: a 4 x 4 matrix applied as ``T M T`` to ours (a wrong frame
    convention)."""
    if turn is not None:
        ours = turn @ ours @ turn
    scale = np.sqrt(np.maximum(model[..., 0, 0], 0.0) / np.maximum(ours[..., 0, 0], 1e-300))
    p = 1e-6 / (len(BLOCK) * 3 * 2)
    worst = 0.0
    for i, j in BLOCK:
        for c in range(3):
            for side in range(2):     # the two halves are one sample read twice: a test each
                sig = stderr[c, :, side, i, j] * scale[c, :, side]
                s = sig > 0
                z = (ours[c, :, side, i, j] - model[c, :, side, i, j])[s] / sig[s]
                worst = max(worst, float(np.sum(z * z)) / chi2_limit(int(np.count_nonzero(s)), p))
    return worst


def test_mitsubas_measured_polarized_reads_our_export_as_its_roughconductor(mitsuba_cells):
    """Mitsuba 3's own plugin, on the exported file, at direction pairs of both halves of phi_d,
    equals its polarized roughconductor within our cells' noise (one chi-square per block element
    and channel, Bonferroni); the elements outside a microfacet reflection's block stay 0 in the
    plane frames, and it reads back our cells."""
    ours, model, stderr, expect = mitsuba_cells
    assert _chi2_ratio(ours, model, stderr) < 1.0
    off = [(i, j) for i in range(4) for j in range(4) if (i, j) not in BLOCK]
    m00 = ours[..., 0, 0]
    for i, j in off:
        assert np.all(np.abs(ours[..., i, j]) <= 1e-5 * m00 + 1e-7)
    # our cells read back (float32; Mitsuba's angles in float32 land a hair off the nodes, between
    # rows that differ by up to a few per cent in this narrow lobe)
    np.testing.assert_allclose(ours, expect, rtol=1e-2, atol=1e-4 * float(np.max(np.abs(expect))))


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
    other = Stack("metal", (Interface(layer.alpha_xy[0], tuple(x * ior_scale for x in layer.ior), layer.extinction),),
                  "metal")
    sca = tabulate(other, _settings(polarized=False, seed=12, rays=2_000_000))
    assert sca.mueller is None and not sca.polarized and metal_tab.polarized
    a, sa, ha = _pooled(metal_tab)
    b, sb, hb = _pooled(sca)
    where = np.broadcast_to((ha >= 200) & (hb >= 200), a.shape)
    if agrees:
        assert_samples_match(a, sa, b, sb, where=where)
    else:
        with pytest.raises(AssertionError):
            assert_samples_match(a, sa, b, sb, where=where)


def test_the_sparse_cells_add_up_to_the_models_flux(metal_tab, model_m00):
    """The cells left out of the comparison above (fewer than EXPECTED expected paths), in
    aggregate: their total M00 flux is the roughconductor's (docs/testing.md)."""
    for c in range(3):
        assert_sparse_flux_matches(metal_tab.value[c], metal_tab.stderr[c], model_m00[c], metal_tab.measure / np.pi,
                                   RAYS, min_expected=EXPECTED)


def test_the_intensity_is_m00(metal_tab):
    """``mueller[..., 0, 0]`` is ``value`` (and its standard error ``stderr``) bit for bit; the
    matrices are finite and zero where no path left; the degree of polarization at most 1."""
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


def test_the_export_layout(metal_tab):
    """The export's fields are the plugin's layout: 5 wavelengths (RGB at 465, 550, 610 nm, the ends
    repeated at 360 and 830 nm), phi_d over both halves, the folded half the reciprocal matrices."""
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
    """Five wavelengths whatever the channels: a spectral tabulation's five bins evenly spread (at
    their centres), three bins padded at 360 and 830 nm with their end bins."""
    from types import SimpleNamespace
    assert list(spectral_bins(30)) == [0, 7, 14, 22, 29]
    assert len(set(spectral_bins(6))) == 5
    for bins in (3, 6, 30):
        s = g.TabulationSettings(spectral=True, wavelength_bins=bins, polarized=True)
        nm, ch = wavelengths(SimpleNamespace(settings=s, wavelengths_nm=s.wavelengths_nm))
        assert nm.dtype == np.uint16 and len(nm) == 5 and np.all(np.diff(nm.astype(int)) > 0)
        centres = np.round(s.wavelengths_nm[ch])
        if bins == 3:
            assert list(ch) == [0, 0, 1, 2, 2] and nm[0] == 360 and nm[-1] == 830
            np.testing.assert_array_equal(nm[1:4], centres[1:4])
        else:
            assert list(ch) == list(spectral_bins(bins))
            np.testing.assert_array_equal(nm, centres)


def test_a_slices_file_is_refused_for_the_polarized_export(tmp_path, capsys):
    from goniometer.cli import main
    r = g.simulate(METAL, g.SimulationSettings(incident_deg=(30.0,), rays=2000, resolution=(3, 6), threads=1,
                                               polarized=True))
    g.write(tmp_path / "s.h5", r)
    assert main(["export", str(tmp_path / "s.h5"), "--format", "mitsuba-polarized", "--out",
                 str(tmp_path / "s.pbsdf")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "a slices file" in err and "gonio tabulate CONFIG --polarized" in err


def _config(tmp_path, extra: str = "") -> str:
    p = tmp_path / "metal.toml"
    p.write_text('name = "metal"\ncategory = "metal"\n[[layers]]\ntype = "interface"\nroughness = 0.03\n'
                 'ior = [0.2, 0.5, 0.9]\nextinction = [3.5, 3.0, 2.8]\n' + extra)
    return str(p)


def test_gonio_tabulate_polarized_export_and_info(tmp_path, capsys):
    """The command line: --polarized (and the [simulation] key) writes the file's Mueller matrices,
    the same bits on two threads as the library's on one (read back from the file); gonio info says
    polarized; gonio export --format mitsuba-polarized writes the tensor file, refuses to overwrite
    it without --overwrite and refuses a scalar tabulation in one line."""
    from goniometer.cli import main
    out = tmp_path / "t.h5"
    assert main(["tabulate", _config(tmp_path), "--polarized", "--rays", "20000", "--threads", "2",
                 "--out", str(out)]) == 0
    with h5py.File(out) as f:
        assert f["simulation"].attrs["polarized"] and f["brdf"].attrs["stokes_frames"] == "plane"
        assert f["brdf/mueller"].dims[4][0].name.endswith("mueller_row")
    back = read_tabulated(out)
    ref = tabulate(METAL, g.TabulationSettings(rays=20000, seed=1, threads=1, polarized=True))
    assert back.polarized and back.settings.polarized
    np.testing.assert_array_equal(back.mueller, ref.mueller)
    np.testing.assert_array_equal(back.mueller_stderr, ref.mueller_stderr)
    np.testing.assert_array_equal(back.value, ref.value)
    assert main(["info", str(out)]) == 0
    assert "polarized: each cell holds its Mueller matrix" in capsys.readouterr().out
    x = tmp_path / "t.pbsdf"
    assert main(["export", str(out), "--format", "mitsuba-polarized", "--out", str(x)]) == 0
    f = read_tensor(x)
    assert f["M"].shape == (360, 90, 90, 5, 4, 4) and list(f["wvls"]) == [360, 465, 550, 610, 830]
    capsys.readouterr()
    assert main(["export", str(out), "--format", "mitsuba-polarized", "--out", str(x)]) == 2
    assert "--overwrite" in capsys.readouterr().err
    # the [simulation] key, and the option over it
    from goniometer.cli import build_parser
    from goniometer.cli.tabulate import tabulation_settings
    from goniometer.stack import load_toml
    cfg = _config(tmp_path, "[simulation]\npolarized = true\n")
    args = build_parser().parse_args(["tabulate", cfg, "--out", str(tmp_path / "k.h5")])
    assert tabulation_settings(load_toml(cfg)[1], args).polarized
    args = build_parser().parse_args(["tabulate", _config(tmp_path), "--out", "k.h5"])
    assert not tabulation_settings(load_toml(_config(tmp_path))[1], args).polarized
    # a scalar tabulation is refused, naming what is needed
    sca = tmp_path / "s.h5"
    assert main(["tabulate", _config(tmp_path), "--rays", "2000", "--threads", "1", "--out", str(sca)]) == 0
    capsys.readouterr()
    assert main(["export", str(sca), "--format", "mitsuba-polarized", "--out", str(tmp_path / "s.pbsdf")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--polarized" in err and "gonio: error:" in err
    assert not (tmp_path / "s.pbsdf").exists()


def test_a_polarized_tabulation_on_cuda_is_accepted():
    """The CUDA kernel tabulates polarized light (tests/goniometer/kernel/test_cuda.py runs it)."""
    s = g.TabulationSettings(polarized=True, device="cuda")
    assert s.polarized and s.device == "cuda"


@pytest.mark.parametrize("folded", [False, True])
def test_a_paths_record_is_its_matrix_in_the_plane_frames(folded):
    """The kernel's record of an exit (goniometer.kernel.polarized.tabulated_exit) is the path's
    matrix taken from the s/p frames to the plane frames as goniometer.grids.stokes converts it, and
    in the folded half reciprocity's D M^T D of that."""
    from goniometer.kernel.polarized import P_FRAME, tabulated_exit
    from goniometer.grids.stokes import frame_x
    rng = np.random.default_rng(4)
    for _ in range(20):
        l, v = rng.normal(size=3), rng.normal(size=3)
        l[2], v[2] = abs(l[2]), abs(v[2])
        l, v = l / np.linalg.norm(l), v / np.linalg.norm(v)
        m = rng.normal(size=(3, 4, 4))
        pol = np.zeros((4, 16))
        pol[:3] = m.reshape(3, 16)
        pol[P_FRAME, :3] = frame_x("sp", l, v)[1]
        out = np.empty((16, 3))
        tabulated_exit(pol, *l, *v, folded, out)
        want = convert_mueller(m, l, v, "sp", "plane")
        if folded:
            want = np.swapaxes(want, -1, -2) * RECIPROCAL
        np.testing.assert_allclose(np.moveaxis(out.reshape(4, 4, 3), -1, 0), want, atol=1e-12)


def test_a_polarized_tabulation_resumes_to_the_same_bits(tmp_path):
    """Interrupted after its first batch, a polarized tabulation resumes from its checkpoint (which
    keeps the Mueller sums) to the bits of an uninterrupted run; a scalar run's checkpoint is not
    a polarized run's (the run's identity says polarized)."""
    from goniometer.run.checkpoints import CheckpointMismatch
    from goniometer.run.tabulation import TabulationCheckpoint, tabulation_description
    settings = _settings(rays=40_000, chunk_rays=4096)
    one = tabulate(METAL, settings)
    cp = TabulationCheckpoint(tmp_path / "cp", tabulation_description(METAL, settings))

    def stop(n):
        raise KeyboardInterrupt
    with pytest.raises(KeyboardInterrupt):
        tabulate(METAL, settings, checkpoint=cp, progress=stop)
    with np.load(tmp_path / "cp" / "state.npz") as z:
        assert {"mueller", "mueller_sq"} <= set(z.files) and 0 < int(z["next_chunk"]) < 10
    again = tabulate(METAL, settings, checkpoint=cp)
    np.testing.assert_array_equal(again.mueller, one.mueller)
    np.testing.assert_array_equal(again.mueller_stderr, one.mueller_stderr)
    np.testing.assert_array_equal(again.value, one.value)
    scalar = replace(settings, polarized=False)
    assert "polarized" not in tabulation_description(METAL, scalar)["settings"]
    with pytest.raises(CheckpointMismatch):
        TabulationCheckpoint(tmp_path / "cp", tabulation_description(METAL, scalar)).check()
