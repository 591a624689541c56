"""Textbook optics for the model tests, written in angle form and independent of goniometer.optics:
Snell's law on angles, Fresnel via sin/tan differences and the a/b form for conductors, GGX D and
Smith Lambda in tan(theta). Shared by tests/models/test_multilayer_lut.py and
tests/models/test_weidlich_wilkie.py. The functions accept scalars (returning floats) or, where
noted, arrays.
"""

from __future__ import annotations

import math

import numpy as np


def direction(theta: float, phi: float) -> np.ndarray:
    """Unit vector of polar angle theta and azimuth phi (radians) about z."""
    return np.array([math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)])


def polar(w: np.ndarray) -> float:
    """Polar angle of the unit vector w."""
    return math.acos(min(1.0, float(w[2])))


def angle(a: np.ndarray, b: np.ndarray) -> float:
    """Angle between the unit vectors a and b."""
    return math.acos(min(1.0, float(np.dot(a, b))))


def half(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """normalize(a + b)."""
    h = a + b
    return h / np.linalg.norm(h)


def fresnel_dielectric_tb(theta_i, n):
    """Unpolarised Fresnel reflectance, incidence angle theta_i (scalar or array), relative index n;
    total internal reflection gives 1, n = 1 gives 0.

    Textbook form R = [sin^2(ti - tt)/sin^2(ti + tt) + tan^2(ti - tt)/tan^2(ti + tt)] / 2 (the
    normal-incidence limit ((n - 1)/(n + 1))^2 below 1e-8 rad).
    """
    scalar = np.ndim(theta_i) == 0
    theta_i = np.asarray(theta_i, dtype=float)
    if n == 1.0:
        r = np.zeros_like(theta_i)  # no interface
    else:
        s = np.sin(theta_i) / n
        tir = s >= 1.0
        tt = np.arcsin(np.minimum(s, 1.0))
        with np.errstate(divide="ignore", invalid="ignore"):
            rs = np.sin(theta_i - tt) ** 2 / np.sin(theta_i + tt) ** 2
            rp = np.tan(theta_i - tt) ** 2 / np.tan(theta_i + tt) ** 2
            r = 0.5 * (rs + rp)
        r = np.where(theta_i < 1e-8, ((n - 1.0) / (n + 1.0)) ** 2, r)
        r = np.where(tir, 1.0, r)
    return float(r) if scalar else r


def fresnel_conductor_tb(theta_i: float, n: float, k: float) -> float:
    """Unpolarised reflectance of a conductor n + i k (Born & Wolf / Cook-Torrance a, b form)."""
    c = math.cos(theta_i)
    s2 = math.sin(theta_i) ** 2
    t0 = n * n - k * k - s2
    a2b2 = math.sqrt(t0 * t0 + 4.0 * n * n * k * k)
    a = math.sqrt(0.5 * (a2b2 + t0))
    rs = (a2b2 - 2.0 * a * c + c * c) / (a2b2 + 2.0 * a * c + c * c)
    rp = rs * (a2b2 * c * c - 2.0 * a * c * s2 + s2 * s2) / (a2b2 * c * c + 2.0 * a * c * s2 + s2 * s2)
    return 0.5 * (rs + rp)


def ggx_d_tb(theta_m, alpha):
    """GGX D = alpha^2 / (pi cos^4 (alpha^2 + tan^2)^2) (Walter 2007, eq. 33); theta_m scalar or array."""
    t2 = np.tan(theta_m) ** 2
    return alpha * alpha / (np.pi * np.cos(theta_m) ** 4 * (alpha * alpha + t2) ** 2)


def lambda_tb(theta, alpha):
    """GGX Smith Lambda = (sqrt(1 + alpha^2 tan^2) - 1) / 2; theta scalar or array."""
    return 0.5 * (np.sqrt(1.0 + alpha * alpha * np.tan(theta) ** 2) - 1.0)


def g1_tb(theta, alpha):
    """GGX Smith G1 = 1 / (1 + Lambda); theta scalar or array."""
    return 1.0 / (1.0 + lambda_tb(theta, alpha))


def ggx_brdf_tb(l: np.ndarray, v: np.ndarray, alpha: float, fresnel) -> float:
    """F D G1 G1 / (4 cos cos) with F = fresnel(angle between l and h)."""
    h = half(l, v)
    return float(fresnel(angle(l, h)) * ggx_d_tb(polar(h), alpha) * g1_tb(polar(l), alpha)
                 * g1_tb(polar(v), alpha) / (4.0 * l[2] * v[2]))


def snell_about_n(w: np.ndarray, eta: float) -> np.ndarray:
    """Inner direction (pointing up) of w refracted about z: same azimuth, sin t = sin i / eta."""
    return direction(math.asin(math.sin(polar(w)) / eta), math.atan2(w[1], w[0]))
