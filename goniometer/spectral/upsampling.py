"""RGB to spectrum: Mallett & Yuksel's spectral primary decomposition.

B. Mallett and C. Yuksel, "Spectral Primary Decomposition for Rendering with sRGB Reflectance",
EGSR 2019 (Eurographics Symposium on Rendering, DL-only track): value(lambda) = r B_r + g B_g + b B_b
with their three basis spectra, here ``colour.recovery.MSDS_BASIS_FUNCTIONS_sRGB_MALLETT2019``
(5 nm, 380-780 nm), linear between nodes and held at the end values (near-equal thirds) outside.

The published basis sums to 1 to within 1e-5 (max |sum - 1| = 9.98e-6); it is divided by its sum
so that it is a partition of unity, the upsampled value a convex combination (within the triple's
[min, max]). An equal triple (r == g == b) upsamples to exactly that constant, bit for bit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from goniometer.spectral.spectrum import SpectrumError


@lru_cache(maxsize=1)
def _basis() -> tuple[np.ndarray, np.ndarray]:
    from colour.recovery import MSDS_BASIS_FUNCTIONS_sRGB_MALLETT2019 as basis

    values = np.array(basis.values, dtype=np.float64)
    return np.array(basis.wavelengths, dtype=np.float64), values / values.sum(axis=1, keepdims=True)


def basis_at(wavelength_nm: np.ndarray | float) -> np.ndarray:
    """The (normalised) basis ``(B_r, B_g, B_b)`` at ``wavelength_nm``: shape ``wavelength_nm.shape + (3,)``."""
    nodes, values = _basis()
    lam = np.asarray(wavelength_nm, dtype=np.float64)
    return np.stack([np.interp(lam, nodes, values[:, j]) for j in range(3)], axis=-1)


def _triple(rgb: Any, where: str) -> tuple[float, float, float]:
    try:
        items = tuple(float(x) for x in rgb)
    except (TypeError, ValueError):
        raise SpectrumError(f"{where}: must be three finite numbers (got {rgb!r})") from None
    if len(items) != 3 or not all(math.isfinite(x) for x in items):
        raise SpectrumError(f"{where}: must be three finite numbers (got {rgb!r})")
    return items  # type: ignore[return-value]


def upsample_rgb(rgb: tuple[float, float, float], wavelength_nm: np.ndarray | float) -> np.ndarray:
    """The spectrum of a linear sRGB triple at ``wavelength_nm`` (float64, the input's shape)."""
    r, g, b = _triple(rgb, "rgb")
    lam = np.asarray(wavelength_nm, dtype=np.float64)
    if r == g == b:
        return np.full(lam.shape, r, dtype=np.float64)
    return basis_at(lam) @ np.array([r, g, b])


@dataclass(frozen=True)
class Upsampled:
    """An RGB value resolved spectrally through :func:`upsample_rgb` (the ``.at()`` interface of spectra)."""

    rgb: tuple[float, float, float]

    def __post_init__(self) -> None:
        object.__setattr__(self, "rgb", _triple(self.rgb, "Upsampled.rgb"))

    def covers(self, lo: float, hi: float) -> bool:
        return True

    def at(self, wavelength_nm: np.ndarray | float) -> np.ndarray:
        return upsample_rgb(self.rgb, wavelength_nm)

    def to_dict(self) -> dict[str, Any]:
        return {"rgb": list(self.rgb)}
