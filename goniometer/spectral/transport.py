"""Spectral transport (``docs/spectral.md`` section 2): a spectral run as kernel launches that
each carry three wavelengths per path, and its reduction to linear sRGB.

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
from typing import Callable

import numpy as np

from goniometer.results import IncidentPart, SimulationResult, SliceData
from goniometer.settings import SimulationSettings
from goniometer.stack import Stack

__all__ = ["launches", "launch_stacks", "launch_seed", "trace_spectral_incident", "to_rgb", "bin_groups"]

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


def trace_spectral_incident(stack: Stack, settings: SimulationSettings, m: int,
                            progress: Callable[[int], None] | None = None,
                            buffers: tuple[np.ndarray, ...] | None = None) -> IncidentPart:
    """Incident direction ``m`` of a spectral run: every launch traced
    (:func:`goniometer.tasks.trace_incident`) and its channels placed in their bins."""
    from goniometer.tasks import trace_incident
    B = settings.wavelength_bins
    merged: IncidentPart | None = None
    for bins, st, s in launch_stacks(stack, settings):
        part = trace_incident(st, s, m, progress, buffers)
        if merged is None:
            merged = _empty(part, B)
        take = list(range(len(bins)))
        for name in ("brdf", "brdf_sq", "btdf", "btdf_sq"):
            a = getattr(part, name)
            if a is not None:
                getattr(merged, name)[:, list(bins)] = a[:, take]
        merged.energy[:, list(bins)] = part.energy[:, take]
        merged.energy_sq[:, list(bins)] = part.energy_sq[:, take]
        merged.counts += part.counts
        merged.elapsed_s += part.elapsed_s
    assert merged is not None
    return merged


def _empty(part: IncidentPart, B: int) -> IncidentPart:
    def widen(a: np.ndarray | None, axis: int) -> np.ndarray | None:
        if a is None:
            return None
        shape = list(a.shape)
        shape[axis] = B
        return np.zeros(shape, dtype=a.dtype)
    return IncidentPart(part.index, widen(part.brdf, 1), widen(part.brdf_sq, 1), widen(part.btdf, 1),
                        widen(part.btdf_sq, 1), widen(part.energy, 1), widen(part.energy_sq, 1),
                        np.zeros_like(part.counts), 0.0)


def to_rgb(result: SimulationResult) -> SimulationResult:
    """A spectral result in linear sRGB (D65, CIE 1931 2-degree observer; ``docs/spectral.md``
    section 4): values, bounce orders and energies mapped linearly; standard errors by
    :func:`goniometer.spectral.combined_stderr` over the launches (an upper bound: bins of one
    launch share paths). The stack is the material's RGB equivalent; the settings say RGB."""
    from goniometer.spectral import combined_stderr, rgb_weights, wavelength_bins
    s = result.settings
    edges = wavelength_bins(s.wavelength_bins)[1]
    W = rgb_weights(edges)                       # (B, 3)
    groups = bin_groups(result.stack, s)

    def lin(a: np.ndarray, axis: int) -> np.ndarray:
        return np.moveaxis(np.tensordot(np.moveaxis(a, axis, -1), W, axes=([-1], [0])), -1, axis)

    def se(a: np.ndarray, axis: int) -> np.ndarray:
        return combined_stderr(a, W, groups, axis=axis)

    def side(sd: SliceData | None) -> SliceData | None:
        if sd is None:
            return None
        return dataclasses.replace(sd, value=lin(sd.value, 1), stderr=se(sd.stderr, 1), orders=lin(sd.orders, 2),
                                   stderr_internal=None if sd.stderr_internal is None else se(sd.stderr_internal, 1))

    rgb_stack = Stack(result.stack.name, result.stack.layers, result.stack.category)
    return dataclasses.replace(
        result, stack=rgb_stack, settings=dataclasses.replace(s, spectral=False),
        brdf=side(result.brdf), btdf=side(result.btdf),
        energy={k: lin(v, 1) for k, v in result.energy.items()},
        energy_stderr={k: se(v, 1) for k, v in result.energy_stderr.items()},
        roulette=lin(result.roulette, 1), capped=lin(result.capped, 1),
        reflected_without_base=None if result.reflected_without_base is None else lin(result.reflected_without_base, 1),
        reflected_without_base_stderr=(None if result.reflected_without_base_stderr is None
                                       else se(result.reflected_without_base_stderr, 1)),
        extra={**result.extra, "from_spectral": {"wavelength_bins": s.wavelength_bins, "spectral_stack": result.stack.to_json()}})
