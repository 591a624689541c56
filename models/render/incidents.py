"""Interpolation between incident directions for isotropic BSDFs (``docs/render.md``).

A BSDF known only at a few light elevations ``theta_k`` (the incident slices of a file, or the
nodes at which a model is evaluated) is looked up for any pair ``(l, v)``: the pair is rotated
about the normal so that ``l`` has azimuth 0 (isotropy), the two nodes around ``theta_l`` are
weighted linearly in ``theta_l``, and each node is read at the **same coordinates** of ``v``:

* ``"view"``: the same outgoing direction ``v`` (relative to the plane of incidence);
* ``"half"``: the same half vector ``h = normalize(l + v')`` (``v'`` = ``v`` mirrored to the upper
  side for transmission, as the half slices of ``docs/slices-format.md`` §3), so that a specular
  peak at ``h = n`` stays a peak between nodes.

Conventions: ``l`` and ``v`` point away from the surface, z is the normal, angles in radians.
"""

from __future__ import annotations

import numpy as np

def align(l: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(theta_l, v_rot)``: the light elevation (N,) and ``v`` (N, 3) rotated about z by ``-phi_l``
    (so that ``l`` lies in the x-z plane with ``l_x >= 0``). A light at the pole keeps ``v``."""
    l = np.asarray(l, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    theta = np.arccos(np.clip(l[:, 2], -1.0, 1.0))
    rho = np.hypot(l[:, 0], l[:, 1])
    c = np.where(rho > 0, l[:, 0] / np.where(rho > 0, rho, 1.0), 1.0)
    s = np.where(rho > 0, l[:, 1] / np.where(rho > 0, rho, 1.0), 0.0)
    vr = np.stack([c * v[:, 0] + s * v[:, 1], -s * v[:, 0] + c * v[:, 1], v[:, 2]], axis=-1)
    return theta, vr


def node_light(theta: float, phi: float = 0.0) -> np.ndarray:
    """Unit light direction at elevation ``theta`` and azimuth ``phi`` (radians)."""
    return np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])


def half_vector(l: np.ndarray, v: np.ndarray, transmission: bool) -> np.ndarray:
    """``normalize(l + v')`` row by row, ``v'`` = ``v`` mirrored to the upper side for transmission."""
    vm = v * np.array([1.0, 1.0, -1.0]) if transmission else v
    h = l + vm
    n = np.linalg.norm(h, axis=-1, keepdims=True)
    return h / np.where(n > 0, n, 1.0)


def view_from_half(l: np.ndarray, h: np.ndarray, transmission: bool) -> tuple[np.ndarray, np.ndarray]:
    """The outgoing directions ``v`` (N, 3) whose half vector with ``l`` (3,) is ``h`` (N, 3), and
    whether each is on the slice's side (``l.h > 0`` and ``v`` above the surface before the mirror)."""
    lh = h @ l
    v = 2.0 * lh[:, None] * h - l
    valid = (lh > 0.0) & (v[:, 2] > 0.0)
    if transmission:
        v = v * np.array([1.0, 1.0, -1.0])
    return v, valid


def bracket(theta: np.ndarray, nodes: np.ndarray, tol: float = 1e-9) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """For each ``theta`` (N,), the nodes around it in the ascending ``nodes`` (K >= 2,):
    ``(k0, k1, t, inside)`` with ``theta ~ (1 - t) nodes[k0] + t nodes[k1]``; ``t`` is clipped to
    [0, 1] (constant beyond the end nodes) and ``inside`` says whether ``theta`` lies within
    ``[nodes[0], nodes[-1]]`` (to ``tol``)."""
    nodes = np.asarray(nodes, dtype=np.float64)
    if nodes.ndim != 1 or len(nodes) < 2 or np.any(np.diff(nodes) <= 0):
        raise ValueError("nodes: need at least two strictly increasing values")
    k0 = np.clip(np.searchsorted(nodes, theta, side="right") - 1, 0, len(nodes) - 2)
    k1 = k0 + 1
    t = np.clip((theta - nodes[k0]) / (nodes[k1] - nodes[k0]), 0.0, 1.0)
    inside = (theta >= nodes[0] - tol) & (theta <= nodes[-1] + tol)
    return k0, k1, t, inside
