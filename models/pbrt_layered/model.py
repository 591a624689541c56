"""pbrt-v4's layered BSDF (``coateddiffuse`` / ``coatedconductor``) as model rows of the harness.

pbrt-v4 evaluates a coated material stochastically (Pharr, Jakob & Humphreys, *Physically Based
Rendering*, 4th ed., section 14.3 "Scattering from Layered Materials", after Guo et al. 2018,
"Position-free Monte Carlo simulation for arbitrary layered BSDFs"): ``f(wo, wi)`` is the coat's
own GGX reflection plus the mean of ``nsamples`` random walks through a one-dimensional layer, each
connected to the light at every base or medium vertex and weighted by multiple importance
sampling. :mod:`models.pbrt_layered.kernel` holds the walk; ``docs/pbrt-layered.md`` states the
algorithm in our words, the mapping of our stacks to pbrt's parameters, and its biases.

Rows:

* ``pbrt-layered`` (:class:`PBRTLayered`): pbrt's defaults, ``maxdepth = 10``, ``nsamples = 1``,
  its masking ``G = 1 / (1 + Lambda_o + Lambda_i)`` in the rough coat's transmission, its MIS
  weights as written (including the density the research notes found inconsistent), roughness
  remapping off (our alpha is pbrt's alpha), ``thickness`` = the medium's optical depth.
* ``pbrt-layered-converged`` (:class:`PBRTLayeredConverged`): the same estimator with deep walks
  and many samples (``maxdepth = 100``, ``nsamples = 64``): what pbrt's ``f`` converges to.
* ``pbrt-layered-fixed`` (:class:`PBRTLayeredFixed`): the converged row with the consistent density
  in the MIS weight of the base-sampled connection (a control, not pbrt).

The rows are stochastic: a direction pair's random stream is keyed by the pair, so the same
inputs give the same bits, and the value carries the standard error of each estimate
(``ModelValue.stderr_internal``; the top lobe is exact), which the harness integrates onto a
reference's cells and reports beside the reference's noise floor (``models.compare``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from goniometer.kernel.packing import BASE_CONDUCTOR, BASE_LAMBERTIAN
from goniometer.stack import Interface, Lambertian, Medium, Stack
from models.base import Model, ModelError, ModelValue, coated_base
from models.pbrt_layered import kernel as K

STRUCTURE = "[dielectric coat interface, optional medium, Lambertian or conductor base]"
#: pbrt's clamp of the Henyey-Greenstein asymmetry
G_CLAMP = 0.99


@dataclass(frozen=True)
class PBRTParameters:
    """The parameters pbrt-v4 would be given for one of our stacks (``docs/pbrt-layered.md``,
    mapping), per RGB channel where our stack has channels.

    ``material``: ``"coateddiffuse"`` or ``"coatedconductor"``; ``eta``: the coat's index
    (``eta`` / ``interface.eta``); ``alpha0``: the coat's roughness with ``remaproughness false``
    (our alpha); ``thickness``: the medium's optical depth (0 without a medium); ``albedo``
    (0 where the medium does not scatter) and ``g`` (clamped to +-0.99 as pbrt does);
    ``reflectance``: the Lambertian's; ``conductor_eta``/``conductor_k``: our absolute base index,
    which pbrt divides by the coat's eta (:attr:`relative_eta`, :attr:`relative_k`); ``alpha1``:
    the conductor's roughness.
    """

    material: str
    eta: float
    alpha0: float
    thickness: tuple[float, float, float]
    albedo: tuple[float, float, float]
    g: float
    reflectance: tuple[float, float, float] | None = None
    conductor_eta: tuple[float, float, float] | None = None
    conductor_k: tuple[float, float, float] | None = None
    alpha1: float | None = None

    @property
    def coat_smooth(self) -> bool:
        """pbrt's rule: an index of 1 or an alpha below 1e-3 is a perfectly smooth coat."""
        return self.eta == 1.0 or self.alpha0 < K.SMOOTH_ALPHA

    @property
    def base_smooth(self) -> bool:
        return self.material == "coatedconductor" and float(self.alpha1) < K.SMOOTH_ALPHA

    @property
    def relative_eta(self) -> np.ndarray | None:
        """The conductor's index relative to the coat (what pbrt's Fresnel uses)."""
        return None if self.conductor_eta is None else np.asarray(self.conductor_eta) / self.eta

    @property
    def relative_k(self) -> np.ndarray | None:
        return None if self.conductor_k is None else np.asarray(self.conductor_k) / self.eta

    def scene(self, channel: int, max_depth: int = 10, n_samples: int = 1) -> str:
        """The pbrt-v4 scene-file line of the material of one channel (pbrt is spectral; each of
        our RGB channels is its own constant-spectrum material)."""
        c = channel
        parts = [f'Material "{self.material}"']
        if self.material == "coateddiffuse":
            parts += [f'"float roughness" {self.alpha0!r}', f'"float eta" {self.eta!r}',
                      f'"rgb reflectance" [{self.reflectance[c]!r} {self.reflectance[c]!r} {self.reflectance[c]!r}]']
        else:
            parts += [f'"float interface.roughness" {self.alpha0!r}', f'"float interface.eta" {self.eta!r}',
                      f'"float conductor.roughness" {self.alpha1!r}',
                      f'"spectrum conductor.eta" {self.conductor_eta[c]!r}',
                      f'"spectrum conductor.k" {self.conductor_k[c]!r}']
        parts += [f'"float thickness" {self.thickness[c]!r}',
                  f'"rgb albedo" [{self.albedo[c]!r} {self.albedo[c]!r} {self.albedo[c]!r}]', f'"float g" {self.g!r}',
                  f'"integer maxdepth" {max_depth}', f'"integer nsamples" {n_samples}', '"bool remaproughness" false']
        return " ".join(parts)


def _kind(layer: object) -> str:
    if isinstance(layer, Interface):
        return "conductor interface" if layer.is_conductor else "dielectric interface"
    if isinstance(layer, Medium):
        return "medium"
    if isinstance(layer, Lambertian):
        return "Lambertian base"
    return type(layer).__name__


def support_reason(stack: Stack) -> str | None:
    """Why pbrt's coated materials cannot express ``stack`` (None if they can). Anisotropy is
    refused before (:meth:`models.base.Model.reason`)."""
    layers = list(stack.layers)
    kinds = ", ".join(_kind(x) for x in layers)
    if not layers or not isinstance(layers[0], Interface) or layers[0].is_conductor:
        return (f"pbrt's coateddiffuse/coatedconductor need a dielectric coat on top: {STRUCTURE}; "
                f"this stack is [{kinds}]")
    if len(layers) == 1:
        return f"a single interface has no base below a coat (pbrt's dielectric or conductor, not layered); needs {STRUCTURE}"
    cb = coated_base(stack)
    if cb is None:
        n_coats = sum(isinstance(x, Interface) and not x.is_conductor for x in layers)
        if n_coats > 1:
            return (f"{n_coats} dielectric interfaces: pbrt's LayeredBxDF has one coat over one base "
                    f"({STRUCTURE}); this stack is [{kinds}]")
        return f"needs exactly {STRUCTURE} (pbrt's LayeredBxDF has one medium at most); this stack is [{kinds}]"
    if cb.base == "dielectric":
        return ("a transmitting slab (dielectric base interface): pbrt's coated materials are opaque, with "
                f"a diffuse or conductor bottom; needs {STRUCTURE}")
    for i, x in enumerate(layers):
        if isinstance(x, Interface) and x.multiple_scattering:
            return (f"layers[{i}] scatters several times on its microsurface (multiple_scattering): pbrt's "
                    "dielectric and conductor BxDFs scatter once")
    return None


def pbrt_parameters(stack: Stack) -> PBRTParameters:
    """The pbrt-v4 parameters of a supported stack (:class:`ModelError` otherwise)."""
    reason = support_reason(stack)
    if reason is not None:
        raise ModelError(reason)
    layers = list(stack.layers)
    coat = layers[0]
    medium = layers[1] if isinstance(layers[1], Medium) else None
    base = layers[-1]
    tau = tuple(float(t) for t in medium.optical_depth) if medium is not None else (0.0, 0.0, 0.0)
    albedo = (0.0, 0.0, 0.0)
    g = 0.0
    if medium is not None and medium.scatters:
        albedo = tuple(float(a) if t > 0.0 else 0.0 for a, t in zip(medium.scattering_albedo, tau))
        g = float(min(G_CLAMP, max(-G_CLAMP, medium.g)))
    eta = float(coat.ior[0])
    if isinstance(base, Lambertian):
        return PBRTParameters("coateddiffuse", eta, float(coat.roughness), tau, albedo, g,
                              reflectance=tuple(float(r) for r in base.albedo))
    return PBRTParameters("coatedconductor", eta, float(coat.roughness), tau, albedo, g,
                          conductor_eta=tuple(float(x) for x in base.ior),
                          conductor_k=tuple(float(x) for x in base.extinction), alpha1=float(base.roughness))


@dataclass(frozen=True)
class Packed:
    """The kernel's arrays for one stack and one row (:mod:`models.pbrt_layered.kernel`)."""

    conf: np.ndarray
    real: np.ndarray
    chan: np.ndarray
    source: np.ndarray


def pack(p: PBRTParameters, max_depth: int, n_samples: int, fixed_mis: bool, exact_masking: bool,
         seed: int) -> Packed:
    """Pack ``p`` for the kernel: one walk group for the three channels, or one per channel when a
    scattering medium's optical depth differs between channels."""
    tau = np.asarray(p.thickness, dtype=np.float64)
    albedo = np.asarray(p.albedo, dtype=np.float64)
    if p.material == "coateddiffuse":
        kind = BASE_LAMBERTIAN
        rho = np.asarray(p.reflectance, dtype=np.float64)
        ce = np.ones(3)
        ck = np.zeros(3)
        alpha1 = 0.0
    else:
        kind = BASE_CONDUCTOR
        rho = np.zeros(3)
        ce = np.asarray(p.relative_eta, dtype=np.float64)
        ck = np.asarray(p.relative_k, dtype=np.float64)
        alpha1 = float(p.alpha1)
    rows = np.stack([tau, albedo, rho, ce, ck])            # (5, 3)
    per_channel = bool(np.any(albedo > 0.0)) and len(set(tau.tolist())) > 1
    if per_channel:
        chan = np.ascontiguousarray(np.repeat(rows.T[:, :, None], 3, axis=2))   # (3 groups, 5, 3 slots)
        source = np.array([0, 3, 6], dtype=np.int64)
    else:
        chan = np.ascontiguousarray(rows[None])
        source = np.array([0, 1, 2], dtype=np.int64)
    conf = np.array([max_depth, n_samples, int(fixed_mis), int(exact_masking), chan.shape[0], kind,
                     int(p.coat_smooth), int(p.base_smooth), seed], dtype=np.int64)
    real = np.array([p.eta, p.alpha0, alpha1, p.g], dtype=np.float64)
    return Packed(conf, real, chan, source)


class PBRTLayered(Model):
    """pbrt-v4's ``coateddiffuse``/``coatedconductor`` at its defaults (``maxdepth`` 10,
    ``nsamples`` 1), roughness remapping off: a stochastic estimate per direction pair.

    Options (the registry uses the class defaults): ``max_depth``, ``n_samples``; ``fixed_mis``
    weights the base- and phase-sampled connections with the density of the light-side strategy
    (``exit.PDF(wi, -w)``) instead of pbrt's ``exit.PDF(-w, wi)``; ``exact_transmission_masking``
    replaces pbrt's ``1 / (1 + Lambda_o + Lambda_i)`` in the coat's transmission by the
    height-correlated Beta function of our simulator (for quantifying that difference); ``seed``
    enters every direction pair's key (pbrt's ``--seed``, default 0).
    """

    name = "pbrt-layered"
    description = "pbrt-v4 LayeredBxDF (coateddiffuse/coatedconductor) at its defaults: maxdepth 10, nsamples 1"
    sides = ("brdf",)
    anisotropic = False
    scattering = True
    #: the estimate is random (per direction pair, deterministic): ``ModelValue.stderr_internal`` holds its noise
    stochastic = True
    max_depth_default = 10
    n_samples_default = 1
    fixed_mis_default = False

    def __init__(self, max_depth: int | None = None, n_samples: int | None = None, fixed_mis: bool | None = None,
                 exact_transmission_masking: bool = False, seed: int = 0) -> None:
        self.max_depth = int(self.max_depth_default if max_depth is None else max_depth)
        self.n_samples = int(self.n_samples_default if n_samples is None else n_samples)
        self.fixed_mis = bool(self.fixed_mis_default if fixed_mis is None else fixed_mis)
        self.exact_transmission_masking = bool(exact_transmission_masking)
        self.seed = int(seed)
        if self.max_depth < 1 or self.n_samples < 1:
            raise ValueError(f"{self.name}: max_depth and n_samples must be at least 1")
        if not 0 <= self.seed < 2**63:
            raise ValueError(f"{self.name}: seed must lie in [0, 2^63)")

    def support_reason(self, stack: Stack) -> str | None:
        return support_reason(stack)

    def cost_note(self, directions: int) -> str:
        """Its walks: ``max(n_samples, 2)`` per direction pair (with one sample, a second walk only
        estimates the noise), each of up to ``max_depth`` events, on the numba threads
        (``docs/pbrt-layered.md`` §6)."""
        import numba
        per = max(self.n_samples, 2)
        threads = numba.get_num_threads()
        return (f"stochastic: {per * directions:,} random walks ({per} per sub-cell direction, up to "
                f"{self.max_depth} events each) on {threads} thread{'s' if threads > 1 else ''}")

    def packed(self, stack: Stack) -> Packed:
        return pack(pbrt_parameters(stack), self.max_depth, self.n_samples, self.fixed_mis,
                    self.exact_transmission_masking, self.seed)

    def _evaluate(self, stack: Stack, l: np.ndarray, v: np.ndarray, side: str) -> ModelValue:
        p = self.packed(stack)
        shape = v.shape[:-1]
        vv = np.ascontiguousarray(v, dtype=np.float64).reshape(-1, 3)
        out = np.zeros((vv.shape[0], 9))
        K.evaluate_many(np.ascontiguousarray(l, dtype=np.float64), vv, p.conf, p.real, p.chan, p.source, out)
        # the top lobe is exact; the walk's own standard error is the internal part's
        return ModelValue(top=out[:, 0:3].reshape(shape + (3,)), internal=out[:, 3:6].reshape(shape + (3,)),
                          stderr_internal=out[:, 6:9].reshape(shape + (3,)))


class PBRTLayeredConverged(PBRTLayered):
    """pbrt's estimator as written, with deep walks and many samples (``maxdepth`` 100,
    ``nsamples`` 64): what pbrt's ``f`` converges to (its MIS bias included)."""

    name = "pbrt-layered-converged"
    description = "pbrt-v4 LayeredBxDF's f as written, converged: maxdepth 100, nsamples 64"
    max_depth_default = 100
    n_samples_default = 64
    #: "every model that applies" (a default evaluate, a report) leaves this row out: about 13
    #: CPU-minutes per database file; name it (--model pbrt-layered-converged) to evaluate it
    on_request = True

    def on_request_reason(self) -> str:
        return ("64 walks of depth up to 100 per sub-cell direction, about 900x belcour-fwd's cost "
                "per cell (docs/pbrt-layered.md section 6)")


class PBRTLayeredFixed(PBRTLayeredConverged):
    """A control, not pbrt: the converged row with the consistent density in the MIS weight of the
    connections sampled at the base or in the medium (``exit.PDF(wi, -w)``)."""

    name = "pbrt-layered-fixed"
    description = "control: pbrt-v4 LayeredBxDF converged, with the consistent MIS density (not pbrt)"
    fixed_mis_default = True


def built_in_models() -> list[Model]:
    """The rows the registry lists, in display order."""
    return [PBRTLayered(), PBRTLayeredConverged(), PBRTLayeredFixed()]
