"""The RGB equivalent of a spectral field (``docs/spectral.md`` section 3): what an RGB run of a
spectral material traces and what the RGB models read.

A colour-like field (albedo, extinction, optical depth, a conductor's index) becomes the linear
sRGB (D65) of its spectrum taken as a reflectance spectrum -- the rule Mitsuba 3 applies to the
spectral data of its RGB variants -- clipped to the field's range; a dielectric's index becomes
one number, the luminance-weighted (D65, CIE 1931 y-bar) mean, which is the index itself for a
constant spectrum. The spectrum is sampled at 1 nm over 360-830 nm, held at its end values
beyond a table's range. The difference between the RGB of the spectral Fresnel and the Fresnel
of these RGB indices is what a spectral run measures and an RGB run cannot.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from goniometer.spectral.colorimetry import rgb_weights, xyz_weights
from goniometer.spectral.spectrum import RANGE_NM

__all__ = ["rgb_equivalent"]


@lru_cache(maxsize=1)
def _fine() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    lo, hi = RANGE_NM
    edges = np.arange(lo, hi + 0.5, 1.0)
    centres = 0.5 * (edges[1:] + edges[:-1])
    return centres, rgb_weights(edges), xyz_weights(edges)[:, 1]


def rgb_equivalent(spectrum, index: bool = False, lo: float = 0.0, hi: float | None = None) -> tuple[float, float, float]:
    """The RGB triple standing for ``spectrum`` (an object with ``at(wavelength_nm)``); ``index``:
    one luminance-weighted value for the three channels. Clipped to ``[lo, hi]``."""
    centres, w_rgb, w_y = _fine()
    if hasattr(spectrum, "wavelength_nm"):
        wl = np.clip(centres, spectrum.wavelength_nm[0], spectrum.wavelength_nm[-1])
    else:
        wl = centres
    v = np.asarray(spectrum.at(wl), dtype=np.float64)
    if index:
        y = float(v @ w_y / w_y.sum())
        out = np.array([y, y, y])
    else:
        out = v @ w_rgb
    out = np.maximum(out, lo)
    if hi is not None:
        out = np.minimum(out, hi)
    return (float(out[0]), float(out[1]), float(out[2]))
