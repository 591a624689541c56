"""The RGL export checked by the real client: Mitsuba 3's ``measured`` plugin loads our files, and

* a rough gold conductor recorded on the RGL grid agrees node by node (chi-square within the
  standard errors) with the stored values Mitsuba's own ``roughconductor`` implies, and the
  plugin's ``eval`` of the exported file at random direction pairs agrees with the plugin's ``eval``
  of the exactly computed file within the propagated standard errors; the exact file itself stays
  within the stated interpolation error of ``roughconductor`` (``docs/rgl-format.md``);
* the plugin's value at the nodes is ``S D / (4 sigma)`` of our tables (the format understood);
* the spectral file loads in ``scalar_spectral`` and a reader written from pbrt-v4's rules takes it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import goniometer as g
from goniometer.files.rgl_export import bsdf_fields, check_readers, fields_from_values
from goniometer.grids.warp import bilinear
from goniometer.grids.rgl import grid_for
from goniometer.files.rgl_tensor import write_tensor
from goniometer.testing import Z_TOL, assert_cells_match

mi = pytest.importorskip("mitsuba")

ETA, K = (0.2, 0.35, 1.4), (3.5, 2.6, 1.9)
ALPHA = 0.3
RAYS = 400_000


@pytest.fixture(scope="module")
def gold():
    stack = g.stack_from_dict({"name": "gold", "category": "metal", "layers": [
        {"type": "interface", "roughness": ALPHA, "ior": list(ETA), "extinction": list(K)}]})
    grid = grid_for(stack, 4, 1, 12)
    settings = g.SimulationSettings.on_rgl_grid(grid, rays=RAYS, seed=11, threads=2)
    return stack, grid, g.simulate(stack, settings)


@pytest.fixture(scope="module")
def rgb_variant():
    mi.set_variant("scalar_rgb")
    ref = mi.load_dict({"type": "roughconductor", "distribution": "ggx", "alpha": ALPHA, "sample_visible": True,
                        "eta": {"type": "rgb", "value": list(ETA)}, "k": {"type": "rgb", "value": list(K)}})
    return ref


def _eval(bsdf, wi, wo) -> np.ndarray:
    """Mitsuba's eval (f cos theta_o) at direction pairs (N, 3) each: wi towards the camera/light."""
    si = mi.SurfaceInteraction3f()
    ctx = mi.BSDFContext()
    out = np.empty((len(wi), 3))
    for k in range(len(wi)):
        si.wi = mi.Vector3f(*wi[k])
        out[k] = np.array(bsdf.eval(ctx, si, mi.Vector3f(*wo[k])))
    return out


def _expected_estimates(grid, ref, sub: int = 6, evaluate=None, channels: int = 3) -> np.ndarray:
    """What the recording estimates at each node, from roughconductor: the dual cell's integral of
    f cos / p over u (midpoint rule, ``sub`` x ``sub`` points), divided by the cell's measure.
    ``evaluate(bsdf, wi, wo) -> (N, channels)`` (default :func:`_eval`, RGB)."""
    evaluate = _eval if evaluate is None else evaluate
    n = grid.n
    edges = np.clip((np.arange(n + 1) - 0.5) / (n - 1), 0.0, 1.0)
    width = np.diff(edges)
    pts = edges[:-1, None] + width[:, None] * (np.arange(sub) + 0.5)[None, :] / sub
    ux = np.broadcast_to(pts[None, :, None, :], (n, n, sub, sub))
    uy = np.broadcast_to(pts[:, None, :, None], (n, n, sub, sub))
    out = np.zeros((len(grid.theta_i_deg), channels, n, n))
    for m in range(len(grid.theta_i_deg)):
        warp = grid.warp(m)
        x, y = warp.sample(ux, uy)
        h, v = grid.node_directions(m, ux, uy)
        l = grid.light(m)
        theta_m = 0.5 * math.pi * x * x
        p = warp.pdf(x, y) / (2 * math.pi ** 2 * x * np.sin(theta_m) * 4 * np.maximum(h @ l, 1e-300))
        ok = (v[..., 2] > 0) & (p > 0)
        fc = np.zeros(v.shape[:-1] + (channels,))
        idx = np.argwhere(ok)
        vals = evaluate(ref, np.broadcast_to(l, (len(idx), 3)), v[ok])
        fc[ok] = vals / p[ok][:, None]
        area = width[:, None] * width[None, :]
        out[m] = np.moveaxis(fc.mean(axis=(2, 3)), -1, 0) * area / np.where(grid.cell_geometry(m)[0] > 0,
                                                                             grid.cell_geometry(m)[0], np.inf)
    return out


def test_recorded_nodes_agree_with_roughconductor(gold, rgb_variant):
    stack, grid, r = gold
    expected = _expected_estimates(grid, rgb_variant)
    for m in range(len(grid.theta_i_deg)):
        area, mask = grid.cell_geometry(m)
        assert_cells_match(r.brdf.value[m], r.brdf.stderr[m], expected[m], area, RAYS, min_expected=20,
                           where=mask, min_cells=60)
    # the energy in the nodes is the reflected energy, and roughconductor's albedo
    for m in range(len(grid.theta_i_deg)):
        area, _ = grid.cell_geometry(m)
        np.testing.assert_allclose((r.brdf.value[m] * area).sum(axis=(1, 2)), r.energy["reflected"][m], rtol=1e-12)


def test_a_wrong_roughness_fails_the_same_check(gold):
    """The node check can fail: roughconductor at alpha 0.36 is told apart from our alpha 0.3."""
    stack, grid, r = gold
    mi.set_variant("scalar_rgb")
    wrong = mi.load_dict({"type": "roughconductor", "distribution": "ggx", "alpha": 0.36,
                          "eta": {"type": "rgb", "value": list(ETA)}, "k": {"type": "rgb", "value": list(K)}})
    expected = _expected_estimates(grid, wrong, sub=4)
    area, mask = grid.cell_geometry(1)
    with pytest.raises(AssertionError, match="chi2"):
        assert_cells_match(r.brdf.value[1], r.brdf.stderr[1], expected[1], area, RAYS, min_expected=20, where=mask,
                           min_cells=60)


def _random_pairs(grid, rng, count=300):
    """Direction pairs at the grid's incident nodes with outgoing directions drawn around the lobe."""
    wi, wo = [], []
    for m in range(len(grid.theta_i_deg)):
        l = grid.light(m)
        u = rng.random((count, 2)) * 0.96 + 0.02
        _, v = grid.node_directions(m, u[:, 0], u[:, 1])
        keep = v[:, 2] > 0.05
        wi.append(np.broadcast_to(l, (keep.sum(), 3)))
        wo.append(v[keep])
    return np.concatenate(wi), np.concatenate(wo)


def test_the_plugin_reads_the_exported_file_as_we_wrote_it(gold, rgb_variant, tmp_path):
    stack, grid, r = gold
    fields = bsdf_fields(r)
    assert not check_readers(fields)["mitsuba-rgb"]
    path = write_tensor(tmp_path / "gold_rgb.bsdf", fields)
    measured = mi.load_dict({"type": "measured", "filename": str(path)})
    # at the nodes: S D / (4 sigma) with our tables
    tab = grid.tables()
    n = grid.n
    for m in range(len(grid.theta_i_deg)):
        uu = np.linspace(0, 1, n)
        ux, uy = np.meshgrid(uu, uu)
        h, v = grid.node_directions(m, ux, uy)
        ok = (v[..., 2] > 0.05) & (h[..., 2] < 0.999)
        l = grid.light(m)
        got = _eval(measured, np.broadcast_to(l, (ok.sum(), 3)), v[ok])
        th_m = np.arccos(np.clip(h[ok][:, 2], -1, 1))
        ph_m = np.arctan2(h[ok][:, 1], h[ok][:, 0])
        D = bilinear(tab["ndf"].astype(np.float64), np.sqrt(th_m / (math.pi / 2)), (ph_m + math.pi) / (2 * math.pi))
        sig = bilinear(tab["sigma"].astype(np.float64), np.array(math.sqrt(math.acos(l[2]) / (math.pi / 2))),
                        np.array(0.5))
        want = fields["rgb"][0, m][:, ok].T * (D / (4 * sig))[:, None]
        np.testing.assert_allclose(got, want, rtol=2e-3, atol=1e-6)


def test_random_pairs_within_noise_of_the_exact_file_which_is_within_the_stated_interpolation_error(
        gold, rgb_variant, tmp_path):
    stack, grid, r = gold
    exact = _expected_estimates(grid, rgb_variant)
    sim_path = write_tensor(tmp_path / "sim.bsdf", bsdf_fields(r))
    ex_path = write_tensor(tmp_path / "exact.bsdf", fields_from_values(grid, exact, "exact"))
    # the noise of the exported file: the stored values' standard errors (same correction) as a file
    se_path = write_tensor(tmp_path / "se.bsdf", fields_from_values(grid, r.brdf.stderr, "stderr"))
    sim = mi.load_dict({"type": "measured", "filename": str(sim_path)})
    ex = mi.load_dict({"type": "measured", "filename": str(ex_path)})
    se = mi.load_dict({"type": "measured", "filename": str(se_path)})
    wi, wo = _random_pairs(grid, np.random.default_rng(5))
    a_sim, a_ex, a_se, ref = _eval(sim, wi, wo), _eval(ex, wi, wo), _eval(se, wi, wo), _eval(rgb_variant, wi, wo)
    # interpolation mixes four nodes: their largest standard error bounds the interpolant's
    z = np.abs(a_sim - a_ex) / np.maximum(a_se, 1e-12)
    assert np.all(z[a_se > 0] < Z_TOL), float(z.max())
    rel = np.abs(a_ex - ref) / np.maximum(ref, 1e-3)
    # the stated interpolation error of the format on this 12 x 12 grid (docs/rgl-format.md: median
    # 1.3 %, 95th percentile 11 %, the largest at grazing outgoing directions)
    assert np.median(rel) < 0.02 and np.percentile(rel, 95) < 0.15, (np.median(rel), np.percentile(rel, 95))


def test_spectral_file_loads_in_scalar_spectral_and_pbrt_rules_take_it(gold, tmp_path):
    stack, grid, r = gold
    fields = bsdf_fields(r, spectral=True)
    verdict = check_readers(fields)
    assert not verdict["pbrt-v4"] and not verdict["mitsuba-spectral"] and verdict["mitsuba-rgb"]
    assert check_readers(bsdf_fields(r))["pbrt-v4"] == ["pbrt-v4 reads spectra + wavelengths only"]
    path = write_tensor(tmp_path / "gold_spec.bsdf", fields)
    mi.set_variant("scalar_spectral")
    try:
        measured = mi.load_dict({"type": "measured", "filename": str(path)})
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(*grid.light(1))
        si.wavelengths = mi.UnpolarizedSpectrum([550.0, 550.0, 550.0, 550.0])
        _, v = grid.node_directions(1, np.array([0.3]), np.array([0.5]))
        got = measured.eval(mi.BSDFContext(), si, mi.Vector3f(*v[0]))
        val = float(np.array(got)[0])
    finally:
        mi.set_variant("scalar_rgb")
    rgb = mi.load_dict({"type": "measured", "filename": str(write_tensor(tmp_path / "g.bsdf", bsdf_fields(r)))})
    want = _eval(rgb, grid.light(1)[None], v)[0, 1]       # 550 nm is the green channel's node
    assert val == pytest.approx(want, rel=2e-3)
    with pytest.raises(RuntimeError, match="spectral variant"):  # the RGB variant refuses the spectral file
        mi.load_dict({"type": "measured", "filename": str(path)})


def test_a_reader_of_pbrts_rules_takes_the_spectral_file_and_agrees_with_mitsuba(gold, tmp_path):
    from tests.goniometer.rgl.pbrt_rules import PbrtMeasured, Refused
    stack, grid, r = gold
    spec = write_tensor(tmp_path / "gold_spec.bsdf", bsdf_fields(r, spectral=True))
    with pytest.raises(Refused, match="spectra"):
        PbrtMeasured(str(write_tensor(tmp_path / "gold_rgb.bsdf", bsdf_fields(r))))
    pbrt = PbrtMeasured(str(spec))
    mi.set_variant("scalar_rgb")
    rgb = mi.load_dict({"type": "measured", "filename": str(tmp_path / "gold_rgb.bsdf")})
    wi, wo = _random_pairs(grid, np.random.default_rng(9), count=40)
    mits = _eval(rgb, wi, wo)
    for k in range(len(wi)):
        # pbrt's wo is the camera side (Mitsuba's wi); its f has no cosine; 550 nm is the green node
        got = pbrt.f(wi[k], wo[k], 550.0) * wo[k][2]
        assert got == pytest.approx(mits[k, 1], rel=2e-3, abs=1e-6)
        # two-sided: the mirrored pair gives the same value; opposite sides give nothing
        flip = np.array([1.0, 1.0, -1.0])
        assert pbrt.f(wi[k] * flip, wo[k] * flip, 550.0) == pytest.approx(got / wo[k][2], rel=1e-6)
        assert pbrt.f(wi[k], wo[k] * flip, 550.0) == 0.0


def test_a_coated_conductor_exported_renders_our_classic_slices(tmp_path):
    """A rough coat over a rough conductor: the plugin's eval of the exported file, integrated over
    regions of a classic grid (4 deg x 45 deg of theta_o x phi_o, midpoint rule on its 2 x 4 deg cells),
    matches our classic slices of the same material within the two runs' standard errors plus the
    stated interpolation error (2 % of a region's energy) for theta_o < 60 deg (nearer the horizon
    the format's few nodes err more: docs/rgl-format.md). A coat of roughness 0.18 in the classic
    run instead of 0.15 fails it."""
    stack = g.stack_from_dict({"name": "coated", "category": "metal", "layers": [
        {"type": "interface", "roughness": 0.15, "ior": 1.5},
        {"type": "medium", "optical_depth": [0.1, 0.3, 0.6]},
        {"type": "interface", "roughness": 0.35, "ior": list(ETA), "extinction": list(K)}]})
    grid = grid_for(stack, 4, 1, 16)
    rgl = g.simulate(stack, g.SimulationSettings.on_rgl_grid(grid, rays=4 * RAYS, seed=3, threads=2))
    theta = grid.theta_i_deg[1:3]
    classic = g.simulate(stack, g.SimulationSettings(incident_deg=theta, rays=4 * RAYS, resolution=(45, 90), seed=4,
                                                     threads=2))
    mi.set_variant("scalar_rgb")
    files = {k: write_tensor(tmp_path / f"{k}.bsdf", fields_from_values(grid, v, k))
             for k, v in (("value", rgl.brdf.value), ("stderr", rgl.brdf.stderr))}
    value, stderr = (mi.load_dict({"type": "measured", "filename": str(p)}) for p in files.values())
    cg = classic.brdf.grid
    th_c, ph_c = np.radians(cg.theta_centers_deg()), np.radians(cg.phi_centers_deg())
    T, P = np.meshgrid(th_c, ph_c, indexing="ij")
    dw = (np.radians(2.0) * np.radians(4.0)) * np.sin(T)
    v = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], axis=-1)
    for k, t in enumerate(theta):
        m = 1 + k
        l = grid.light(m)
        flat = v.reshape(-1, 3)
        a = _eval(value, np.broadcast_to(l, flat.shape), flat).reshape(T.shape + (3,))
        s = _eval(stderr, np.broadcast_to(l, flat.shape), flat).reshape(T.shape + (3,))
        ours = np.moveaxis(classic.brdf.value[k], 0, -1) * classic.brdf.proj_solid_angle[k][..., None]
        ours_se = np.moveaxis(classic.brdf.stderr[k], 0, -1) * classic.brdf.proj_solid_angle[k][..., None]
        # regions: 23 rings of theta_o x 8 azimuth sectors
        ring = (np.arange(45) // 2)[:, None] * np.ones((1, 90), int)
        sector = np.ones((45, 1), int) * (np.arange(90) // 12)[None, :]
        for r_ in range(23):
            for q in range(8):
                sel = (ring == r_) & (sector == q) & (T < np.radians(60))
                if not sel.any():
                    continue
                A = (a[sel] * dw[sel][:, None]).sum(axis=0)
                B = ours[sel].sum(axis=0)
                sa = (s[sel] * dw[sel][:, None]).sum(axis=0)           # nodes correlated: summed, an upper bound
                sb = np.sqrt((ours_se[sel] ** 2).sum(axis=0))
                tol = Z_TOL * np.sqrt(sa ** 2 + sb ** 2) + 0.02 * np.maximum(A, B) + 1e-5
                assert np.all(np.abs(A - B) <= tol), (t, r_, q, A, B, tol)
