"""The Belcour statistics as data, for the inverse method and inspection: :func:`stack_statistics`
(per-lobe energies and variances and the stack's accumulated R0N, T0N, RN0, TN0 statistics, Bati
2021 notation) and :func:`lobe_statistics` (energy and roughness per lobe), RGB."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from goniometer.stack import Stack
from models.belcour.adding import run_adding_doubling
from models.belcour.covariance import variance_to_roughness
from models.belcour.options import BelcourOptions, resolve_options
from models.belcour.packing import pack_stack


@dataclass(frozen=True)
class BelcourLobe:
    """One GGX lobe: RGB energy (albedo, Fresnel included), RGB variance and roughness ``f^-1``."""

    energy: np.ndarray
    variance: np.ndarray
    alpha: np.ndarray


@dataclass(frozen=True)
class StackStatistics:
    """Result of the adding-doubling for one incidence cosine (§6; Bati 2021 notation).

    ``lobes[k]`` belongs to interface k. ``R0N``/``T0N``: reflectance/transmittance of the whole
    stack lit from above; ``RN0``/``TN0``: lit from below (inside the bottom medium); ``vR0N`` etc.
    their normalised variances (RGB); ``J0N``/``JN0`` the products of the variance Jacobians;
    ``cos_bottom`` the mean cosine in the last medium reached (below a transmitting stack, above a
    conductor; -1 after total internal reflection at the mean). Everything is RGB except the
    Jacobians and the cosine (angular quantities use the mean index).
    """

    lobes: list[BelcourLobe]
    R0N: np.ndarray
    T0N: np.ndarray
    RN0: np.ndarray
    TN0: np.ndarray
    vR0N: np.ndarray
    vT0N: np.ndarray
    vRN0: np.ndarray
    vTN0: np.ndarray
    J0N: float
    JN0: float
    cos_bottom: float


def stack_statistics(stack: Stack, cos_theta: float, options: BelcourOptions | None = None,
                     **kwargs) -> StackStatistics:
    """Per-lobe energies and variances (and the stack's total statistics) at incidence ``cos_theta``
    (cosine in the ambient medium, air). Options as :class:`BelcourOptions` (or keyword arguments)."""
    opts = resolve_options(options, kwargs)
    packed = pack_stack(stack, opts)
    r = run_adding_doubling(packed, cos_theta, opts)
    V = r.covariance[:, :, 0]
    lobes = [BelcourLobe(r.energy[k].copy(), V[k].copy(), np.array([variance_to_roughness(x) for x in V[k]]))
             for k in range(packed.n_lobes)]
    return StackStatistics(lobes, r.R0N, r.T0N, r.RN0, r.TN0, r.cov_R0N[:, 0].copy(), r.cov_T0N[:, 0].copy(),
                           r.cov_RN0[:, 0].copy(), r.cov_TN0[:, 0].copy(), r.J0N, r.JN0, r.cos_bottom)


def lobe_statistics(stack: Stack, cos_theta: float, options: BelcourOptions | None = None,
                    **kwargs) -> list[tuple[np.ndarray, np.ndarray]]:
    """``[(energy_rgb, alpha_rgb), ...]``, one pair per interface (top first), at ``cos_theta``.

    ``alpha`` is ``f^-1`` of the lobe variance, per channel (equal channels with
    ``per_channel=False``), not clamped. See :func:`stack_statistics` for everything else.
    """
    s = stack_statistics(stack, cos_theta, options, **kwargs)
    return [(lobe.energy, lobe.alpha) for lobe in s.lobes]

