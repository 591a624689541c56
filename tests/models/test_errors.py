"""models.compare.errors: eq. 4, noise floors, masks."""

from __future__ import annotations

import math

import numpy as np

from goniometer.run.results import SliceData
from goniometer.grids.slice_grid import SliceGrid
from models.compare import errors
from models.compare.integrate import ModelSlices


def _slices(rng, M=2, nt=6, nph=8):
    g = SliceGrid("classic", nt, nph)
    orders = rng.random((M, 2, 3, nt, nph))
    value = orders[:, 0] + orders[:, 1]
    stderr = 0.01 * rng.random((M, 3, nt, nph))
    omega = np.broadcast_to(g.proj_solid_angle(np.array([0, 0, 1.0])), (M, nt, nph)).copy()
    mask = np.ones((M, nt, nph), bool)
    return SliceData(g, value, stderr, orders, mask, omega, stderr_internal=0.5 * stderr)


def test_identical_slices_give_zero():
    sd = _slices(np.random.default_rng(0))
    ms = ModelSlices("m", "brdf", sd.grid, sd.orders[:, 0], sd.orders[:, 1], 5)
    e = errors.compare(sd, ms, drop_first_order=True)
    for part in ("internal", "total"):
        assert e[part]["rmse"] == [0.0, 0.0, 0.0] and e[part]["rmse_mean"] == 0.0 and e[part]["rmse_luminance"] == 0.0


def test_eq4_by_hand_and_noise_floor_from_stderr():
    rng = np.random.default_rng(1)
    sd = _slices(rng)
    model = sd.value + 0.05
    # constant difference d: E_c = sqrt(1/M sum_m sum_cells d^2 Omega) = d sqrt(sum Omega over one slice) = d sqrt(pi)
    e = errors.error_object(sd.value, sd.stderr, model, sd.proj_solid_angle, sd.mask)
    np.testing.assert_allclose(e["rmse"], 0.05 * math.sqrt(math.pi), rtol=1e-12)
    np.testing.assert_allclose(e["rmse_luminance"], 0.05 * math.sqrt(math.pi), rtol=1e-12)
    M = sd.value.shape[0]
    expected = [math.sqrt(np.sum(sd.stderr[:, c] ** 2 * sd.proj_solid_angle) / M) for c in range(3)]
    np.testing.assert_allclose(e["noise_floor"], expected, rtol=1e-12)
    assert e["noise_floor_mean"] == np.mean(expected)
    # internal comparison uses orders >= 2 and the internal standard error
    ms = ModelSlices("m", "brdf", sd.grid, np.zeros_like(sd.value), sd.orders[:, 1], 5)
    ei = errors.compare(sd, ms, drop_first_order=True)["internal"]
    assert ei["rmse_mean"] == 0.0
    np.testing.assert_allclose(ei["noise_floor"], 0.5 * np.array(expected), rtol=1e-12)


def test_noise_floor_is_what_a_perfect_model_scores():
    """A perfect model against a reference with Gaussian noise of the stated stderr scores, on
    average, its noise floor (E[(f_ref - f_true)^2] = stderr^2)."""
    rng = np.random.default_rng(2)
    sd = _slices(rng, M=3, nt=20, nph=40)
    truth = sd.value.copy()
    noisy = truth + rng.normal(size=truth.shape) * sd.stderr
    e = errors.error_object(noisy, sd.stderr, truth, sd.proj_solid_angle, sd.mask)
    np.testing.assert_allclose(e["rmse"], e["noise_floor"], rtol=0.05)


def test_masked_cells_never_count():
    rng = np.random.default_rng(3)
    sd = _slices(rng)
    model = sd.value * 1.1
    before = errors.error_object(sd.value, sd.stderr, model, sd.proj_solid_angle, sd.mask)
    sd.mask[:, 2, 3] = False
    wild = model.copy()
    wild[:, :, 2, 3] = 1e9
    masked = errors.error_object(sd.value, sd.stderr, wild, sd.proj_solid_angle, sd.mask)
    sd.mask[:, 2, 3] = True
    sd2 = errors.error_object(sd.value, sd.stderr, model, sd.proj_solid_angle, sd.mask)
    assert masked["rmse_mean"] < before["rmse_mean"] and before == sd2


def test_reference_norm_is_the_error_of_a_model_that_predicts_nothing():
    rng = np.random.default_rng(5)
    ref = rng.random((2, 3, 4, 5))
    omega = rng.random((2, 4, 5))
    mask = rng.random((2, 4, 5)) > 0.3
    e = errors.error_object(ref, 0.1 * ref, np.zeros_like(ref), omega, mask)
    assert e["reference_norm"] == e["rmse"]
    # by hand, channel 1: sqrt((1/M) sum f^2 Omega over valid cells)
    by_hand = np.sqrt(sum((ref[m, 1] ** 2 * omega[m] * mask[m]).sum() for m in range(2)) / 2)
    assert abs(e["reference_norm"][1] - by_hand) < 1e-12
