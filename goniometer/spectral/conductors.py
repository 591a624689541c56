"""Named conductors: measured complex refractive indices ``eta + i k`` shipped as ``data/<Name>.csv``.

Each file has the columns ``wavelength_nm,eta,k`` under a ``#`` header stating its source (published
measurements, numbers from the refractiveindex.info database, CC0): Johnson & Christy 1972 for
Au, Ag and Cu (187.9-1937 nm), Rakic 1995 for Al. All cover the spectral range 360-830 nm.
"""

from __future__ import annotations

from functools import lru_cache
from importlib import resources

import numpy as np

from goniometer.spectral.spectrum import Spectrum, SpectrumError

_JOHNSON_CHRISTY = ("P. B. Johnson and R. W. Christy, Optical constants of the noble metals, "
                    "Phys. Rev. B 6, 4370 (1972), doi:10.1103/PhysRevB.6.4370 "
                    "(via refractiveindex.info, CC0)")

#: the citation each named conductor's spectra carry as ``source``
CITATIONS: dict[str, str] = {
    "Ag": _JOHNSON_CHRISTY,
    "Al": ("A. D. Rakic, Algorithm for the determination of intrinsic optical constants of metal films: "
           "application to aluminum, Appl. Opt. 34, 4755 (1995), doi:10.1364/AO.34.004755 "
           "(via refractiveindex.info, CC0)"),
    "Au": _JOHNSON_CHRISTY,
    "Cu": _JOHNSON_CHRISTY,
}

#: the conductors :func:`named_conductor` knows
NAMED_CONDUCTORS: tuple[str, ...] = tuple(sorted(CITATIONS))


@lru_cache(maxsize=None)
def _load(name: str) -> tuple[Spectrum, Spectrum]:
    text = resources.files("goniometer.spectral").joinpath("data", f"{name}.csv").read_text(encoding="utf-8")
    lines = [line for line in text.splitlines() if line.strip() and not line.startswith("#")]
    if lines[0].replace(" ", "") != "wavelength_nm,eta,k":
        raise SpectrumError(f"data/{name}.csv: the header must be wavelength_nm,eta,k (got {lines[0]!r})")
    table = np.array([[float(x) for x in line.split(",")] for line in lines[1:]], dtype=np.float64)
    wl, eta, k = table.T
    source = CITATIONS[name]
    return (Spectrum(tuple(wl), tuple(eta), f"{name} eta: {source}"),
            Spectrum(tuple(wl), tuple(k), f"{name} k: {source}"))


def named_conductor(name: str, where: str = "material") -> tuple[Spectrum, Spectrum]:
    """``(eta, k)`` of a named conductor (case-insensitive: ``"Au"``, ``"au"``), ``source`` the citation."""
    canonical = {n.lower(): n for n in NAMED_CONDUCTORS}.get(str(name).lower())
    if canonical is None:
        raise SpectrumError(f"{where}: unknown conductor {name!r} (known: {', '.join(NAMED_CONDUCTORS)})")
    return _load(canonical)
