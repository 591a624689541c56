"""The launches of a spectral run (``docs/spectral.md`` section 2): kernel runs that each carry
three wavelengths per path (traced by :func:`goniometer.run.tasks.trace_spectral_incident`).

A run of ``B`` wavelength bins traces, per incident direction, the launches of
:func:`launches`: each is an ordinary three-channel run (same kernel, same bits rules) of the
stack evaluated at its three wavelengths (:meth:`goniometer.stack.Stack.at_wavelengths`), with
``rays`` paths; its three channels land in their bins. Bins ``k, k + B/3, k + 2B/3`` share a
launch (hero wavelengths spread over the range, Wilkie et al. 2014), so every bin is estimated
from ``rays`` paths. A stack whose dielectric index varies with wavelength is traced one
wavelength per launch (the three channels equal): its refracted directions differ per
wavelength, and a path can follow only one.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from goniometer.run.settings import SimulationSettings
from goniometer.stack import Stack

__all__ = ["launches", "launch_stacks", "launch_seed", "bin_groups"]

_GOLDEN = 0x9E3779B97F4A7C15
_MASK64 = (1 << 64) - 1


def launches(stack: Stack, settings: SimulationSettings) -> list[tuple[int, ...]]:
    """The wavelength bins each launch of a spectral run carries, in launch order: three bins
    ``(k, k + B/3, k + 2B/3)`` per launch, or one bin per launch for a dispersive stack."""
    from goniometer.spectral import wavelength_bins
    B = settings.wavelength_bins
    centres = wavelength_bins(B)[0]
    if stack.dispersive(centres):
        return [(b,) for b in range(B)]
    G = B // 3
    return [(k, k + G, k + 2 * G) for k in range(G)]


def bin_groups(stack: Stack, settings: SimulationSettings) -> np.ndarray:
    """Per bin, the launch that traced it (bins of one launch share their paths: their errors are
    correlated)."""
    out = np.zeros(settings.wavelength_bins, dtype=np.int64)
    for g, bins in enumerate(launches(stack, settings)):
        out[list(bins)] = g
    return out


def launch_seed(seed: int, launch: int) -> int:
    """The seed of launch ``launch`` of a run of seed ``seed`` (splitmix64 of the pair, 63 bits):
    every launch draws its own streams."""
    z = (seed + _GOLDEN * (launch + 1)) & _MASK64
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & _MASK64
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & _MASK64
    return (z ^ (z >> 31)) & ((1 << 63) - 1)


def launch_stacks(stack: Stack, settings: SimulationSettings) -> list[tuple[tuple[int, ...], Stack, SimulationSettings]]:
    """(bins, three-channel stack, settings) of every launch of a spectral run of ``stack``."""
    from goniometer.spectral import wavelength_bins
    centres = wavelength_bins(settings.wavelength_bins)[0]
    stack.check_covers(float(centres[0]), float(centres[-1]))
    out = []
    for g, bins in enumerate(launches(stack, settings)):
        wl = tuple(float(centres[b]) for b in (bins if len(bins) == 3 else bins * 3))
        s = dataclasses.replace(settings, spectral=False, seed=launch_seed(settings.seed, g))
        out.append((bins, stack.at_wavelengths(wl), s))
    return out
