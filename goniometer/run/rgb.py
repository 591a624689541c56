"""A spectral result in linear sRGB (``docs/spectral.md`` section 4): what
:meth:`goniometer.run.results.SimulationResult.rgb` returns."""

from __future__ import annotations

import dataclasses

import numpy as np

from goniometer.run.launches import bin_groups
from goniometer.stack import Stack

__all__ = ["to_rgb"]


def to_rgb(result):
    """A spectral result in linear sRGB (D65, CIE 1931 2-degree observer; ``docs/spectral.md``
    section 4): values, bounce orders, a polarized run's Mueller matrices and energies mapped
    linearly; standard errors by
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

    def side(sd):
        if sd is None:
            return None
        return dataclasses.replace(sd, value=lin(sd.value, 1), stderr=se(sd.stderr, 1), orders=lin(sd.orders, 2),
                                   stderr_internal=None if sd.stderr_internal is None else se(sd.stderr_internal, 1),
                                   mueller=None if sd.mueller is None else lin(sd.mueller, 1),
                                   mueller_stderr=None if sd.mueller_stderr is None else se(sd.mueller_stderr, 1))

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
