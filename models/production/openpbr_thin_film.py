"""``openpbr-thin-film``: OpenPBR Surface's thin film on a metal or dielectric base, as the node
graph ``NG_open_pbr_surface_surfaceshader`` of ``open_pbr_surface.mtlx`` (MaterialX 1.39.5)
computes it (``docs/spectral.md`` section "Models"; ``docs/iridescence-models.md``).

Spec (OpenPBR 1.1, "Thin-film iridescence"): a clear film of thickness ``thin_film_thickness`` (um)
and index ``thin_film_ior`` on the base, coverage ``thin_film_weight``; it modulates the Fresnel
factor of the base's specular lobes (metal and dielectric; not the coat), computed by Airy theory
after Belcour & Barla 2017. The graph: ``thin_film_thickness_nm = 1000 thin_film_thickness``; the
metal ``generalized_schlick_bsdf`` (``color0 = base_weight base_color``, ``color82 =
specular_color``) and the dielectric ``dielectric_bsdf`` (``scatter_mode R``, ``ior =
modulated_eta_s``, which is ``specular_ior`` without a coat) each exist twice, with and without the
film inputs, mixed by ``thin_film_weight``. Both nodes evaluate their Fresnel by GLSL's
``mx_compute_fresnel`` -> ``mx_fresnel_airy`` (``pbrlib/genglsl/lib/mx_microfacet_specular.glsl``),
which this module implements literally (:func:`mx_fresnel_airy`):

* air (``eta1 = 1``) above, ``eta2 = max(thin_film_ior, 1)``, ``cos_t`` in the film;
* ``R12`` the polarised dielectric Fresnel at ``cos_theta`` (1 past total reflection);
* the base: dielectric: ``eta3 = ior``, ``kappa3 = 0``, ``R23`` the polarised conductor formula at
  ``cos_t`` for ``eta3 / eta2``, phases of ``mx_fresnel_conductor_phase_polarized``;
  metal (Schlick model): ``eta3 = (1 + sqrt F0) / (1 - sqrt F0)`` (F0 clamped to [0.01, 0.99]),
  ``kappa3 = 0``, **``R23 = F82(cos_t) / 2`` in each polarisation** (as the GLSL code does), phases
  ``pi`` where ``eta3 < eta2``, else 0;
* ``phi21 = (0 if cos_theta < cos(atan eta2) else pi, pi)`` (p, s);
* per polarisation ``I += R12 + Rs + sum_{m=1}^{2} C_m 2 S(m OPD, m (phi23 + phi21))`` with
  ``Rs = T121^2 R23 / (1 - R12 R23)``, ``C_m = (Rs - T121) (R12 R23)^(m/2)``,
  ``OPD = 2 eta2 cos_t d``, ``S`` Belcour & Barla's Gaussian sensitivities
  (:func:`models.iridescence.sensitivity`, ``mx_eval_sensitivity``); ``AIRY_FRESNEL_ITERATIONS = 2``
  (MaterialX's default, ``GenOptions::hwAiryFresnelIterations``); the RGB channel c of the base's
  amplitudes is paired with XYZ component c, as in the GLSL code;
* ``I / 2`` through MaterialX's ``XYZ_TO_RGB`` (CIE 1931 RGB, equal-energy white), clamped to
  [0, 1].

The lobe: ``f = F D G2 / (4 |n.l| |n.v|)`` with GGX ``D``, height-correlated Smith ``G2``
(``mx_ggx_smith_G2``), ``alpha = specular_roughness**2``; as in ``openpbr-coat`` the GLSL-only
energy compensation (``mx_ggx_energy_compensation``) is not in the formula. The dielectric's
transmitted substrate adds nothing to the BRDF. Thickness 0 (``fd.airy`` false) gives the bare
lobes: the F82-tint metal, the exact dielectric Fresnel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from goniometer.optics import np_fresnel_dielectric
from goniometer.stack import Stack
from models.base import Model, ModelValue
from models.iridescence import ggx_geometry, sensitivity, single_film_reason
from models.production.fresnel import f82_tint_from_ior

RGB = tuple[float, float, float]

#: MaterialX's XYZ_TO_RGB of mx_fresnel_airy (rows R, G, B: the GLSL mat3 is column-major)
MX_XYZ_TO_RGB = np.array([[2.3706743, -0.9000405, -0.4706338],
                          [-0.5138850, 1.4253036, 0.0885814],
                          [0.0052982, -0.0146949, 1.0093968]])
#: MaterialX's default number of Airy harmonics (``AIRY_FRESNEL_ITERATIONS``)
AIRY_FRESNEL_ITERATIONS = 2

#: the OpenPBR inputs a filmed interface sets (the others keep their defaults)
THIN_FILM_INPUTS: dict[str, str] = {
    "thin_film_weight": "1 (the interface carries a film)",
    "thin_film_thickness": "film.thickness_nm / 1000 (um; the graph multiplies by 1000 again)",
    "thin_film_ior": "film.ior (one value: the Rec. 709 luminance-weighted mean of the RGB triple)",
    "base_metalness": "1 for a conductor, 0 for a dielectric",
    "base_weight": "1",
    "base_color": "conductor: F(0 deg) in air (F82-tint map of openpbr-coat)",
    "specular_color": "conductor: F(1/7) / Schlick(1/7) (F82-tint); dielectric: 1",
    "specular_weight": "1",
    "specular_ior": "dielectric: the interface's ior",
    "specular_roughness": "sqrt(alpha) of the interface",
    "transmission_weight": "dielectric: 1 (the slab transmits; its BRDF is the specular lobe)",
    "coat_weight": "0",
}

_LUMA = np.array([0.2126, 0.7152, 0.0722])


@dataclass(frozen=True)
class ThinFilmParameters:
    base_metalness: float
    base_color: RGB
    specular_color: RGB
    specular_ior: float
    specular_roughness: float
    thin_film_weight: float
    thin_film_thickness: float  # um
    thin_film_ior: float


def thin_film_parameters(stack: Stack) -> ThinFilmParameters:
    x = stack.layers[0]
    film = x.film
    tf = dict(thin_film_weight=1.0, thin_film_thickness=float(film.thickness_nm) / 1000.0,
              thin_film_ior=float(_LUMA @ np.asarray(film.ior, dtype=float)),
              specular_roughness=math.sqrt(float(x.roughness)))
    if x.is_conductor:
        f0, tint = f82_tint_from_ior(x.ior, x.extinction)
        return ThinFilmParameters(base_metalness=1.0, base_color=tuple(f0.tolist()),
                                  specular_color=tuple(tint.tolist()), specular_ior=1.5, **tf)
    return ThinFilmParameters(base_metalness=0.0, base_color=(0.8, 0.8, 0.8), specular_color=(1.0, 1.0, 1.0),
                              specular_ior=float(x.ior[0]), **tf)


def _dielectric_polarized(c, ior):
    """``mx_fresnel_dielectric_polarized``: ``(Rp, Rs)``."""
    c2 = np.clip(c, 0.0, 1.0) ** 2
    s2 = 1.0 - c2
    t0 = np.maximum(ior * ior - s2, 0.0)
    t1 = t0 + c2
    t2 = 2.0 * np.sqrt(t0) * c
    rs = (t1 - t2) / (t1 + t2)
    t3 = c2 * t0 + s2 * s2
    t4 = t2 * s2
    return rs * (t3 - t4) / (t3 + t4), rs


def _conductor_polarized(c, n, k):
    """``mx_fresnel_conductor_polarized``: ``(Rp, Rs)``."""
    c2 = np.clip(c, 0.0, 1.0) ** 2
    s2 = 1.0 - c2
    n2, k2 = n * n, k * k
    t0 = n2 - k2 - s2
    ab = np.sqrt(t0 * t0 + 4.0 * n2 * k2)
    t1 = ab + c2
    a = np.sqrt(np.maximum(0.5 * (ab + t0), 0.0))
    t2 = 2.0 * a * c
    rs = (t1 - t2) / (t1 + t2)
    t3 = c2 * ab + s2 * s2
    t4 = t2 * s2
    return rs * (t3 - t4) / (t3 + t4), rs


def _conductor_phase_polarized(c, eta1, eta2, kappa2):
    """``mx_fresnel_conductor_phase_polarized``: ``(phiP, phiS)``."""
    k2 = kappa2 / eta2
    s2 = 1.0 - c * c
    A = eta2 * eta2 * (1.0 - k2 * k2) - eta1 * eta1 * s2
    B = np.sqrt(A * A + (2.0 * eta2 * eta2 * k2) ** 2)
    U = np.sqrt((A + B) / 2.0)
    V = np.maximum(0.0, np.sqrt(np.maximum((B - A) / 2.0, 0.0)))
    phi_s = np.arctan2(2.0 * eta1 * V * c, U * U + V * V - (eta1 * c) ** 2)
    phi_p = np.arctan2(2.0 * eta1 * eta2 * eta2 * c * (2.0 * k2 * U - (1.0 - k2 * k2) * V),
                       (eta2 * eta2 * (1.0 + k2 * k2) * c) ** 2 - eta1 * eta1 * (U * U + V * V))
    return phi_p, phi_s


def _hoffman_schlick(c, f0, f82, f90=1.0, exponent=5.0):
    """``mx_fresnel_hoffman_schlick`` (the F82-tint curve for ``f90 = 1``, exponent 5)."""
    mb = 1.0 / 7.0
    factor = 1.0 / (mb * (1.0 - mb) ** 6)
    x = np.clip(c, 0.0, 1.0)
    a = (f0 + (f90 - f0) * (1.0 - mb) ** exponent) * (1.0 - f82) * factor
    return f0 + (f90 - f0) * (1.0 - x) ** exponent - a * x * (1.0 - x) ** 6


def mx_fresnel_airy(cos_theta: np.ndarray, p: ThinFilmParameters, iterations: int = AIRY_FRESNEL_ITERATIONS
                    ) -> np.ndarray:
    """``(..., 3)``: MaterialX's ``mx_fresnel_airy`` for the metal (``base_metalness`` 1, Schlick
    model) or dielectric lobe of ``p`` at ``cos_theta = v.h`` (module docstring)."""
    c = np.asarray(cos_theta, dtype=np.float64)[..., None]
    schlick = p.base_metalness == 1.0
    f0 = np.asarray(p.base_color, dtype=np.float64)
    f82 = np.asarray(p.specular_color, dtype=np.float64)
    eta1 = 1.0
    eta2 = max(p.thin_film_ior, eta1)
    if schlick:
        sq = np.sqrt(np.clip(f0, 0.01, 0.99))
        eta3 = (1.0 + sq) / (1.0 - sq)
    else:
        eta3 = np.full(3, p.specular_ior)
    kappa3 = np.zeros(3)
    cos_t = np.sqrt(np.maximum(1.0 - (1.0 - c * c) * (eta1 / eta2) ** 2, 0.0))
    r12p, r12s = _dielectric_polarized(c, eta2 / eta1)
    r12p = np.where(cos_t <= 0.0, 1.0, r12p)
    r12s = np.where(cos_t <= 0.0, 1.0, r12s)
    t121p, t121s = 1.0 - r12p, 1.0 - r12s
    if schlick:
        f = _hoffman_schlick(cos_t, f0, f82)
        r23p = r23s = 0.5 * f
        phi23p = np.broadcast_to(np.where(eta3 < eta2, np.pi, 0.0), f.shape)
        phi23s = phi23p
    else:
        r23p, r23s = _conductor_polarized(cos_t, eta3 / eta2, kappa3 / eta2)
        phi23p, phi23s = _conductor_phase_polarized(cos_t, eta2, eta3, kappa3)
    cos_b = math.cos(math.atan(eta2 / eta1))
    phi21p = np.where(c < cos_b, 0.0, np.pi)
    phi21s = np.pi
    r123p = np.maximum(np.sqrt(r12p * r23p), 0.0)
    r123s = np.maximum(np.sqrt(r12s * r23s), 0.0)
    opd = 2.0 * eta2 * cos_t * (p.thin_film_thickness * 1000.0 * 1e-9)
    out = np.zeros(np.broadcast(c, r23p).shape)
    opd = np.broadcast_to(opd, out.shape)
    for r12, t121, r23, r123, phi in ((r12p, t121p, r23p, r123p, phi23p + phi21p),
                                      (r12s, t121s, r23s, r123s, phi23s + phi21s)):
        rs = t121 * t121 * r23 / (1.0 - r12 * r23)
        out = out + r12 + rs
        cm = rs - t121
        for m in range(1, iterations + 1):
            cm = cm * r123
            # XYZ component j paired with RGB channel j of the amplitudes (as the GLSL vec3 code)
            phi_m = np.broadcast_to(phi, out.shape)
            sm = 2.0 * np.stack([sensitivity(m * opd[..., j], m * phi_m[..., j])[..., j] for j in range(3)], axis=-1)
            out = out + cm * sm
    out = 0.5 * out
    return np.clip(out @ MX_XYZ_TO_RGB.T, 0.0, 1.0)


def openpbr_fresnel(cos_theta: np.ndarray, p: ThinFilmParameters) -> np.ndarray:
    """The Fresnel factor of the lobe: ``thin_film_weight`` mixes the film's ``mx_fresnel_airy``
    and the bare lobe's (F82-tint metal or exact dielectric); thickness 0 is the bare lobe."""
    c = np.asarray(cos_theta, dtype=np.float64)
    if p.base_metalness == 1.0:
        bare = _hoffman_schlick(c[..., None], np.asarray(p.base_color), np.asarray(p.specular_color))
    else:
        bare = np.repeat(np.asarray(np_fresnel_dielectric(np.clip(c, 0.0, 1.0), p.specular_ior))[..., None], 3,
                         axis=-1) * np.asarray(p.specular_color)
    if p.thin_film_thickness <= 0.0 or p.thin_film_weight == 0.0:
        return bare
    film = mx_fresnel_airy(c, p)
    if p.base_metalness != 1.0:
        film = film * np.asarray(p.specular_color)
    w = p.thin_film_weight
    return w * film + (1.0 - w) * bare


class OpenPBRThinFilm(Model):
    """OpenPBR Surface's thin film (MaterialX 1.39.5 graph and ``mx_fresnel_airy``; module docstring).

    ``height_correlated``: Smith G2 form (MaterialX's ``mx_ggx_smith_G2`` is height-correlated)."""

    name = "openpbr-thin-film"
    description = ("OpenPBR Surface thin film (MaterialX 1.39.5 graph, mx_fresnel_airy with 2 harmonics): "
                   "F82-tint metal or dielectric GGX lobe with an iridescent Fresnel")
    sides = ("brdf",)
    #: the model is of filmed interfaces (Model.films)
    films = True
    #: GGX and the film's Airy Fresnel of l, v and h only (Model.mirror_symmetric)
    mirror_symmetric = True

    def __init__(self, height_correlated: bool = True) -> None:
        self.height_correlated = bool(height_correlated)

    def support_reason(self, stack: Stack) -> str | None:
        return single_film_reason(stack, "OpenPBR")

    def _evaluate(self, stack: Stack, l: np.ndarray, v: np.ndarray, side: str) -> ModelValue:
        p = thin_film_parameters(stack)
        lh, geo = ggx_geometry(l, v, p.specular_roughness ** 2, self.height_correlated)
        top = openpbr_fresnel(lh, p) * geo[..., None]
        return ModelValue(top=top, internal=np.zeros_like(top))
