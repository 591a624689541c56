"""An analytic model as the BSDF of a rendering (``docs/render.md``).

``Model.evaluate`` takes one light direction and many outgoing directions, while every pixel of a
sphere has its own light direction. The model is therefore evaluated at light elevations every
:func:`node_step_deg` (azimuth 0) and interpolated linearly in ``theta_l`` at a fixed half vector
(:mod:`models.render.incidents`, ``"half"`` coordinates: a specular peak does not fade between
nodes). A node whose outgoing direction falls below the horizon is left out (the other carries the
pair); lights closer to grazing than the last node (``90 deg - step``) use that node.
Isotropic stacks only (the pair is rotated so that ``l`` has azimuth 0).
"""

from __future__ import annotations

import numpy as np

from goniometer.stack import Stack
from models.base import Model, ModelError
from models.render.incidents import align, bracket, half_vector, node_light, view_from_half

#: the finest and the coarsest spacing of the light elevations at which a model is evaluated (degrees)
THETA_STEP_DEG = 0.25
THETA_STEP_MAX_DEG = 2.0


def node_step_deg(size: int) -> float:
    """Node spacing for a sphere ``size`` pixels wide: the angle between the normals of two
    neighbouring pixels at the image centre (``2 / size`` rad), clipped to [0.25, 2] degrees."""
    return float(np.clip(np.degrees(2.0 / size), THETA_STEP_DEG, THETA_STEP_MAX_DEG))


class ModelBSDF:
    """``f(l, v)`` of ``model`` on ``stack`` (``top + internal``) for pairs of directions (N, 3)."""

    def __init__(self, model: Model, stack: Stack, side: str, step_deg: float = THETA_STEP_DEG) -> None:
        if side not in model.sides:
            raise ModelError(f"{model.name}: cannot evaluate the {side.upper()} (it models {', '.join(model.sides)})")
        reason = model.reason(stack)
        if reason is not None:
            raise ModelError(f"{model.name}: {reason}")
        self.model, self.stack, self.side = model, stack, side
        self.transmission = side == "btdf"
        n = int(round((90.0 - step_deg) / step_deg))
        self.nodes = np.radians(np.arange(n + 1) * step_deg)

    def __call__(self, l: np.ndarray, v: np.ndarray) -> np.ndarray:
        theta_l, vr = align(l, v)
        lr = np.stack([np.sin(theta_l), np.zeros_like(theta_l), np.cos(theta_l)], axis=-1)
        h = half_vector(lr, vr, self.transmission)
        k0, k1, t, _ = bracket(theta_l, self.nodes)
        acc = np.zeros((len(theta_l), 3))
        wsum = np.zeros(len(theta_l))
        for k in np.unique(np.concatenate([k0[t < 1.0], k1[t > 0.0]])):
            weight = np.where(k0 == k, 1.0 - t, 0.0) + np.where(k1 == k, t, 0.0)
            sel = np.flatnonzero(weight > 0.0)
            lk = node_light(float(self.nodes[k]))
            vk, valid = view_from_half(lk, h[sel], self.transmission)
            sel, vk = sel[valid], vk[valid]
            if not len(sel):
                continue
            f = self.model.evaluate(self.stack, lk, vk, self.side).total
            acc[sel] += weight[sel, None] * f
            wsum[sel] += weight[sel]
        out = np.full_like(acc, np.nan)
        ok = wsum > 0.0
        out[ok] = acc[ok] / wsum[ok, None]
        return out
