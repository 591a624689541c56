"""Spectral data and the colour pipeline of spectral runs (360-830 nm; pure numpy).

* values: :class:`Spectrum` (tabulated, linear), :class:`Cauchy`, :class:`Sellmeier` and
  :class:`Upsampled` (an sRGB triple, Mallett & Yuksel 2019), each with ``at(wavelength_nm)``,
  ``covers(lo, hi)`` and ``to_dict()``; :func:`from_toml` reads the TOML tables;
* :func:`named_conductor` -- ``(eta, k)`` of Ag, Al, Au, Cu from published measurements (``data/*.csv``);
* :func:`wavelength_bins`, :func:`xyz_weights`, :func:`rgb_weights`, :func:`spectral_to_xyz`,
  :func:`spectral_to_rgb` (CIE 1931 2-degree observer, D65, linear sRGB) and :func:`combined_stderr`.

Wavelengths in nm throughout. ``colour-science`` is imported on first use of the colour functions.
"""

from __future__ import annotations

from typing import Any

from goniometer.spectral.colorimetry import (
    DEFAULT_BINS,
    combined_stderr,
    rgb_weights,
    spectral_to_rgb,
    spectral_to_xyz,
    wavelength_bins,
    xyz_weights,
)
from goniometer.spectral.conductors import NAMED_CONDUCTORS, named_conductor
from goniometer.spectral.spectrum import (
    RANGE_NM,
    Cauchy,
    Sellmeier,
    Spectral,
    Spectrum,
    SpectrumError,
    from_toml,
    is_spectral,
)
from goniometer.spectral.upsampling import Upsampled, upsample_rgb
from goniometer.spectral.equivalent import rgb_equivalent

__all__ = [
    "DEFAULT_BINS", "NAMED_CONDUCTORS", "RANGE_NM", "XYZ_TO_LINEAR_SRGB",
    "Cauchy", "Sellmeier", "Spectral", "Spectrum", "SpectrumError", "Upsampled",
    "combined_stderr", "from_toml", "is_spectral", "named_conductor", "rgb_equivalent", "rgb_weights",
    "spectral_to_rgb", "spectral_to_xyz", "upsample_rgb", "wavelength_bins", "xyz_weights",
]


def __getattr__(name: str) -> Any:
    if name == "XYZ_TO_LINEAR_SRGB":  # loaded on first use (it comes from colour-science)
        from goniometer.spectral import colorimetry

        return colorimetry.XYZ_TO_LINEAR_SRGB
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
