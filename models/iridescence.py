"""``belcour-iridescence``: Belcour & Barla 2017, "A Practical Extension to Microfacet Theory for the
Modeling of Varying Iridescence" (ACM TOG 36(4)), for one GGX interface carrying a thin film
(``docs/spectral.md`` section "Models"; formulas and measured errors: ``docs/iridescence-models.md``).

The BRDF is the single-scattering Cook-Torrance / Walter lobe of the bare interface with its
Fresnel factor replaced by the film's spectrally integrated Airy reflectance at the microfacet
cosine ``c = l.h``::

    f(l, v) = R_rgb(c) D(h) G2(l, v) / (4 |n.l| |n.v|)

``D`` is GGX, ``G2`` Smith's (separable by default, as the simulator's default masking;
``height_correlated=True`` for the height-correlated form), both from :mod:`goniometer.optics`.

**The film's reflectance as a Fourier series** (the paper's section 4). Air (index 1) above, a
clear film ``n2`` of thickness ``d``, the base ``n3 + i k3`` below. Per polarisation, with the
Airy amplitude ``r = (r12 + r23 E) / (1 + r12 r23 E)``, ``E = exp(i Delta)``,
``Delta = 2 pi OPD / lambda``, ``OPD = 2 n2 d cos theta_2``, and the amplitudes and phases the
film's (independent of the wavelength: constant indices), ``|r|^2`` is a Fourier series in
``Delta``::

    R(lambda) = R12 + T^2 R23 / (1 - R12 R23) + sum_{m>=1} 2 C_m cos(m Delta + m psi)
    C_m = (T^2 R23 / (1 - R12 R23) - T) (R12 R23)^(m/2),   T = 1 - R12,
    psi = phi21 + phi23 = arg(-r12) + arg(r23).

**Spectral integration in the Fourier domain.** The CIE XYZ value of ``R`` is
``R12 + ... `` times the sensitivities' integrals plus, per harmonic, the sensitivities' Fourier
transform at the path difference ``m OPD`` with the phase ``m psi``. Belcour & Barla fit the
sensitivities (as functions of the wavenumber ``1/lambda``) with Gaussians, whose transforms are
closed forms: :func:`sensitivity` (their fit's 4 Gaussians: 2 for x, 1 each for y and z; published
in the paper's supplemental material and reproduced in MaterialX's ``mx_eval_sensitivity``). The
series is summed until its terms fall below 1e-12 (at most :data:`MAX_TERMS` harmonics; the paper
truncates it at a few). XYZ (equal-energy white, the fit's normalisation by the integral of
ybar) goes to linear sRGB through the IEC sRGB matrix with a Bradford adaptation E -> D65,
renormalised so that a constant reflectance gives exactly the same value in R, G and B
(:data:`XYZ_E_TO_LINEAR_SRGB`); the reference's colour pipeline (D65, linear sRGB,
:func:`goniometer.spectral.rgb_weights`) is therefore matched exactly for grey spectra and up to
the fit's error for fringes (measured: ``docs/iridescence-models.md``).

**Channels.** The model reads the RGB-equivalent fields of the stack: channel c uses the film index
and the base index of channel c (the model is evaluated three times, each keeping its own channel);
for a grey base and a grey film (one value in all channels) this is the paper's model exactly.

Thickness 0 is the bare interface (the exact Fresnel term, as the simulator, which drops the film).
"""

from __future__ import annotations

import numpy as np

from goniometer.optics import np_fresnel_conductor, np_fresnel_dielectric, np_ggx_d, np_ggx_lambda
from goniometer.stack import Interface, Stack
from models.base import Model, ModelValue

__all__ = ["BelcourIridescence", "MAX_TERMS", "XYZ_E_TO_LINEAR_SRGB", "airy_fourier", "film_reflectance_rgb",
           "film_reflectance_xyz", "ggx_geometry", "sensitivity", "single_film_reason"]

#: Belcour & Barla's Gaussian fit of the CIE 1931 sensitivities in the wavenumber domain (m^-1):
#: per Gaussian (XYZ component, amplitude, mean wavenumber, variance)
_GAUSSIANS = ((0, 5.4856e-13, 1.6810e+06, 4.3278e+09),
              (1, 4.4201e-13, 1.7953e+06, 9.3046e+09),
              (2, 5.2481e-13, 2.2084e+06, 6.6121e+09),
              (0, 9.7470e-14, 2.2399e+06, 4.5282e+09))
#: the fit's normalisation: the integral of ybar over the wavelength, in m
_Y_INTEGRAL = 1.0685e-7

#: at most this many harmonics of the Airy series
MAX_TERMS = 400


def sensitivity(opd_m: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """``(..., 3)``: the XYZ sensitivities' Fourier transform at path difference ``opd_m`` (metres)
    and phase ``shift`` (radians), ``int s_c(nu) cos(2 pi opd nu + shift) dnu / int ybar``, from
    Belcour & Barla's Gaussian fit (closed form per Gaussian)."""
    phase = 2.0 * np.pi * np.asarray(opd_m, dtype=np.float64)
    shift = np.asarray(shift, dtype=np.float64)
    out = np.zeros(np.broadcast(phase, shift).shape + (3,))
    for c, val, pos, var in _GAUSSIANS:
        out[..., c] += val * np.sqrt(2.0 * np.pi * var) * np.cos(pos * phase + shift) * np.exp(-var * phase * phase)
    return out / _Y_INTEGRAL


def _xyz_e_to_srgb() -> np.ndarray:
    from goniometer.spectral import XYZ_TO_LINEAR_SRGB
    bradford = np.array([[0.8951, 0.2664, -0.1614], [-0.7502, 1.7135, 0.0367], [0.0389, -0.0685, 1.0296]])
    white_e = np.ones(3)
    white_d65 = np.array([0.95047, 1.0, 1.08883])
    cone = np.linalg.solve(bradford, np.diag((bradford @ white_d65) / (bradford @ white_e)) @ bradford)
    m = np.asarray(XYZ_TO_LINEAR_SRGB) @ cone
    grey = m @ sensitivity(np.zeros(()), np.zeros(()))
    return m / grey[:, None]


class _Lazy:
    value: np.ndarray | None = None


def xyz_e_to_linear_srgb() -> np.ndarray:
    """The 3 x 3 map of :func:`sensitivity`'s XYZ to linear sRGB (see the module docstring)."""
    if _Lazy.value is None:
        _Lazy.value = _xyz_e_to_srgb()
    return _Lazy.value


def __getattr__(name: str):
    if name == "XYZ_E_TO_LINEAR_SRGB":
        return xyz_e_to_linear_srgb()
    raise AttributeError(name)


def _q(n: np.ndarray, s2: np.ndarray) -> np.ndarray:
    """``n cos theta = sqrt(n^2 - s2)`` with ``Im >= 0`` (complex)."""
    q = np.sqrt(np.asarray(n, dtype=np.complex128) ** 2 - s2)
    return np.where(q.imag < 0.0, -q, q)


def airy_fourier(cos1: np.ndarray, n2, n3, k3):
    """The film's Fourier series per polarisation: ``(dc, c1, ratio, psi, cos2)`` with shape
    ``(2, ...)`` (s, p) but ``cos2``: ``R(Delta) = dc + sum_m 2 c1 ratio^(m-1) cos(m (Delta + psi))``
    (air above, clear film ``n2 >= 1``, base ``n3 + i k3``; ``cos2`` the film's cosine)."""
    c1 = np.clip(np.abs(np.asarray(cos1, dtype=np.float64)), 0.0, 1.0)
    n2 = np.asarray(n2, dtype=np.float64)
    s2 = 1.0 - c1 * c1
    q1 = c1.astype(np.complex128)
    q2 = _q(n2, s2)
    q3 = _q(np.asarray(n3, dtype=np.float64) + 1j * np.asarray(k3, dtype=np.float64), s2)
    a2 = (n2 + 0j) ** 2
    a3 = (np.asarray(n3, dtype=np.float64) + 1j * np.asarray(k3, dtype=np.float64)) ** 2
    r12 = np.stack([(q1 - q2) / (q1 + q2), (q2 - a2 * q1) / (q2 + a2 * q1)])
    r23 = np.stack([(q2 - q3) / (q2 + q3), (a2 * q3 - a3 * q2) / (a2 * q3 + a3 * q2)])
    R12 = np.abs(r12) ** 2
    R23 = np.abs(r23) ** 2
    T = 1.0 - R12
    body = T * T * R23 / np.maximum(1.0 - R12 * R23, 1e-300)
    ratio = np.sqrt(R12 * R23)
    c_1 = (body - T) * ratio
    psi = np.angle(-r12) + np.angle(r23)
    return R12 + body, c_1, ratio, psi, q2.real / n2


def bare_fresnel(cos1: np.ndarray, n3, k3) -> np.ndarray:
    """The bare interface's Fresnel reflectance (air above; :mod:`goniometer.optics`)."""
    c = np.clip(np.abs(np.asarray(cos1, dtype=np.float64)), 0.0, 1.0)
    if float(k3) > 0.0:
        return np_fresnel_conductor(c, float(n3), float(k3))
    return np_fresnel_dielectric(c, float(n3))


def film_reflectance_xyz(cos1: np.ndarray, thickness_nm: float, n2, n3, k3, tol: float = 1e-12) -> np.ndarray:
    """``(..., 3)``: Belcour & Barla's spectrally integrated film reflectance in XYZ (equal-energy
    normalisation) at the microfacet cosines ``cos1`` (scalar indices)."""
    dc, c_1, ratio, psi, cos2 = airy_fourier(cos1, n2, n3, k3)
    opd = 2.0 * float(n2) * cos2 * (float(thickness_nm) * 1e-9)
    g0 = sensitivity(np.zeros(()), np.zeros(()))
    if thickness_nm <= 0.0:
        # the film is optically absent: the bare interface's Fresnel term (grey)
        return np.asarray(bare_fresnel(cos1, n3, k3))[..., None] * g0
    out = 0.5 * (dc[0] + dc[1])[..., None] * g0
    for pol in (0, 1):
        cm = c_1[pol].copy()
        for m in range(1, MAX_TERMS + 1):
            out += cm[..., None] * sensitivity(m * opd, m * psi[pol])  # 0.5 (polarisations) * 2
            cm = cm * ratio[pol]
            if not np.any(np.abs(cm) > tol):
                break
    return out


def film_reflectance_rgb(cos1: np.ndarray, film_ior, film_thickness_nm: float, base_ior, base_k) -> np.ndarray:
    """``(..., 3)``: the model's linear sRGB Fresnel factor; channel c from the channel-c indices
    (``film_ior``, ``base_ior``, ``base_k``: RGB triples)."""
    cos1 = np.asarray(cos1, dtype=np.float64)
    m = xyz_e_to_linear_srgb()
    out = np.empty(cos1.shape + (3,))
    done: dict[tuple[float, float, float], np.ndarray] = {}
    for c in range(3):
        key = (float(film_ior[c]), float(base_ior[c]), float(base_k[c]))
        if key not in done:
            done[key] = film_reflectance_xyz(cos1, film_thickness_nm, *key) @ m.T
        out[..., c] = done[key][..., c]
    return out


def ggx_geometry(l: np.ndarray, v: np.ndarray, alpha: float, height_correlated: bool):
    """``(l.h, D G2 / (4 l_z v_z))`` of the GGX reflection lobe (0 where undefined)."""
    l = np.broadcast_to(np.asarray(l, dtype=np.float64), np.shape(v))
    v = np.asarray(v, dtype=np.float64)
    h = l + v
    norm = np.linalg.norm(h, axis=-1, keepdims=True)
    h = h / np.where(norm > 0.0, norm, 1.0)
    lh = np.sum(l * h, axis=-1)
    ok = (l[..., 2] > 0.0) & (v[..., 2] > 0.0) & (norm[..., 0] > 0.0)
    d = np_ggx_d(h[..., 0], h[..., 1], h[..., 2], alpha, alpha)
    li = np_ggx_lambda(l[..., 0], l[..., 1], l[..., 2], alpha, alpha)
    lo = np_ggx_lambda(v[..., 0], v[..., 1], v[..., 2], alpha, alpha)
    g = 1.0 / (1.0 + li + lo) if height_correlated else 1.0 / ((1.0 + li) * (1.0 + lo))
    with np.errstate(divide="ignore", invalid="ignore"):
        geo = np.where(ok, d * g / (4.0 * l[..., 2] * v[..., 2]), 0.0)
    return np.where(ok, lh, 1.0), np.nan_to_num(geo, nan=0.0, posinf=0.0)


def single_film_reason(stack: Stack, model: str) -> str | None:
    """The structure both iridescence rows accept: one rough isotropic single-scattering interface
    with a clear film (``film.extinction`` 0, ``film.ior`` >= 1), over a conductor or a dielectric."""
    layers = stack.layers
    if len(layers) != 1 or not isinstance(layers[0], Interface):
        kinds = ", ".join(type(x).__name__.lower() for x in layers)
        return f"one interface carrying a thin film only (this stack has {len(layers)} layers: {kinds})"
    x = layers[0]
    if x.film is None:
        return "the interface carries no thin film (layers[0].film)"
    if x.roughness <= 0.0:
        return "a rough interface only (alpha = 0 is a Dirac lobe)"
    if x.multiple_scattering:
        return "single-scattering microfacet lobe only (layers[0].multiple_scattering is true)"
    if max(x.film.extinction) > 0.0:
        return f"{model}'s film is a clear dielectric (layers[0].film.extinction = {list(x.film.extinction)})"
    if min(x.film.ior) < 1.0:
        return f"a film index below the air above is not modelled (layers[0].film.ior = {list(x.film.ior)})"
    return None


class BelcourIridescence(Model):
    """Belcour & Barla 2017's iridescent microfacet BRDF of one filmed GGX interface (module
    docstring; ``docs/spectral.md`` section "Models", ``docs/iridescence-models.md``).

    ``height_correlated``: Smith G2 form (default separable, the simulator's default masking)."""

    name = "belcour-iridescence"
    description = ("Belcour & Barla 2017: GGX interface whose Fresnel is a thin film's Airy reflectance "
                   "integrated against CIE XYZ in the Fourier domain (Gaussian fits), to linear sRGB")
    sides = ("brdf",)
    #: the model is of filmed interfaces (Model.films)
    films = True
    #: GGX and the film's Airy Fresnel of l, v and h only (Model.mirror_symmetric)
    mirror_symmetric = True

    def __init__(self, height_correlated: bool = False) -> None:
        self.height_correlated = bool(height_correlated)

    def support_reason(self, stack: Stack) -> str | None:
        return single_film_reason(stack, "Belcour & Barla")

    def fresnel(self, stack: Stack, cos1: np.ndarray) -> np.ndarray:
        """The model's RGB Fresnel factor at microfacet cosines ``cos1`` (``(..., 3)``)."""
        x = stack.layers[0]
        k = x.extinction if x.is_conductor else (0.0, 0.0, 0.0)
        return film_reflectance_rgb(cos1, x.film.ior, float(x.film.thickness_nm), x.ior, k)

    def _evaluate(self, stack: Stack, l: np.ndarray, v: np.ndarray, side: str) -> ModelValue:
        x = stack.layers[0]
        lh, geo = ggx_geometry(l, v, float(x.roughness), self.height_correlated)
        top = self.fresnel(stack, lh) * geo[..., None]
        return ModelValue(top=top, internal=np.zeros_like(top))
