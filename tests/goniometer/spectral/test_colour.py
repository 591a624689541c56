"""The colour pipeline (goniometer.spectral.colorimetry, .upsampling) against colour-science's own
integration, the D65 white point, the Mallett-Yuksel round trip and brute-force correlated samples."""

from __future__ import annotations

import colour
import numpy as np
import pytest
from scipy.special import erf

from goniometer.spectral import (
    DEFAULT_BINS,
    RANGE_NM,
    XYZ_TO_LINEAR_SRGB,
    SpectrumError,
    Upsampled,
    combined_stderr,
    rgb_weights,
    spectral_to_rgb,
    spectral_to_xyz,
    upsample_rgb,
    wavelength_bins,
    xyz_weights,
)
from goniometer.spectral.upsampling import basis_at

CMFS = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
D65 = colour.SDS_ILLUMINANTS["D65"]

#: max |RGB(ones) - 1| over the channels (the IEC matrix's 4 decimals and the 360-830 nm integral)
WHITE_RESIDUAL = 2e-4


def test_wavelength_bins():
    centres, edges = wavelength_bins()
    assert DEFAULT_BINS == 30 and RANGE_NM == (360.0, 830.0)
    assert centres.shape == (30,) and edges.shape == (31,)
    assert edges[0] == 360.0 and edges[-1] == 830.0
    np.testing.assert_allclose(np.diff(edges), 470.0 / 30, rtol=1e-12)
    np.testing.assert_allclose(centres, 360.0 + (np.arange(30) + 0.5) * 470.0 / 30, rtol=1e-12)
    assert wavelength_bins(3)[1].tolist() == [360.0, 360.0 + 470 / 3, 360.0 + 940 / 3, 830.0]


@pytest.mark.parametrize("n", [31, 0, -3, 1, 3.0, True, "30"])
def test_wavelength_bins_multiple_of_three(n):
    with pytest.raises(SpectrumError, match=r"^wavelength_bins = .*: must be a positive multiple of 3 "
                                            r"\(each path carries three wavelengths\)$"):
        wavelength_bins(n)


def test_the_message_quotes_the_count():
    with pytest.raises(SpectrumError, match=r"^wavelength_bins = 31: "):
        wavelength_bins(31)


@pytest.mark.parametrize("n", [3, 30, 90])
def test_ones_give_y_one_and_the_d65_white(n):
    _, edges = wavelength_bins(n)
    xyz = spectral_to_xyz(np.ones(n), edges)
    assert abs(xyz[1] - 1.0) < 1e-12
    # colour's D65 white point: xy = (0.3127, 0.3290) (4 decimals), XYZ = (0.95047, 1, 1.08883)
    np.testing.assert_allclose(xyz[:2] / xyz.sum(), [0.3127, 0.3290], atol=1e-4)
    np.testing.assert_allclose(xyz, [0.95047, 1.0, 1.08883], atol=2e-5)
    rgb = spectral_to_rgb(np.ones(n), edges)
    np.testing.assert_allclose(rgb, 1.0, rtol=0, atol=WHITE_RESIDUAL)
    np.testing.assert_allclose(spectral_to_rgb(np.full(n, 0.37), edges), 0.37, rtol=0, atol=0.37 * WHITE_RESIDUAL)


def test_rgb_weights_are_xyz_weights_through_the_srgb_matrix():
    _, edges = wavelength_bins()
    np.testing.assert_allclose(XYZ_TO_LINEAR_SRGB, colour.RGB_COLOURSPACES["sRGB"].matrix_XYZ_to_RGB)
    np.testing.assert_allclose(rgb_weights(edges), xyz_weights(edges) @ XYZ_TO_LINEAR_SRGB.T, rtol=1e-14)
    assert xyz_weights(edges).shape == (30, 3) and np.all(xyz_weights(edges)[:, 1] >= 0)
    # the illuminant-weighted observer's integral is additive over bins: 3 bins = sums of 30
    coarse = xyz_weights(wavelength_bins(3)[1])
    np.testing.assert_allclose(coarse, xyz_weights(edges).reshape(3, 10, 3).sum(axis=1), rtol=1e-12)


def _gaussian_bin_means(edges, mu=550.0, sigma=40.0, amp=0.8, base=0.1):
    primitive = 0.5 * sigma * np.sqrt(2 * np.pi) * erf((edges - mu) / (np.sqrt(2) * sigma))
    return base + amp * np.diff(primitive) / np.diff(edges)


def _colour_reference():
    lam = np.arange(360.0, 831.0)
    sd = colour.SpectralDistribution(0.1 + 0.8 * np.exp(-0.5 * ((lam - 550.0) / 40.0) ** 2), lam)
    return colour.sd_to_XYZ(sd, CMFS, D65, method="Integration") / 100.0


@pytest.mark.filterwarnings("ignore:Aligning")  # colour extends its D65 table (to 780 nm) to 830 nm
@pytest.mark.parametrize("n, y_tol, xyz_tol", [
    # binning error of a bin-averaged Gaussian reflectance (sigma 40 nm) at 30 bins:
    # X -0.09 %, Y -0.54 %, Z +1.28 %; at 470 bins (1 nm): |error| <= 1.1e-4
    (30, 1e-2, 1.5e-2),
    (470, 1e-3, 1e-3),
])
def test_xyz_agrees_with_colours_integration(n, y_tol, xyz_tol):
    edges = np.linspace(360.0, 830.0, n + 1)
    ours = spectral_to_xyz(_gaussian_bin_means(edges), edges)
    ref = _colour_reference()
    assert abs(ours[1] / ref[1] - 1) < y_tol
    np.testing.assert_allclose(ours, ref, rtol=xyz_tol)


def test_axis_argument():
    _, edges = wavelength_bins()
    values = np.random.default_rng(1).random((4, 30, 2))
    out = spectral_to_rgb(values, edges, axis=1)
    assert out.shape == (4, 3, 2)
    np.testing.assert_allclose(out[2, :, 1], values[2, :, 1] @ rgb_weights(edges), rtol=1e-13)
    with pytest.raises(SpectrumError, match="bins"):
        spectral_to_xyz(values, edges)
    with pytest.raises(SpectrumError, match="edges_nm"):
        xyz_weights(np.array([350.0, 500.0, 830.0]))


# --- Mallett & Yuksel 2019 upsampling

def test_mallett_basis_sums_to_one():
    published = colour.recovery.MSDS_BASIS_FUNCTIONS_sRGB_MALLETT2019.values
    assert np.abs(published.sum(axis=1) - 1).max() < 1e-5  # 9.98e-6: a partition of unity to 1e-5
    assert np.all(published > 0)
    lam = np.linspace(360.0, 830.0, 941)
    np.testing.assert_allclose(basis_at(lam).sum(axis=-1), 1.0, rtol=0, atol=1e-15)
    np.testing.assert_allclose(basis_at(np.array([380.0, 500.0, 780.0])),
                               published[[0, 24, -1]] / published[[0, 24, -1]].sum(axis=1, keepdims=True),
                               rtol=1e-14)


def _bin_means(f, edges, per_bin=200):
    fine = np.linspace(edges[0], edges[-1], (len(edges) - 1) * per_bin + 1)
    return f(0.5 * (fine[1:] + fine[:-1])).reshape(len(edges) - 1, per_bin, -1).mean(axis=1)


@pytest.mark.parametrize("n, atol", [
    (470, 2e-3),  # 1 nm bins: the paper's round trip (max error 1.1e-3)
    (30, 2e-2),   # 30 bins: the binning error of the basis (max 1.3e-2)
])
def test_primaries_round_trip(n, atol):
    edges = np.linspace(360.0, 830.0, n + 1)
    basis = _bin_means(basis_at, edges)  # (n, 3): the bin means of B_r, B_g, B_b
    np.testing.assert_allclose(spectral_to_rgb(basis.T, edges), np.eye(3), rtol=0, atol=atol)
    red = _bin_means(lambda lam: upsample_rgb((1.0, 0.0, 0.0), lam)[..., None], edges)[:, 0]
    np.testing.assert_allclose(spectral_to_rgb(red, edges), [1.0, 0.0, 0.0], rtol=0, atol=atol)


def test_achromatic_triples_upsample_to_exact_constants():
    lam = np.linspace(300.0, 900.0, 601)
    for c in (0.0, 0.18, 0.5, 1.0, 1.5, 2.4172, 1e-7):
        out = upsample_rgb((c, c, c), lam)
        assert out.dtype == np.float64 and out.shape == lam.shape
        assert np.all(out == c)  # bit for bit
        assert np.all(Upsampled((c, c, c)).at(lam) == c)


def test_upsampled_is_a_convex_combination():
    lam = np.linspace(360.0, 830.0, 471)
    rng = np.random.default_rng(7)
    for rgb in rng.random((50, 3)) * 2:
        out = upsample_rgb(tuple(rgb), lam)
        assert np.all(out >= rgb.min() - 1e-15) and np.all(out <= rgb.max() + 1e-15)


def test_upsampled_value():
    u = Upsampled((0.2, 0.4, 0.6))
    assert u.covers(0.0, 1e6) and u.to_dict() == {"rgb": [0.2, 0.4, 0.6]}
    np.testing.assert_array_equal(u.at([450.0, 550.0]), upsample_rgb((0.2, 0.4, 0.6), [450.0, 550.0]))
    assert u.at(500.0).shape == ()
    for bad in ((0.1, 0.2), (0.1, 0.2, float("nan")), "abc"):
        with pytest.raises(SpectrumError):
            Upsampled(bad)


# --- standard errors of correlated bins

def _simulate(n_bins, groups, sigma_shared, sigma_own, replicates, seed):
    """Replicate estimates of the bins: bins of a group share one normal draw (their paths)."""
    rng = np.random.default_rng(seed)
    shared = rng.standard_normal((replicates, groups.max() + 1))[:, groups]
    return shared * sigma_shared + rng.standard_normal((replicates, n_bins)) * sigma_own


def test_combined_stderr_bounds_correlated_bins():
    n = 30
    groups = np.arange(n) // 3  # three wavelengths per path: here bins 3g, 3g + 1, 3g + 2 share paths
    rng = np.random.default_rng(3)
    sigma_shared, sigma_own = rng.random(n) * 0.05, rng.random(n) * 0.05
    samples = _simulate(n, groups, sigma_shared, sigma_own, 200_000, seed=4)
    weights = rgb_weights(wavelength_bins(n)[1])
    sigma = np.sqrt(sigma_shared**2 + sigma_own**2)  # each bin's own standard error
    bound = combined_stderr(sigma, weights, groups)
    empirical = (samples @ weights).std(axis=0)
    # the sample std's relative error is ~1/sqrt(2 * 200000) = 0.16 %: 1 % is > 6 sigma
    assert np.all(bound >= empirical * 0.99)
    # treating the bins as independent would understate Y (weights >= 0, positively correlated bins)
    y = xyz_weights(wavelength_bins(n)[1])[:, 1]
    naive = np.sqrt(np.sum(sigma**2 * y**2))
    empirical_y = (samples @ y).std()
    assert naive < empirical_y * 0.95 and combined_stderr(sigma, y, groups) >= empirical_y * 0.99


def test_combined_stderr_is_tight_for_perfect_correlation_and_independence():
    n = 9
    weights = np.linspace(0.5, 2.0, n)
    sigma = np.linspace(0.01, 0.03, n)
    groups = np.repeat([0, 1, 2], 3)
    perfect = _simulate(n, groups, sigma, np.zeros(n), 400_000, seed=5) @ weights
    bound = combined_stderr(sigma, weights, groups)
    exact = np.sqrt(sum((weights[groups == g] * sigma[groups == g]).sum() ** 2 for g in range(3)))
    assert abs(bound - exact) < 1e-15
    assert abs(perfect.std() / bound - 1) < 0.01  # the sample std: 0.11 % relative error
    independent = _simulate(n, np.arange(n), sigma, np.zeros(n), 400_000, seed=6) @ weights
    bound = combined_stderr(sigma, weights, np.arange(n))
    assert abs(bound - np.sqrt(np.sum((weights * sigma) ** 2))) < 1e-15
    assert abs(independent.std() / bound - 1) < 0.01


def test_combined_stderr_shapes():
    _, edges = wavelength_bins()
    groups = np.arange(30) % 10
    s = np.random.default_rng(0).random((5, 30, 2))
    out = combined_stderr(s, rgb_weights(edges), groups, axis=1)
    assert out.shape == (5, 3, 2)
    np.testing.assert_allclose(out[1, :, 0], combined_stderr(s[1, :, 0], rgb_weights(edges), groups))
    assert combined_stderr(s[0, :, 0], np.ones(30), groups).shape == ()
    with pytest.raises(SpectrumError):
        combined_stderr(s[0, :, 0], np.ones(30), groups[:5])
