"""An example model plugin for goniometer: ``coated-diffuse``, a Lambertian base under a GGX
dielectric coat (docs/models.md, "Writing a model (plugins)").

Installed (``pip install -e examples/plugin-model``), the distribution registers the class below in
the entry-point group ``goniometer.models`` (its pyproject.toml); ``gonio models`` then lists
``coated-diffuse`` with its source, and every command that takes ``--model`` uses it. Without
installing it, ``--model python:examples/plugin-model/example_plugin.py:CoatedDiffuse`` does the
same.

The model, for ``[dielectric coat (alpha, eta), optional absorbing medium (tau), Lambertian (rho)]``:

* ``top``: the coat's single-scattering GGX reflection ``F D G2 / (4 l_z v_z)`` (separable Smith
  masking), bounce order 1 of the simulator: ``goniometer.optics.np_microfacet_reflection``.
* ``internal``: the base seen through a smooth coat (Fresnel at the macro normal),

      T(l) T(v) a(l) a(v) rho / (pi eta^2 (1 - rho r_i)),   T(w) = 1 - F(w_z, eta),
      a(w) = exp(-tau / cos_t(w)),  cos_t(w) = sqrt(1 - (1 - w_z^2) / eta^2),

  with ``r_i = int_0^1 2 mu F(mu, 1/eta) exp(-2 tau / mu) dmu``, the fraction of the base's
  diffuse light that the coat sends back down after a round trip through the medium (Fresnel from
  inside, total internal reflection included; midpoint rule, 512 nodes).

Conventions (docs/models.md section 1): ``l`` (3,) towards the light, ``v`` (..., 3) towards the
viewer, local frame with z the normal; values without the cosine, in 1/sr, RGB last.
"""

from __future__ import annotations

import numpy as np

from goniometer.optics import np_fresnel_dielectric, np_microfacet_reflection
from goniometer.stack import Stack
from models.base import Model, ModelValue, coated_base

#: midpoint nodes of the inner diffuse reflectance r_i
NODES = 512


class CoatedDiffuse(Model):
    """A Lambertian base under a rough dielectric coat (module docstring)."""

    name = "coated-diffuse"
    description = "Lambertian base under a GGX dielectric coat: exact coat lobe, smooth-Fresnel base (example plugin)"
    sides = ("brdf",)
    #: it depends on ``v`` through ``l . h``, ``h_z`` and ``v_z`` only, so it is the same at ``v`` and at its
    #: mirror ``(v_x, -v_y, v_z)`` when ``l_y = 0``: the harness may integrate it on half of the cells
    #: (docs/models.md, "Mirror symmetry"; a test checks the declaration against the full evaluation)
    mirror_symmetric = True

    def support_reason(self, stack: Stack) -> str | None:
        cb = coated_base(stack)
        if cb is None or cb.base != "lambertian":
            return "exactly [dielectric coat interface, optional medium, Lambertian base]"
        return None

    def _evaluate(self, stack: Stack, l: np.ndarray, v: np.ndarray, side: str) -> ModelValue:
        cb = coated_base(stack)
        eta = np.asarray(stack.layers[0].ior, dtype=np.float64)          # (3,) coat index per channel
        tau, rho, alpha = cb.tau, cb.rho, float(cb.alpha0)
        vz = v[..., 2:3]                                                    # (..., 1)
        upper = vz > 0.0
        top = np.zeros(v.shape[:-1] + (3,))
        if alpha > 0.0:   # a smooth coat's mirror lobe is a Dirac: 0 here (docs/models.md section 1)
            top = np_microfacet_reflection(l[0], l[1], l[2], v[..., 0:1], v[..., 1:2], vz,
                                           alpha, alpha, eta, 0.0, False)
        t_l = 1.0 - np_fresnel_dielectric(l[2], eta)                        # (3,)
        t_v = 1.0 - np_fresnel_dielectric(np.clip(vz, 0.0, 1.0), eta)       # (..., 3)
        a_l = np.exp(-tau / _cos_t(l[2], eta))
        a_v = np.exp(-tau / _cos_t(np.clip(vz, 0.0, 1.0), eta))
        mu = (np.arange(NODES) + 0.5) / NODES
        f_in = np_fresnel_dielectric(mu[:, None], 1.0 / eta)                # (NODES, 3)
        r_i = (2.0 * mu[:, None] * f_in * np.exp(-2.0 * tau / mu[:, None])).mean(axis=0)
        internal = t_l * a_l * t_v * a_v * rho / (np.pi * eta**2 * (1.0 - rho * r_i))
        return ModelValue(np.where(upper, top, 0.0), np.where(upper, internal, 0.0))


def _cos_t(cos_i, eta):
    """Cosine of the direction refracted into the coat of index ``eta`` (from air)."""
    return np.sqrt(1.0 - (1.0 - np.square(cos_i)) / np.square(eta))
