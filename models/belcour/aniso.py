"""Anisotropic Belcour model (``belcour-aniso``): Belcour 2018's forward model with a 2 x 2
covariance per statistic instead of a scalar variance, after Yamaguchi et al. 2019 (cited as Y19),
Belcour's adding-doubling otherwise unchanged (the kernels of :mod:`models.belcour.adding` and
:mod:`models.belcour.lobes` run with ``nq = 3`` covariance entries).

Conventions: as :mod:`models.base` (``l`` towards the light, ``l_z > 0``; ``v`` towards the viewer;
values without cosine in 1/sr, RGB last; ``top`` = lobe 0, ``internal`` = the other lobes).
Covariances live in the **macro tangent plane** (x towards phi = 0, y towards phi = 90 deg) and are
stored as their three distinct entries ``(xx, xy, yy)``; an interface's tangent frame is rotated by
``psi = rotation_deg`` about z (as the simulator, :mod:`goniometer.kernel.tracer`).

Equations, the choices where Y19 is vague (lobe GGX from a covariance, FGD lookup roughness of an
anisotropic interface, channels, the ``incident="view"`` table) and the reduction to
``belcour-fwd`` on isotropic stacks (to the last bit): ``docs/belcour.md``, "Anisotropic extension".
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from goniometer.stack import Interface, Stack
from models.belcour.adding import run_adding_doubling
from models.belcour.covariance import principal, unit_azimuth, variance_to_roughness
from models.belcour.model import BelcourModel
from models.belcour.options import DIRECTION_GRID, BelcourOptions, resolve_options
from models.belcour.packing import BelcourPackedStack, pack_stack

#: azimuth nodes on [0, pi) of the ``incident="view"`` statistics table (anisotropic stacks)
AZIMUTH_GRID = 128


# --------------------------------------------------------------------------- packing

def isotropic_proxy(stack: Stack, roughness: str = "x") -> Stack:
    """``stack`` with every interface made isotropic: roughness ``alpha_x`` (``"x"``) or the mean
    ``(alpha_x + alpha_y) / 2`` (``"mean"``); indices and everything else unchanged."""
    layers = []
    for layer in stack.layers:
        if isinstance(layer, Interface):
            ax, ay = layer.alpha_xy
            a = ax if roughness == "x" else 0.5 * (ax + ay)
            layer = Interface(a, layer.ior, layer.extinction)
        layers.append(layer)
    return Stack(stack.name, tuple(layers), stack.category)


def pack_aniso(stack: Stack, options: BelcourOptions = BelcourOptions()) -> BelcourPackedStack:
    """Flatten a supported (possibly anisotropic) stack with covariances ``(xx, xy, yy)``:
    :func:`models.belcour.packing.pack_stack` with ``anisotropic=True``."""
    return pack_stack(stack, options, anisotropic=True)


# --------------------------------------------------------------------------- public statistics

@dataclass(frozen=True)
class AnisoOptions(BelcourOptions):
    """:class:`models.belcour.options.BelcourOptions` plus the azimuth nodes of the ``incident="view"`` table."""

    azimuth_grid: int = AZIMUTH_GRID

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.azimuth_grid < 1:
            raise ValueError(f"azimuth_grid must be >= 1, got {self.azimuth_grid!r}")


@dataclass(frozen=True)
class AnisoLobe:
    """One anisotropic GGX lobe (per RGB channel): ``energy`` (3,), ``covariance`` (3, 2, 2) in the
    macro tangent plane, principal roughnesses ``alpha`` (3, 2) = ``h^-1`` of the eigenvalues (larger
    first, not clamped) and ``axis`` (3, 2) the unit principal direction of ``alpha[:, 0]``."""

    energy: np.ndarray
    covariance: np.ndarray
    alpha: np.ndarray
    axis: np.ndarray


@dataclass(frozen=True)
class AnisoStatistics:
    """Result of the adding-doubling for one incident direction: lobes (one per interface, top
    first), the stack's energies ``R0N``, ``T0N``, ``RN0``, ``TN0`` (RGB) and covariances ``SR0N``,
    ``ST0N``, ``SRN0``, ``STN0`` (3, 2, 2) (Bati 2021 notation), the Jacobian products and the mean
    cosine in the last medium reached (as :class:`models.belcour.statistics.StackStatistics`)."""

    lobes: list[AnisoLobe]
    R0N: np.ndarray
    T0N: np.ndarray
    RN0: np.ndarray
    TN0: np.ndarray
    SR0N: np.ndarray
    ST0N: np.ndarray
    SRN0: np.ndarray
    STN0: np.ndarray
    J0N: float
    JN0: float
    cos_bottom: float


def _matrices(c3: np.ndarray) -> np.ndarray:
    """(..., 3) entries (xx, xy, yy) -> (..., 2, 2) symmetric matrices."""
    out = np.empty(c3.shape[:-1] + (2, 2))
    out[..., 0, 0] = c3[..., 0]
    out[..., 0, 1] = c3[..., 1]
    out[..., 1, 0] = c3[..., 1]
    out[..., 1, 1] = c3[..., 2]
    return out


def _principal_rgb(c3: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    alpha = np.zeros((3, 2))
    axis = np.zeros((3, 2))
    for ch in range(3):
        xx, xy, yy = (float(x) for x in c3[ch])
        l1, l2, ex, ey = principal(xx, xy, yy)
        alpha[ch] = (variance_to_roughness(l1), variance_to_roughness(l2))
        axis[ch] = (ex, ey)
    return alpha, axis


def aniso_statistics(stack: Stack, omega_i, options: BelcourOptions | None = None, **kwargs) -> AnisoStatistics:
    """Lobe energies and covariances for the incident direction ``omega_i`` (unit, upper hemisphere;
    its azimuth matters for anisotropic stacks). Options as :class:`AnisoOptions` or keywords."""
    opts = resolve_options(options, kwargs, AnisoOptions)
    packed = pack_aniso(stack, opts)
    w = np.asarray(omega_i, dtype=float).reshape(3)
    r = run_adding_doubling(packed, float(w[2]), opts, unit_azimuth(float(w[0]), float(w[1])))
    lobes = []
    for k in range(packed.n_lobes):
        alpha, axis = _principal_rgb(r.covariance[k])
        lobes.append(AnisoLobe(r.energy[k].copy(), _matrices(r.covariance[k]), alpha, axis))
    return AnisoStatistics(lobes, r.R0N, r.T0N, r.RN0, r.TN0, _matrices(r.cov_R0N), _matrices(r.cov_T0N),
                           _matrices(r.cov_RN0), _matrices(r.cov_TN0), r.J0N, r.JN0, r.cos_bottom)


# --------------------------------------------------------------------------- model

class BelcourAniso(BelcourModel):
    """Belcour 2018 forward model with 2 x 2 covariances and anisotropic GGX lobes (Yamaguchi et al.
    2019). Options as :class:`models.belcour.model.BelcourForward` plus ``azimuth_grid``; evaluation by
    :class:`models.belcour.model.BelcourModel`."""

    name = "belcour-aniso"
    description = ("Anisotropic Belcour (Yamaguchi 2019): forward adding-doubling of 2x2 lobe covariances, "
                   "anisotropic GGX lobes")
    sides = ("brdf",)
    anisotropic = True
    options_type = AnisoOptions

    def __init__(self, incident: str = "light", use_tir: bool = False, transmission_scale: str = "normal",
                 per_channel: bool = True, height_correlated: bool = False, fgd_source: str = "material",
                 transmitted_jacobian: str = "reference",
                 cache_dir: str | os.PathLike | None = None, direction_grid: int = DIRECTION_GRID,
                 azimuth_grid: int = AZIMUTH_GRID) -> None:
        super().__init__(incident=incident, use_tir=use_tir, transmission_scale=transmission_scale,
                         per_channel=per_channel, height_correlated=height_correlated, fgd_source=fgd_source,
                         transmitted_jacobian=transmitted_jacobian, cache_dir=cache_dir,
                         direction_grid=direction_grid, azimuth_grid=azimuth_grid)

    def statistics(self, stack: Stack, omega_i) -> AnisoStatistics:
        """:func:`aniso_statistics` with this model's options."""
        return aniso_statistics(stack, omega_i, self.options)

    def azimuth_nodes(self, packed: BelcourPackedStack) -> int:
        """One azimuth for an isotropic stack (reproducing ``belcour-fwd`` exactly), else
        ``azimuth_grid``."""
        return 1 if packed.isotropic else self.options.azimuth_grid


__all__ = ["AZIMUTH_GRID", "AnisoLobe", "AnisoOptions", "AnisoStatistics", "BelcourAniso", "aniso_statistics",
           "isotropic_proxy", "pack_aniso"]
