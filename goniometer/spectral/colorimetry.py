"""The colour pipeline of spectral runs: wavelength bins, CIE XYZ and linear sRGB, standard errors.

A spectral result holds one value per wavelength bin (``n`` equal bins over 360-830 nm, the value
constant over its bin). ``values @ xyz_weights(edges)`` is CIE 1931 XYZ under D65 and
``values @ rgb_weights(edges)`` linear sRGB (D65 white), both normalised so that a spectrum of ones
has Y = 1. Data through ``colour-science``: the CIE 1931 2-degree observer (1 nm, 360-830 nm) and
CIE D65 (the CIE 5 nm table, linear to 1 nm; 785-830 nm, past colour's table, from the CIE daylight
series at D65's CCT, which matches the table to 8e-6), integrated over each bin at 1 nm resolution
(the exact integral of the 1 nm linear interpolant). sRGB: colour's ``RGB_COLOURSPACES["sRGB"].matrix_XYZ_to_RGB`` (IEC 61966-2-1).
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any

import numpy as np

from goniometer.spectral.spectrum import RANGE_NM, SpectrumError

#: wavelength bins of a spectral run unless configured
DEFAULT_BINS = 30


@lru_cache(maxsize=1)
def _xyz_to_linear_srgb() -> np.ndarray:
    import colour  # imported on first use: ``import colour`` takes seconds

    matrix = np.array(colour.RGB_COLOURSPACES["sRGB"].matrix_XYZ_to_RGB, dtype=np.float64)
    matrix.flags.writeable = False
    return matrix


def __getattr__(name: str) -> Any:
    # XYZ_TO_LINEAR_SRGB: the matrix from CIE XYZ to linear sRGB (rows R, G, B), colour's sRGB
    # colourspace (IEC 61966-2-1), read-only; loaded on first use
    if name == "XYZ_TO_LINEAR_SRGB":
        return _xyz_to_linear_srgb()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

_CMFS_NAME = "CIE 1931 2 Degree Standard Observer"


def wavelength_bins(n: int = DEFAULT_BINS) -> tuple[np.ndarray, np.ndarray]:
    """``(centres, edges)`` (nm) of ``n`` equal bins over :data:`RANGE_NM`; ``n`` a positive multiple of 3."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 3 or n % 3:
        raise SpectrumError(f"wavelength_bins = {n!r}: must be a positive multiple of 3 "
                            f"(each path carries three wavelengths)")
    edges = np.linspace(RANGE_NM[0], RANGE_NM[1], int(n) + 1)
    return 0.5 * (edges[:-1] + edges[1:]), edges


@lru_cache(maxsize=1)
def _observer_d65() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """1 nm grid over RANGE_NM, D65 there, and D65 * (xbar, ybar, zbar) there (shape (471, 3))."""
    import colour

    grid = np.arange(RANGE_NM[0], RANGE_NM[1] + 0.5, 1.0)
    cmfs = colour.MSDS_CMFS[_CMFS_NAME]
    cmf = np.array(cmfs[grid], dtype=np.float64)  # tabulated at 1 nm over exactly this range
    d65 = colour.SDS_ILLUMINANTS["D65"]
    # the CIE's D65 is the daylight series at CCT 6500 K * 1.4388 / 1.4380; colour tabulates it to 780 nm
    series = colour.sd_CIE_illuminant_D_series(colour.temperature.CCT_to_xy_CIE_D(6500.0 * 1.4388 / 1.4380))
    nodes = np.arange(300.0, 831.0, 5.0)
    table = np.where(nodes <= d65.wavelengths[-1],
                     np.interp(nodes, d65.wavelengths, d65.values),
                     np.interp(nodes, series.wavelengths, series.values))
    illuminant = np.interp(grid, nodes, table)
    return grid, illuminant, illuminant[:, None] * cmf


def _cumulative(grid: np.ndarray, f: np.ndarray, x: np.ndarray) -> np.ndarray:
    """The integral from grid[0] to x of the linear interpolant of ``f`` (rows on ``grid``, 1 nm)."""
    h = grid[1] - grid[0]
    nodes = np.concatenate([np.zeros((1,) + f.shape[1:]), np.cumsum(0.5 * h * (f[1:] + f[:-1]), axis=0)])
    i = np.clip(np.floor((x - grid[0]) / h).astype(int), 0, len(grid) - 2)
    t = np.clip(x - grid[i], 0.0, h)[:, None]
    return nodes[i] + f[i] * t + (f[i + 1] - f[i]) * t * t / (2.0 * h)


def _check_edges(edges_nm: np.ndarray) -> np.ndarray:
    edges = np.asarray(edges_nm, dtype=np.float64)
    lo, hi = RANGE_NM
    if (edges.ndim != 1 or len(edges) < 2 or not np.all(np.diff(edges) > 0)
            or edges[0] < lo * (1 - 1e-9) or edges[-1] > hi * (1 + 1e-9)):
        raise SpectrumError(f"edges_nm: must be increasing bin edges within {lo:g}-{hi:g} nm "
                            f"(got {np.array2string(edges, threshold=8)})")
    return np.clip(edges, lo, hi)


@lru_cache(maxsize=16)
def _xyz_weights(edges: tuple[float, ...]) -> np.ndarray:
    grid, _, f = _observer_d65()
    x = np.asarray(edges)
    total_y = _cumulative(grid, f, np.array([RANGE_NM[1]]))[0, 1]
    cumulative = _cumulative(grid, f, x)
    weights = np.diff(cumulative, axis=0) / total_y
    weights.flags.writeable = False
    return weights


def xyz_weights(edges_nm: np.ndarray) -> np.ndarray:
    """``(n_bins, 3)``: the integral of D65 * (xbar, ybar, zbar) over each bin / the integral of D65 * ybar
    over 360-830 nm, so ``values @ xyz_weights(edges)`` is XYZ with Y = 1 for a spectrum of ones."""
    return _xyz_weights(tuple(_check_edges(edges_nm)))


def rgb_weights(edges_nm: np.ndarray) -> np.ndarray:
    """``(n_bins, 3)`` = ``xyz_weights(edges) @ XYZ_TO_LINEAR_SRGB.T``: ``values @ rgb_weights`` is linear sRGB.

    A constant spectrum c gives RGB = c * (1, 1, 1) to within 1.7e-4 (360-830 nm; the matrix is the
    4-decimal IEC one, the white XYZ an integral at 1 nm): close enough that the matrix is not renormalised.
    """
    return xyz_weights(edges_nm) @ _xyz_to_linear_srgb().T


def _apply(values: np.ndarray, weights: np.ndarray, axis: int) -> np.ndarray:
    v = np.moveaxis(np.asarray(values, dtype=np.float64), axis, -1)
    if v.shape[-1] != weights.shape[0]:
        raise SpectrumError(f"values: axis {axis} has {v.shape[-1]} entries, the bins {weights.shape[0]}")
    return np.moveaxis(v @ weights, -1, axis)


def spectral_to_xyz(values: np.ndarray, edges_nm: np.ndarray, axis: int = -1) -> np.ndarray:
    """CIE XYZ (D65, Y = 1 for ones) of per-bin ``values``; the bin axis ``axis`` becomes the XYZ axis."""
    return _apply(values, xyz_weights(edges_nm), axis)


def spectral_to_rgb(values: np.ndarray, edges_nm: np.ndarray, axis: int = -1) -> np.ndarray:
    """Linear sRGB (D65 white) of per-bin ``values``; the bin axis ``axis`` becomes the RGB axis."""
    return _apply(values, rgb_weights(edges_nm), axis)


def combined_stderr(stderr: np.ndarray, weights: np.ndarray, groups: np.ndarray, axis: int = -1) -> np.ndarray:
    """The standard error of ``sum_b w_b x_b`` from the bins' standard errors ``stderr`` (bins on ``axis``).

    Bins sharing a group (``groups``: an int per bin; the paths they share) may be correlated in any
    way: their part is bounded by Cauchy-Schwarz, ``sum_b |w_b| sigma_b`` (exact when perfectly
    correlated); different groups are independent and add in quadrature. The result is a rigorous
    upper bound on the true standard error. ``weights`` is ``(n_bins,)`` or ``(n_bins, k)`` (e.g.
    :func:`rgb_weights`); with ``(n_bins, k)`` the bin axis becomes a k axis, with ``(n_bins,)`` it goes.
    """
    w = np.abs(np.asarray(weights, dtype=np.float64))
    vector = w.ndim == 1
    if vector:
        w = w[:, None]
    s = np.moveaxis(np.asarray(stderr, dtype=np.float64), axis, -1)
    g = np.asarray(groups)
    if g.shape != (w.shape[0],) or s.shape[-1] != w.shape[0]:
        raise SpectrumError(f"combined_stderr: {s.shape[-1]} bins of stderr, {w.shape[0]} of weights, "
                            f"groups of shape {g.shape}: they must agree")
    total = np.zeros(s.shape[:-1] + (w.shape[1],))
    for group in np.unique(g):
        mask = g == group
        total += (s[..., mask] @ w[mask]) ** 2
    out = np.sqrt(total)
    return out[..., 0] if vector else np.moveaxis(out, -1, axis)
