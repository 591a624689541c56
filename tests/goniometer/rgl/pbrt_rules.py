"""A reader of RGL tensor files written from pbrt-v4's rules (``RGLMeasuredBxDF``; facts in
``docs/rgl-format.md``): spectral fields only, the Jacobian always applied, anisotropic files only
with reduction 1, two-sided; its warp tables are Mitsuba's continuous 2-D distributions, which are
numerically pbrt's ``PiecewiseLinear2D``. A test-side reader: independent of ``goniometer.rgl``."""

from __future__ import annotations

import math

import numpy as np


class Refused(ValueError):
    """pbrt-v4 would stop on this file."""


class PbrtMeasured:
    def __init__(self, path: str) -> None:
        import mitsuba as mi
        from mitsuba import tensor_io
        f = tensor_io.read(path)
        for name in ("description", "jacobian", "theta_i", "phi_i", "ndf", "sigma", "vndf", "luminance", "spectra",
                     "wavelengths"):
            if name not in f:
                raise Refused(f"no field {name}")
        for name in ("theta_i", "phi_i", "ndf", "sigma", "vndf", "luminance", "spectra", "wavelengths"):
            if f[name].dtype != np.float32:
                raise Refused(f"{name} is not float32")
        self.phi_i, self.theta_i = f["phi_i"], f["theta_i"]
        self.isotropic = self.phi_i.shape[0] <= 2
        if not self.isotropic:
            reduction = int(round(2 * math.pi / float(self.phi_i[-1] - self.phi_i[0])))
            if reduction != 1:
                raise Refused(f"reduction {reduction}")
        params = [self.phi_i.tolist(), self.theta_i.tolist()]
        self.ndf = mi.MarginalContinuous2D0(f["ndf"], normalize=False)
        self.sigma = mi.MarginalContinuous2D0(f["sigma"], normalize=False)
        self.vndf = mi.MarginalContinuous2D2(f["vndf"], params)
        self.spectra = mi.MarginalContinuous2D3(f["spectra"], params + [f["wavelengths"].tolist()], normalize=False)
        self.mi = mi

    @staticmethod
    def _u(theta: float, phi: float) -> tuple[float, float]:
        return math.sqrt(theta / (0.5 * math.pi)), (phi + math.pi) / (2 * math.pi)

    def f(self, wo: np.ndarray, wi: np.ndarray, lam: float) -> float:
        """pbrt's f(wo, wi) (no cosine): ``wo`` the camera side (the tables' parameter)."""
        if wo[2] * wi[2] <= 0:
            return 0.0
        if wo[2] < 0:                      # two-sided: both mirrored up
            wo, wi = wo * np.array([1, 1, -1]), wi * np.array([1, 1, -1])
        wm = (wo + wi) / np.linalg.norm(wo + wi)
        th_o, ph_o = math.acos(min(1.0, wo[2])), math.atan2(wo[1], wo[0])
        th_m, ph_m = math.acos(min(1.0, wm[2])), math.atan2(wm[1], wm[0])
        if self.isotropic:
            ph_m -= ph_o
        ux, uy = self._u(th_m, ph_m)
        uy -= math.floor(uy)
        P = self.mi.Point2f
        sample = self.vndf.invert(P(ux, uy), [ph_o, th_o])[0]
        s = max(0.0, float(self.spectra.eval(sample, [ph_o, th_o, lam])))
        ndf = float(self.ndf.eval(P(ux, uy)))
        sig = float(self.sigma.eval(P(*self._u(th_o, ph_o))))
        return s * ndf / (4.0 * sig * abs(wi[2]))
