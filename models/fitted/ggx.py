"""The fitted GGX families ``ggx1`` and ``ggx2`` (:class:`GGXFamily`): Lambertian plus one or two GGX
lobes with a Schlick Fresnel shape, ``kd/pi + sum_j ks_j F_S(F0_j, l.h) / F0_j D(h) G2(l, v) / (4 l_z v_z)``
with GGX ``D`` and the height-correlated Smith ``G2`` of :mod:`goniometer.optics`. ``l``, ``v`` point
away from the surface; values without cosine in 1/sr, RGB last. ``docs/fitted.md``.
"""

from __future__ import annotations

import math

import numpy as np

from goniometer.optics import ggx_d, ggx_lambda, half_vector, smith_g2
from models._jit import njit
from models.fitted.family import FD_STEP, INV_PI, Family, ParamSpec
from models.fitted.samples import Samples


@njit(cache=True)
def _ggx_lobe(l: np.ndarray, v: np.ndarray, schlick: np.ndarray, w: np.ndarray, start: np.ndarray,
              alpha: float, A: np.ndarray, B: np.ndarray) -> None:
    """Cell averages of an isotropic GGX lobe ``q = D(h) G2(l, v) / (4 l_z v_z)``.

    ``D``, ``Lambda`` and the height-correlated ``G2`` come from :mod:`goniometer.optics`.
    ``A = <q (1 - m)>``, ``B = <q m>`` with ``<.>`` the ``w``-weighted sum over a cell's samples
    ``start[i]:start[i + 1]`` (weights normalised per cell) and ``m`` the Schlick weight.
    Samples with ``l_z <= 0`` or ``v_z <= 0`` contribute 0.
    """
    n_cells = start.shape[0] - 1
    for i in range(n_cells):
        sa = 0.0
        sb = 0.0
        for k in range(start[i], start[i + 1]):
            lx, ly, lz = l[k, 0], l[k, 1], l[k, 2]
            vx, vy, vz = v[k, 0], v[k, 1], v[k, 2]
            if w[k] == 0.0 or not (lz > 0.0 and vz > 0.0):
                continue
            hx, hy, hz = half_vector(lx, ly, lz, vx, vy, vz)
            d = ggx_d(hx, hy, hz, alpha, alpha)
            g = smith_g2(ggx_lambda(lx, ly, lz, alpha, alpha), ggx_lambda(vx, vy, vz, alpha, alpha), False, True)
            q = w[k] * d * g / (4.0 * lz * vz)
            sa += q * (1.0 - schlick[k])
            sb += q * schlick[k]
        A[i] = sa
        B[i] = sb


class GGXFamily(Family):
    """Diffuse + ``n_lobes`` GGX lobes with a Schlick Fresnel shape (see the module docstring).

    Lobe ``j``: ``ks_j F_S(F0_j, l.h) / F0_j * D G2 / (4 l_z v_z)`` -- ``ks`` (RGB) is the lobe's
    Fresnel factor at normal incidence, the scalar ``F0`` only shapes the grazing rise
    ``(1 - m) + m / F0`` (``m = (1 - l.h)^5``). ``ks = 0`` switches a lobe off, so one lobe nests
    in two.
    """

    def __init__(self, n_lobes: int) -> None:
        self.n_lobes = n_lobes
        self.kind = f"ggx{n_lobes}"
        specs = [ParamSpec("kd", 3, 0.0, 1.0, typical=(0.0, 1.0), linear=True, start=0.5)]
        starts = (0.1,) if n_lobes == 1 else (0.05, 0.3)
        for j in range(n_lobes):
            sfx = "" if n_lobes == 1 else f"_{j + 1}"
            specs.append(ParamSpec(f"ks{sfx}", 3, 0.0, 5.0, typical=(0.0, 1.0), linear=True, start=0.05))
            specs.append(ParamSpec(f"F0{sfx}", 1, 0.02, 1.0, log=True, typical=(0.02, 1.0), start=0.04))
            specs.append(ParamSpec(f"alpha{sfx}", 1, 1e-3, 1.5, log=True, typical=(0.01, 1.0), start=starts[j]))
        self.specs = tuple(specs)

    def lobe(self, alpha: float, smp: Samples) -> tuple[np.ndarray, np.ndarray]:
        """Cell averages ``(<q (1 - m)>, <q m>)`` of the lobe shape ``q`` (see :func:`_ggx_lobe`)."""
        A = np.empty(smp.n_cells)
        B = np.empty(smp.n_cells)
        _ggx_lobe(smp.l, smp.v, smp.schlick, smp.w, smp.start, float(alpha), A, B)
        return A, B

    def cells_and_jac(self, z, smp, jac):
        s = self.slices()
        x = self.to_natural(z)
        n = smp.n_cells
        f = np.broadcast_to(x[s["kd"]] * INV_PI, (n, 3)).copy()
        K = 1 + 3 * self.n_lobes
        V = np.empty((3, K, n)) if jac else None
        cols = np.empty((3, K), dtype=np.int64)
        for c in range(3):
            cols[c, 0] = s["kd"].start + c
            if jac:
                V[c, 0] = INV_PI
        for j in range(self.n_lobes):
            sfx = "" if self.n_lobes == 1 else f"_{j + 1}"
            s_ks, s_f0, s_a = s["ks" + sfx], s["F0" + sfx], s["alpha" + sfx]
            ks, f0 = x[s_ks], x[s_f0][0]
            A, B = self.lobe(x[s_a][0], smp)
            shape = A + B / f0
            f += shape[:, None] * ks[None, :]
            if not jac:
                continue
            za = z[s_a][0]
            Ap, Bp = self.lobe(math.exp(za + FD_STEP), smp)
            Am, Bm = self.lobe(math.exp(za - FD_STEP), smp)
            dshape = ((Ap - Am) + (Bp - Bm) / f0) / (2.0 * FD_STEP)
            for c in range(3):
                cols[c, 1 + 3 * j: 4 + 3 * j] = (s_ks.start + c, s_f0.start, s_a.start)
                V[c, 1 + 3 * j] = shape
                V[c, 2 + 3 * j] = -(B / f0) * ks[c]   # d/d(ln F0) of B / F0 is -B / F0
                V[c, 3 + 3 * j] = dshape * ks[c]
        return f, ((V, cols) if jac else None)
