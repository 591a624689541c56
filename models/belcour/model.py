"""The Belcour 2018 models: ``belcour-fwd`` (:class:`BelcourForward`), ``belcour-sym``
(:class:`BelcourSymmetric`), ``belcour-bati19`` (:class:`BelcourBati19`), ``belcour-btdf``
(:class:`BelcourBTDF`) and the machinery they share with ``belcour-aniso`` (:class:`BelcourModel`).

Conventions (as :mod:`models.base`): ``l`` towards the light (``l_z > 0``); ``v`` towards the
viewer; values without cosine, in 1/sr, RGB last; ``top`` = lobe 0, ``internal`` = the others;
BTDF values are flux based (no ``(eta_0/eta_N)^2`` factor). The models, their choices and speed:
``docs/belcour.md``.
"""

from __future__ import annotations

import os

import numpy as np

from goniometer.stack import Stack
from models.base import Model, ModelValue
from models.belcour.adding import run_adding_doubling
from models.belcour.covariance import unit_azimuth, variance_to_roughness
from models.belcour.lobes import (ALPHA_EVAL_MIN, MODE_HALF, MODE_LIGHT, MODE_VIEW, eval_dynamic, eval_fixed, eval_grid,
                                  lobe_params, stats_grid)
from models.belcour.options import DIRECTION_GRID, BelcourOptions
from models.belcour.packing import BelcourPackedStack, pack_stack, unsupported_reason
from models.belcour.statistics import lobe_statistics


class BelcourModel(Model):
    """Machinery shared by the Belcour models (here and :class:`models.belcour.aniso.BelcourAniso`):
    options (``options_type(**options)``), support, per-instance memos of packed stacks and
    statistics grids, and the reflection evaluation. ``anisotropic`` (class attribute) selects the
    covariance form of :func:`pack_stack`; :meth:`_evaluate` is the forward model (statistics at
    ``omega_i`` = ``l`` or ``v`` as ``options.incident``; lobe 0 the exact top BRDF if ``top_exact``)."""

    options_type: type = BelcourOptions
    top_exact: bool = False
    #: on isotropic stacks: the adding of the lobes' statistics in cosines, GGX and Fresnel of l, v
    #: and h only (Model.mirror_symmetric; BelcourAniso too, whose azimuth tables are one azimuth
    #: on an isotropic stack)
    mirror_symmetric = True
    #: scattering media with g >= G_MIN (Belcour's forward-scattering operator; ``unsupported_reason``)
    scattering = True

    def __init__(self, **options) -> None:
        if options.get("cache_dir") is not None:
            options["cache_dir"] = os.fspath(options["cache_dir"])
        self.options = self.options_type(**options)
        self._packed: dict[Stack, BelcourPackedStack] = {}
        self._grids: dict[Stack, np.ndarray] = {}

    def support_reason(self, stack: Stack) -> str | None:
        return unsupported_reason(stack, self.anisotropic)

    def packed(self, stack: Stack) -> BelcourPackedStack:
        """The packed form of ``stack`` (memoised per model instance)."""
        p = self._packed.get(stack)
        if p is None:
            p = pack_stack(stack, self.options, self.anisotropic)
            self._packed[stack] = p
        return p

    def azimuth_nodes(self, packed: BelcourPackedStack) -> int:
        """Azimuth nodes of the statistics grid of a packed stack (1: isotropic statistics)."""
        return 1

    def _grid(self, stack: Stack) -> np.ndarray:
        """The :func:`stats_grid` table of ``stack`` (memoised per stack)."""
        g = self._grids.get(stack)
        if g is None:
            p = self.packed(stack)
            o = self.options
            g = stats_grid(o.direction_grid, self.azimuth_nodes(p), p.n_lobes, p.kernel_args(), o.per_channel,
                           o.use_tir, o.transmission_scale == "angular", o.transmitted_jacobian == "consistent")
            self._grids[stack] = g
        return g

    def _reflection(self, stack: Stack, l: np.ndarray, v: np.ndarray, mode: int, top_exact: bool) -> ModelValue:
        p = self.packed(stack)
        o = self.options
        l = np.ascontiguousarray(l, dtype=np.float64)
        shape = v.shape[:-1]
        vv = np.ascontiguousarray(v.reshape(-1, 3), dtype=np.float64)
        top = np.empty((vv.shape[0], 3))
        internal = np.empty((vv.shape[0], 3))
        top_alpha = max(float(p.alpha[0]), ALPHA_EVAL_MIN)
        if l[2] <= 0.0:
            top[:] = 0.0
            internal[:] = 0.0
        elif mode == MODE_LIGHT:
            r = run_adding_doubling(p, float(l[2]), o, unit_azimuth(float(l[0]), float(l[1])))
            P = np.zeros((p.n_lobes, 3, 5))
            lobe_params(r.energy, r.covariance, P, float(l[0]), float(l[1]), float(l[2]), 1 if top_exact else 0)
            eval_fixed(l, vv, 1.0, r.energy, P, o.height_correlated, top_exact, top_alpha, p.top_eta, p.top_kappa,
                       top, internal)
        elif o.direction_grid > 0:
            eval_grid(l, vv, mode, self._grid(stack), o.height_correlated, top_exact, top_alpha, p.top_eta,
                      p.top_kappa, top, internal)
        else:
            eval_dynamic(l, vv, mode, p.n_lobes, p.kernel_args(), o.per_channel, o.use_tir,
                         o.transmission_scale == "angular", o.transmitted_jacobian == "consistent", o.height_correlated, top_exact, top_alpha,
                         p.top_eta, p.top_kappa, top, internal)
        return ModelValue(top.reshape(shape + (3,)), internal.reshape(shape + (3,)))

    def _evaluate(self, stack: Stack, l: np.ndarray, v: np.ndarray, side: str) -> ModelValue:
        mode = MODE_LIGHT if self.options.incident == "light" else MODE_VIEW
        return self._reflection(stack, l, v, mode, self.top_exact)


class _BelcourBase(BelcourModel):
    """The isotropic models: scalar variances, :func:`lobe_statistics` with the model's options."""

    def lobe_statistics(self, stack: Stack, cos_theta: float) -> list[tuple[np.ndarray, np.ndarray]]:
        """:func:`lobe_statistics` with this model's options."""
        return lobe_statistics(stack, cos_theta, self.options)


class _ForwardBase(_BelcourBase):
    """The constructor of the isotropic forward models."""

    def __init__(self, incident: str = "light", use_tir: bool = False, transmission_scale: str = "normal",
                 per_channel: bool = True, height_correlated: bool = False, fgd_source: str = "material",
                 transmitted_jacobian: str = "reference",
                 cache_dir: str | os.PathLike | None = None, direction_grid: int = DIRECTION_GRID) -> None:
        super().__init__(incident=incident, use_tir=use_tir, transmission_scale=transmission_scale,
                         per_channel=per_channel, height_correlated=height_correlated, fgd_source=fgd_source,
                         transmitted_jacobian=transmitted_jacobian, cache_dir=cache_dir,
                         direction_grid=direction_grid)


class BelcourForward(_ForwardBase):
    """Belcour 2018, forward model (statistics for the incident direction; not reciprocal)."""

    name = "belcour-fwd"
    description = "Belcour 2018 forward model: GGX lobes from adding-doubling of statistics at omega_i.n"
    sides = ("brdf",)


class BelcourSymmetric(_BelcourBase):
    """Belcour 2018, symmetric model: statistics for c = |l.h| (reciprocal)."""

    name = "belcour-sym"
    description = "Belcour 2018 symmetric model: statistics from the half vector (reciprocal)"
    sides = ("brdf",)

    def __init__(self, use_tir: bool = False, transmission_scale: str = "normal", per_channel: bool = True,
                 height_correlated: bool = False, fgd_source: str = "material",
                 cache_dir: str | os.PathLike | None = None, direction_grid: int = DIRECTION_GRID) -> None:
        super().__init__(use_tir=use_tir, transmission_scale=transmission_scale, per_channel=per_channel,
                         height_correlated=height_correlated, fgd_source=fgd_source, cache_dir=cache_dir,
                         direction_grid=direction_grid)

    def _evaluate(self, stack: Stack, l: np.ndarray, v: np.ndarray, side: str) -> ModelValue:
        return self._reflection(stack, l, v, MODE_HALF, top_exact=False)


class BelcourBati19(_ForwardBase):
    """Bati 2019 eq. 6: exact top-interface microfacet BRDF + Belcour forward lobes k >= 1."""

    name = "belcour-bati19"
    description = "Belcour forward model with lobe 0 replaced by the exact top-interface BRDF (Bati 2019 eq. 6)"
    sides = ("brdf",)
    top_exact = True


class BelcourBTDF(_BelcourBase):
    """Belcour 2018 forward BTDF of slabs (``layered_dielectric``): one transmission lobe.

    The transmitted variance is carried down with the inverse of the Jacobian that brings
    reflected variances back up (``transmitted_jacobian="consistent"``, the default here): the
    published adding code multiplies by it both ways, which shrinks a lobe leaving glass into air
    instead of widening it (``docs/belcour.md``, "Jacobian bookkeeping"; ``"reference"`` restores it)."""

    name = "belcour-btdf"
    description = "Belcour 2018 forward BTDF for slabs: one GGX lobe about the Snell direction"
    sides = ("btdf",)

    def __init__(self, use_tir: bool = False, transmission_scale: str = "normal", per_channel: bool = True,
                 height_correlated: bool = False, fgd_source: str = "material",
                 transmitted_jacobian: str = "consistent",
                 cache_dir: str | os.PathLike | None = None) -> None:
        super().__init__(use_tir=use_tir, transmission_scale=transmission_scale, per_channel=per_channel,
                         height_correlated=height_correlated, fgd_source=fgd_source,
                         transmitted_jacobian=transmitted_jacobian, cache_dir=cache_dir)

    def support_reason(self, stack: Stack) -> str | None:
        reason = unsupported_reason(stack)
        if reason is not None:
            return reason
        if any(x.is_conductor for x in stack.interfaces):
            return "belcour-btdf models slabs only: every interface must be dielectric (kappa = 0)"
        if not stack.transmits:
            return "belcour-btdf needs a stack whose last layer is a dielectric interface (light exits below)"
        return None

    def transmission_lobe(self, stack: Stack, cos_theta: float) -> tuple[np.ndarray, np.ndarray, float]:
        """``(T0N_rgb, alpha_T_rgb, cos_N)``: energy, roughness (unclamped) and mean exit cosine."""
        r = run_adding_doubling(self.packed(stack), cos_theta, self.options)
        alpha = np.array([variance_to_roughness(x) for x in r.cov_T0N[:, 0]])
        return r.T0N, alpha, r.cos_bottom

    def _evaluate(self, stack: Stack, l: np.ndarray, v: np.ndarray, side: str) -> ModelValue:
        p = self.packed(stack)
        shape = v.shape[:-1]
        vv = np.ascontiguousarray(v.reshape(-1, 3), dtype=np.float64)
        out = np.zeros((vv.shape[0], 3))
        zero = np.zeros_like(out)
        if l[2] > 0.0:
            r = run_adding_doubling(p, float(l[2]), self.options)
            T, c_n = r.T0N, r.cos_bottom
            # Snell with the mean index through the whole stack (air above): the exit direction is
            # w_t = (-l_x / eta_N, -l_y / eta_N, -cos_N); the fake incident direction is its mirror.
            if c_n > 0.0 and np.any(T > 0.0):
                wi = np.array([l[0] / p.eta_exit, l[1] / p.eta_exit, c_n])
                wi /= np.linalg.norm(wi)
                # one lobe of energy T0N and variance vT0N (roughness clamped as every lobe)
                E = np.maximum(T, 0.0)[None, :]
                P = np.zeros((1, 3, 5))
                lobe_params(E, r.cov_T0N[None], P, float(wi[0]), float(wi[1]), float(wi[2]), 0)
                # the mirror trick of §8: the lobe about w_t is a reflection lobe about wi for the
                # mirrored views (v_x, v_y, -v_z); lobe 0 goes to ``out``, the other output is the
                # BTDF's zero top part
                eval_fixed(wi, vv, -1.0, E, P, self.options.height_correlated, False, ALPHA_EVAL_MIN, p.top_eta,
                           p.top_kappa, out, zero)
        return ModelValue(zero.reshape(shape + (3,)), out.reshape(shape + (3,)))
