"""Closed forms for perfectly smooth stacks: the simulator's exact oracles.

* :func:`adding_energies` -- reflected and transmitted flux fractions of a stack of smooth
  interfaces and absorbing media over a transmitting, conductor or absent base, by the adding
  equations (Stokes relations, inter-reflections summed as geometric series) with exact Fresnel
  and Beer-Lambert attenuation ``exp(-tau / cos theta)`` along the refracted direction, for
  scalar light (every Fresnel event sees unpolarized light: what the scalar tracer computes).
* :func:`adding_mueller` -- the same stack's reflection and transmission Mueller matrices: the
  adding of the Fresnel events' Mueller matrices (``docs/polarization.md``), s and p summed
  separately and their cross terms as complex numbers; its ``a`` is the true intensity for
  unpolarized light, which :func:`adding_energies` gets wrong off the normal.
* :func:`coated_lambertian_brdf` -- the BRDF of a smooth dielectric coat (optionally absorbing)
  over a Lambertian base, without the specular reflection off the coat:
  ``f = rho T(l) T(v) a(l) a(v) / (pi eta^2 (1 - rho r_i))``, with ``T = 1 - F`` the coat
  transmittances, ``a`` the attenuation along the refracted directions, and ``r_i`` the coat's
  internal diffuse reflectance ``2 Int_0^1 F_in(mu) exp(-2 tau / mu) mu dmu`` (quadrature).

Angles are elevations in air, radians or degrees as stated; all results are per RGB channel.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import integrate

from goniometer import optics
from goniometer.stack import Interface, Lambertian, Medium, Stack


def _refuse_scattering(stack: Stack, what: str) -> None:
    if any(isinstance(x, Medium) and x.scatters for x in stack.layers):
        raise ValueError(f"{what}: media must only absorb (this stack has a scattering medium)")


def adding_energies(stack: Stack, theta_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Reflected and transmitted fractions (RGB) of a smooth stack lit at ``theta_deg`` from air.

    Every interface is treated as perfectly smooth whatever its roughness. A Lambertian base is
    not supported (use :func:`coated_lambertian_brdf`).
    """
    if isinstance(stack.layers[-1], Lambertian):
        raise ValueError("adding_energies: a Lambertian base is not a smooth stack")
    _refuse_scattering(stack, "adding_energies")
    s0 = math.sin(math.radians(theta_deg))
    etas, taus, interfaces = _regions(stack)

    def cos_in(region: int) -> float:
        s = s0 / etas[region]
        return math.sqrt(max(0.0, 1.0 - s * s))

    # bottom-up: (R, T) of everything below region r, seen from region r (RGB)
    last = interfaces[-1]
    n_reg = len(etas)
    if last.is_conductor:
        r_above = n_reg - 1
        c = cos_in(r_above)
        n_above = etas[r_above]
        R = np.array([optics.fresnel_conductor(c, last.ior[i] / n_above, last.extinction[i] / n_above)
                      for i in range(3)])
        T = np.zeros(3)
        k_top = len(interfaces) - 2
    else:
        R = np.zeros(3)
        T = np.ones(3)
        k_top = len(interfaces) - 1
    for k in range(k_top, -1, -1):
        below = k + 1
        c_below = cos_in(below)
        a = np.exp(-taus[below] / c_below) if c_below > 0 else np.zeros(3)
        r = optics.fresnel_dielectric(cos_in(k), etas[below] / etas[k])
        t = 1.0 - r
        denom = 1.0 - r * a * a * R
        R, T = r + t * t * a * a * R / denom, t * a * T / denom
    return R, T


def adding_mueller(stack: Stack, theta_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """The reflection and transmission Mueller matrices of a smooth stack lit at ``theta_deg`` from
    air, as their four numbers ``(a, b, c, s)`` per channel (arrays (4, 3); the matrix
    ``[[a, b, 0, 0], [b, a, 0, 0], [0, 0, c, s], [0, 0, -s, c]]`` in the s/p frames of the plane of
    incidence, ``docs/polarization.md``). Every beam of a smooth stack has the one plane of
    incidence, so the events' matrices keep that form: the s and p intensities add as two scalar
    adding problems, the cross terms ``c + i s`` multiply as complex numbers. Media only absorb."""
    if isinstance(stack.layers[-1], Lambertian):
        raise ValueError("adding_mueller: a Lambertian base is not a smooth stack")
    _refuse_scattering(stack, "adding_mueller")
    s0 = math.sin(math.radians(theta_deg))
    etas, taus, interfaces = _regions(stack)

    def cos_in(region: int) -> float:
        s = s0 / etas[region]
        return math.sqrt(max(0.0, 1.0 - s * s))

    def parts(terms) -> np.ndarray:
        """The s intensity, the p intensity and the cross term ``c + i s`` of an event's (a, b, c, s)."""
        a, b, c, s = terms
        return np.array([a + b, a - b, complex(c, s)])

    R_out = np.zeros((4, 3))
    T_out = np.zeros((4, 3))
    last = interfaces[-1]
    for ch in range(3):
        # bottom-up: what lies below region r, seen from region r
        if last.is_conductor:
            n_above = etas[-1]
            R = parts(optics.fresnel_conductor_mueller(cos_in(len(etas) - 1), last.ior[ch] / n_above,
                                                       last.extinction[ch] / n_above))
            T = np.zeros(3, dtype=complex)
            k_top = len(interfaces) - 2
        else:
            R = np.zeros(3, dtype=complex)
            T = np.ones(3, dtype=complex)
            k_top = len(interfaces) - 1
        for k in range(k_top, -1, -1):
            below = k + 1
            cb = cos_in(below)
            a = math.exp(-taus[below][ch] / cb) if cb > 0 else 0.0
            eta = etas[below] / etas[k]
            down = optics.fresnel_dielectric_mueller(cos_in(k), eta)
            up = optics.fresnel_dielectric_mueller(cb, 1.0 / eta) if cb > 0 else (0.0,) * 8
            r, t, r_up, t_up = parts(down[:4]), parts(down[4:]), parts(up[:4]), parts(up[4:])
            loop = 1.0 / (1.0 - r_up * a * a * R)
            R, T = r + t * t_up * a * a * R * loop, t * a * T * loop
        R_out[:, ch] = [0.5 * (R[0] + R[1]).real, 0.5 * (R[0] - R[1]).real, R[2].real, R[2].imag]
        T_out[:, ch] = [0.5 * (T[0] + T[1]).real, 0.5 * (T[0] - T[1]).real, T[2].real, T[2].imag]
    return R_out, T_out


def _regions(stack: Stack) -> tuple[list[float], list[np.ndarray], list[Interface]]:
    """The real index and the optical depth of each region of a smooth stack (air first), and its
    interfaces."""
    etas = [1.0]
    taus = [np.zeros(3)]
    interfaces: list[Interface] = []
    for layer in stack.layers:
        if isinstance(layer, Interface):
            interfaces.append(layer)
            if not layer.is_conductor:
                etas.append(layer.ior[0])
                taus.append(np.zeros(3))
        elif isinstance(layer, Medium):
            taus[-1] = np.asarray(layer.optical_depth, dtype=float)
    return etas, taus, interfaces


def internal_diffuse_reflectance(eta: float, tau: np.ndarray | float) -> np.ndarray:
    """r_i = 2 Int_0^1 F(mu; 1/eta) exp(-2 tau/mu) mu dmu: the fraction of a diffuse (Lambertian)
    upward flux inside a coat of index ``eta`` that the coat sends back down to the base
    (total internal reflection included), after absorption on both passes. RGB."""
    taus = np.broadcast_to(np.asarray(tau, dtype=float), (3,))
    mu_c = math.sqrt(max(0.0, 1.0 - 1.0 / (eta * eta))) if eta > 1.0 else 0.0
    out = np.empty(3)
    for i, t in enumerate(taus):
        def g(mu: float) -> float:
            return 2.0 * optics.fresnel_dielectric(mu, 1.0 / eta) * math.exp(-2.0 * t / mu) * mu if mu > 0 else 0.0
        pts = [mu_c] if 0.0 < mu_c < 1.0 else None
        out[i] = integrate.quad(g, 0.0, 1.0, points=pts, limit=200, epsabs=1e-13, epsrel=1e-11)[0]
    return out


def coat_escape(eta: float, tau: np.ndarray | float) -> np.ndarray:
    """e_out = 2 Int_0^1 (1 - F(mu; 1/eta)) exp(-tau/mu) mu dmu: the fraction of a diffuse upward
    flux leaving the base that escapes through the coat into air. RGB."""
    taus = np.broadcast_to(np.asarray(tau, dtype=float), (3,))
    mu_c = math.sqrt(max(0.0, 1.0 - 1.0 / (eta * eta))) if eta > 1.0 else 0.0
    out = np.empty(3)
    for i, t in enumerate(taus):
        def g(mu: float) -> float:
            return 2.0 * (1.0 - optics.fresnel_dielectric(mu, 1.0 / eta)) * math.exp(-t / mu) * mu if mu > 0 else 0.0
        pts = [mu_c] if 0.0 < mu_c < 1.0 else None
        out[i] = integrate.quad(g, 0.0, 1.0, points=pts, limit=200, epsabs=1e-13, epsrel=1e-11)[0]
    return out


def _coat_lambertian_parts(stack: Stack) -> tuple[float, np.ndarray, np.ndarray]:
    layers = stack.layers
    ok = (isinstance(layers[0], Interface) and not layers[0].is_conductor and isinstance(layers[-1], Lambertian)
          and (len(layers) == 2 or (len(layers) == 3 and isinstance(layers[1], Medium))))
    if not ok:
        raise ValueError("coated Lambertian closed form: expected [interface, (medium), lambertian]")
    _refuse_scattering(stack, "coated Lambertian closed form")
    eta = layers[0].ior[0]
    tau = np.asarray(layers[1].optical_depth if len(layers) == 3 else (0.0,) * 3, dtype=float)
    rho = np.asarray(layers[-1].albedo, dtype=float)
    return eta, tau, rho


def coated_lambertian_brdf(stack: Stack, cos_l: np.ndarray, cos_v: np.ndarray) -> np.ndarray:
    """BRDF (1/sr, no cosine, RGB on the last axis) of the internal paths of a smooth coat over
    a Lambertian base, for arrays of light and view cosines in air (broadcast together)."""
    eta, tau, rho = _coat_lambertian_parts(stack)
    cl, cv = np.broadcast_arrays(np.asarray(cos_l, float), np.asarray(cos_v, float))
    ri = internal_diffuse_reflectance(eta, tau)

    def through(c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t = 1.0 - optics.np_fresnel_dielectric(c, eta)
        ci = np.sqrt(np.maximum(0.0, 1.0 - (1.0 - c * c) / (eta * eta)))
        a = np.exp(-tau / ci[..., None])
        return t, a

    tl, al = through(cl)
    tv, av = through(cv)
    return (rho * tl[..., None] * tv[..., None] * al * av) / (math.pi * eta * eta * (1.0 - rho * ri))


def coated_lambertian_albedo(stack: Stack, cos_l: float) -> np.ndarray:
    """Integral of :func:`coated_lambertian_brdf` times cos over the view hemisphere (RGB)."""
    eta, tau, rho = _coat_lambertian_parts(stack)
    t = 1.0 - optics.fresnel_dielectric(cos_l, eta)
    ci = math.sqrt(max(0.0, 1.0 - (1.0 - cos_l * cos_l) / (eta * eta)))
    a = np.exp(-tau / ci)
    return t * a * rho * coat_escape(eta, tau) / (1.0 - rho * internal_diffuse_reflectance(eta, tau))
