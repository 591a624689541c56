"""``ggx-kulla-conty``: one GGX interface (conductor or dielectric) with the energy compensation of
Kulla & Conty 2017, or Turquin 2019's variant (:class:`GGXKullaConty`).

Sources: C. Kulla and A. Conty, "Revisiting Physically Based Shading at Imageworks", SIGGRAPH 2017
course *Physically Based Shading in Theory and Practice*, section "Energy compensation" (the
Kelemen & Szirmay-Kalos 2001 section 2.2 lobe, its Fresnel term, and its extension to
dielectrics); E. Turquin, "Practical multiple scattering compensation for microfacet models",
technical report, 2019 (the scaling ``1 + F0 (1 - E) / E`` of the single-scattering lobe, and its
dielectric form ``1 / E``). Our reading of both, every choice and what each conserves:
``docs/production-models.md`` ("ggx-kulla-conty").

Conventions (as :mod:`models.base`): ``l`` towards the light in air (``l_z > 0``), ``v`` towards
the viewer; values without the cosine factor, in 1/sr, RGB last; BTDF values flux based. The
single-scattering lobe is the Walter 2007 GGX BSDF of :mod:`goniometer.optics`; ``E(mu)`` and
``E_avg`` come from :mod:`models.tables.microfacet_albedo` (quadrature for the exact roughness and
index of the interface). The simulator counts a walk on a multiple-scattering microsurface as one
event (``docs/material-format.md``, "Counting"), so all light the interface reflects is bounce
order 1: ``top`` is the whole BRDF (single scattering + compensation) and ``internal`` is 0; for the
BTDF, ``internal`` is the whole BTDF (:meth:`GGXKullaConty.parts` gives the two terms apart).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from goniometer import optics
from goniometer.stack import Interface, Stack
from models.base import Model, ModelValue
from models.tables.microfacet_albedo import AlbedoTable, fresnel_average, load_albedo_table

COMPENSATIONS = ("kulla-conty", "turquin", "turquin-light")
#: below this lost energy ``1 - E_avg`` the compensation lobe is zero (the interface is smooth)
LOSS_FLOOR = 1e-12


@dataclass(frozen=True)
class KullaContyOptions:
    """``compensation``: ``"kulla-conty"`` (the added reciprocal lobe), ``"turquin"`` (scaling of
    the single-scattering lobe by the albedo at the view direction, as Turquin 2019 and renderers
    evaluate it) or ``"turquin-light"`` (the same scaling with the albedo at the light direction: the
    form whose directional albedo, as the goniometer measures it, is exactly 1); ``height_correlated``: Smith masking of the lobe and of its
    tables; ``cache_dir``: where the albedo tables live (None: ``$GONIOMETER_CACHE``)."""

    compensation: str = "kulla-conty"
    height_correlated: bool = False
    cache_dir: str | None = None

    def __post_init__(self) -> None:
        if self.compensation not in COMPENSATIONS:
            raise ValueError(f"compensation must be one of {', '.join(COMPENSATIONS)}, got {self.compensation!r}")


@dataclass(frozen=True)
class DielectricSplit:
    """Coefficients of Kulla-Conty's four dielectric compensation lobes, each
    ``k (1 - E_a(mu_l)) (1 - E_b(mu_v)) / pi`` with ``E_a`` the table of the side of the light and
    ``E_b`` that of the viewer: reflection from outside (``r_out``: ``E_out``, ``E_out``),
    transmission from outside (``t_out``: ``E_out``, ``E_in``), and the same from inside.
    "outside" is the side the stack's light comes from (relative index ``eta = n_in / n_out``)."""

    r_out: float
    t_out: float
    r_in: float
    t_in: float
    #: the fraction ``x`` of Kulla-Conty's split (transmitted share of the compensation from outside
    #: is ``(1 - F_avg_out) x``, from inside ``(1 - F_avg_in) (1 - x)``)
    x: float


def dielectric_split(eta: float, e_avg_out: float, e_avg_in: float, f_avg_out: float,
                     f_avg_in: float) -> DielectricSplit:
    """Kulla & Conty's split of the dielectric compensation between reflection and transmission.

    The lost energy ``1 - E(mu)`` of each side is shared between a reflected and a transmitted
    lobe; the transmitted shares are ``(1 - F_avg_out) x`` from outside and ``(1 - F_avg_in)
    (1 - x)`` from inside, and ``x`` is the one value that makes transmission reciprocal in our
    flux-based convention, ``f_t(out -> in) = eta^2 f_t(in -> out)``:
    ``x / (1 - x) = eta^2 (1 - F_avg_in) (1 - E_avg_in) / ((1 - F_avg_out) (1 - E_avg_out))``.
    Each side then loses nothing: ``k_r (1 - E_avg_same) + k_t (1 - E_avg_other) = 1``.
    A side without loss (``1 - E_avg < LOSS_FLOOR``) gives zero lobes.
    """
    loss_out = 1.0 - e_avg_out
    loss_in = 1.0 - e_avg_in
    if loss_out < LOSS_FLOOR or loss_in < LOSS_FLOOR:
        return DielectricSplit(0.0, 0.0, 0.0, 0.0, 0.0)
    q = eta * eta * (1.0 - f_avg_in) * loss_in / ((1.0 - f_avg_out) * loss_out)
    x = q / (1.0 + q)
    tau_out = (1.0 - f_avg_out) * x
    tau_in = (1.0 - f_avg_in) * (1.0 - x)
    return DielectricSplit(r_out=(1.0 - tau_out) / loss_out, t_out=tau_out / loss_in,
                           r_in=(1.0 - tau_in) / loss_in, t_in=tau_in / loss_out, x=x)


def conductor_fresnel_term(f_avg: float, e_avg: float) -> float:
    """Kulla & Conty's colour of the compensation lobe of a conductor,
    ``F_avg^2 E_avg / (1 - F_avg (1 - E_avg))``: the energy that survives the second and later
    bounces when each bounce keeps ``F_avg`` (1 when ``F_avg = 1``)."""
    return f_avg * f_avg * e_avg / (1.0 - f_avg * (1.0 - e_avg))


class GGXKullaConty(Model):
    """One GGX interface with Kulla & Conty 2017's energy compensation (Turquin 2019's as an option).

    Conductor: ``f = f_ss + F_ms (1 - E(mu_l)) (1 - E(mu_v)) / (pi (1 - E_avg))`` with ``E`` the
    albedo of the lobe with Fresnel 1 and ``F_ms`` :func:`conductor_fresnel_term` per channel.
    Dielectric: the same lobe shape for reflection and transmission, with ``E`` the single-scattering
    albedo (R + T) of each side and the reciprocal split of :func:`dielectric_split`.
    Turquin: ``f = f_ss (1 + F0 (1 - E(mu_v)) / E(mu_v))`` (conductor, ``F0`` the Fresnel factor at
    normal incidence) or ``f = f_ss / E(mu_v)`` (dielectric; ``E`` the albedo R + T of the viewer's
    side: outside for the BRDF, inside for the BTDF); ``turquin-light`` puts ``mu_l`` (and the
    outside table) in place of ``mu_v``. ``top`` is the
    whole BRDF, ``internal`` the whole BTDF (module docstring); :meth:`parts` separates the single
    scattering from the compensation. Options:
    :class:`KullaContyOptions`. Section references and choices: module docstring and
    ``docs/production-models.md``.
    """

    name = "ggx-kulla-conty"
    description = "one GGX conductor or dielectric interface with Kulla-Conty 2017 energy compensation"
    sides = ("brdf", "btdf")
    #: GGX, Fresnel and albedo tables of l, v and h only (Model.mirror_symmetric)
    mirror_symmetric = True

    def __init__(self, compensation: str = "kulla-conty", height_correlated: bool = False,
                 cache_dir: str | os.PathLike | None = None) -> None:
        self.options = KullaContyOptions(compensation, bool(height_correlated),
                                         None if cache_dir is None else os.fspath(cache_dir))

    def support_reason(self, stack: Stack) -> str | None:
        layers = stack.layers
        if len(layers) != 1 or not isinstance(layers[0], Interface):
            kinds = ", ".join(type(x).__name__.lower() for x in layers)
            return f"a single GGX interface only (this stack has {len(layers)} layers: {kinds})"
        x = layers[0]
        if not x.is_conductor and any(n == 1.0 for n in x.ior):
            return "an index-matched dielectric interface (ior 1) scatters nothing"
        return None

    # ----------------------------------------------------------------- tables

    def _table(self, kind: str, alpha: float, eta: float = 1.0) -> AlbedoTable:
        o = self.options
        return load_albedo_table(kind, alpha, eta, o.height_correlated, o.cache_dir)

    def parts(self, stack: Stack, l: np.ndarray, v: np.ndarray, side: str = "brdf") -> tuple[np.ndarray, np.ndarray]:
        """``(single, compensation)``, each ``v.shape[:-1] + (3,)``: the single-scattering lobe of
        :mod:`goniometer.optics` and the compensation (the added lobe; for Turquin the added part
        ``f - f_ss``). Their sum is the BRDF (``top``) or BTDF (``internal``) of :meth:`evaluate`.
        Raises :class:`models.base.ModelError` like :meth:`evaluate`."""
        self.evaluate(stack, l, np.zeros((0, 3)), side)  # the checks of Model.evaluate
        return self._terms(stack, np.asarray(l, dtype=np.float64).reshape(3), np.asarray(v, dtype=np.float64), side)

    def _evaluate(self, stack: Stack, l: np.ndarray, v: np.ndarray, side: str) -> ModelValue:
        single, compensation = self._terms(stack, l, v, side)
        total = single + compensation
        zero = np.zeros_like(total)
        return ModelValue(total, zero) if side == "brdf" else ModelValue(zero, total)

    def _terms(self, stack: Stack, l: np.ndarray, v: np.ndarray, side: str) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`parts` for checked inputs."""
        x: Interface = stack.layers[0]
        shape = v.shape[:-1] + (3,)
        single = np.zeros(shape)
        compensation = np.zeros(shape)
        alpha = float(x.roughness)
        if l[2] <= 0.0 or alpha <= 0.0:
            # a smooth interface is a Dirac lobe, which the model does not represent
            return single, compensation
        if x.is_conductor:
            if side == "brdf":
                self._conductor(x, l, v, single, compensation)
        else:
            self._dielectric(x, l, v, side, single, compensation)
        return single, compensation

    # both fill ``top`` with the single-scattering lobe and ``internal`` with the compensation
    def _conductor(self, x: Interface, l: np.ndarray, v: np.ndarray, top: np.ndarray, internal: np.ndarray) -> None:
        o = self.options
        alpha = float(x.roughness)
        table = self._table("white", alpha)
        up = v[..., 2] > 0.0
        e_l = float(table.at(l[2]))
        e_v = table.at(v[..., 2])
        for c, (eta, kappa) in enumerate(zip(x.ior, x.extinction)):
            f_ss = optics.np_microfacet_reflection(l[0], l[1], l[2], v[..., 0], v[..., 1], v[..., 2], alpha, alpha,
                                                   float(eta), float(kappa), o.height_correlated)
            top[..., c] = f_ss
            if o.compensation != "kulla-conty":
                f0 = optics.fresnel_conductor(1.0, float(eta), float(kappa))
                e = e_l if o.compensation == "turquin-light" else np.where(up, e_v, 1.0)
                internal[..., c] = f_ss * f0 * (1.0 - e) / e
                continue
            loss = 1.0 - table.e_avg
            if loss < LOSS_FLOOR:
                continue
            f_ms = conductor_fresnel_term(fresnel_average(float(eta), float(kappa)), table.e_avg)
            internal[..., c] = np.where(up, f_ms * (1.0 - e_l) * (1.0 - e_v) / (math.pi * loss), 0.0)

    def _dielectric(self, x: Interface, l: np.ndarray, v: np.ndarray, side: str, top: np.ndarray,
                    internal: np.ndarray) -> None:
        o = self.options
        alpha = float(x.roughness)
        for c, eta in enumerate(x.ior):
            eta = float(eta)
            out = self._table("dielectric", alpha, eta)
            e_l = float(out.at(l[2]))
            if side == "brdf":
                f_ss = optics.np_microfacet_reflection(l[0], l[1], l[2], v[..., 0], v[..., 1], v[..., 2], alpha,
                                                       alpha, eta, 0.0, o.height_correlated)
            else:
                f_ss = optics.np_microfacet_transmission(l[0], l[1], l[2], v[..., 0], v[..., 1], v[..., 2], alpha,
                                                         alpha, eta, o.height_correlated)
            top[..., c] = f_ss
            if o.compensation != "kulla-conty":
                if o.compensation == "turquin-light":
                    e = e_l
                else:   # the albedo of the side the viewer looks from
                    viewer = out if side == "brdf" else self._table("dielectric", alpha, 1.0 / eta)
                    e = np.maximum(viewer.at(np.abs(v[..., 2])), 1e-300)
                internal[..., c] = f_ss * (1.0 - e) / e
                continue
            inside = self._table("dielectric", alpha, 1.0 / eta)
            split = dielectric_split(eta, out.e_avg, inside.e_avg, fresnel_average(eta), fresnel_average(1.0 / eta))
            if side == "brdf":
                lobe = split.r_out * (1.0 - e_l) * (1.0 - out.at(v[..., 2])) / math.pi
                internal[..., c] = np.where(v[..., 2] > 0.0, lobe, 0.0)
            else:
                lobe = split.t_out * (1.0 - e_l) * (1.0 - inside.at(v[..., 2])) / math.pi
                internal[..., c] = np.where(v[..., 2] < 0.0, lobe, 0.0)
