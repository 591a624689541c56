"""The Stokes frames of polarized slices and their conversion to other codes' frames
(``docs/polarization.md`` section 2).

A polarized run's Mueller matrix of a cell maps the Stokes vector of the incident beam (travelling
along ``-l``) to that of the exit beam (along ``v``), each in the goniometer's s/p frame of its own
plane of incidence (``"sp"``): ``x = s = normalize(z x k)``, normal to the plane of the beam and the
surface normal, ``y = k x s`` (at the normal, the limit along the azimuth of ``l`` or ``v``,
:func:`goniometer.optics.normal_frame`). Other frame families:

* ``"mitsuba"``: Mitsuba 3's ``stokes_basis(k)`` (the Duff et al. 2017 frame of ``k``) for both
  beams, as its polarized BSDFs' ``eval`` returns them (in the local shading frame);
* ``"plane"``: ``x = normalize(l x v)`` for both beams, the normal of the plane that holds both (and
  the half vector): the frames of Mitsuba's ``roughconductor`` Fresnel term and of the
  ``measured_polarized`` format (Baek et al. 2020).

:func:`convert_mueller` takes a Mueller matrix from one family to another (a rotation of each beam's frame
about its direction); every function takes arrays and broadcasts over leading axes. ``l`` and
``v`` point away from the surface (``docs/slices-format.md``).
"""

from __future__ import annotations

import numpy as np

__all__ = ["FRAMES", "convert_mueller", "frame_x", "mitsuba_stokes_basis", "rotator"]

#: the frame families :func:`convert_mueller` knows
FRAMES = ("sp", "mitsuba", "plane")


def _unit(a: np.ndarray) -> np.ndarray:
    return a / np.linalg.norm(a, axis=-1, keepdims=True)


def mitsuba_stokes_basis(k: np.ndarray) -> np.ndarray:
    """Mitsuba 3's ``stokes_basis(k)`` (``coordinate_system(k).first``): ``(1 - x^2 / (1 + z), -x y /
    (1 + z), -x)`` for ``z >= 0`` and ``(1 - x^2 / (1 - z), -x y / (1 - z), x)`` below."""
    k = np.asarray(k, dtype=float)
    x, y, z = k[..., 0], k[..., 1], k[..., 2]
    up = z >= 0.0
    d = np.where(up, 1.0 + z, 1.0 - z)
    return np.stack([1.0 - x * x / d, -x * y / d, np.where(up, -x, x)], axis=-1)


def _sp_x(k: np.ndarray, horizontal: np.ndarray) -> np.ndarray:
    """``normalize(z x k)``; at the normal ``z x h`` for the unit horizontal ``h`` of the limit."""
    zk = np.stack([-k[..., 1], k[..., 0], np.zeros(k.shape[:-1])], axis=-1)
    n = np.linalg.norm(zk, axis=-1, keepdims=True)
    zh = np.stack([-horizontal[..., 1], horizontal[..., 0], np.zeros(k.shape[:-1])], axis=-1)
    return np.where(n > 1e-15, zk / np.where(n > 1e-15, n, 1.0), zh)


def frame_x(family: str, l: np.ndarray, v: np.ndarray, phi_l_deg=0.0, phi_v_deg=0.0) -> tuple[np.ndarray, np.ndarray]:
    """The x axes ``(x_in, x_out)`` of the incident beam (along ``-l``) and the exit beam (along
    ``v``) in frame family ``family``; ``phi_l_deg``, ``phi_v_deg``: the azimuths whose limit the s/p
    frames take at the normal."""
    l = np.asarray(l, dtype=float)
    v = np.asarray(v, dtype=float)
    if family == "sp":
        pl = np.radians(np.asarray(phi_l_deg, dtype=float))
        pv = np.radians(np.asarray(phi_v_deg, dtype=float))
        hl = np.stack(np.broadcast_arrays(-np.cos(pl), -np.sin(pl)), axis=-1)
        hv = np.stack(np.broadcast_arrays(np.cos(pv), np.sin(pv)), axis=-1)
        return _sp_x(-l, hl), _sp_x(v, hv)
    if family == "mitsuba":
        return mitsuba_stokes_basis(-l), mitsuba_stokes_basis(v)
    if family == "plane":
        x = _unit(np.cross(l, v))
        return x, x
    raise ValueError(f"frames: {family!r} is not one of {', '.join(FRAMES)}")


def rotator(k: np.ndarray, x_from: np.ndarray, x_to: np.ndarray) -> np.ndarray:
    """The 4 x 4 matrices taking a Stokes vector of a beam along ``k`` from the frame whose x axis is
    ``x_from`` to the one whose x axis is ``x_to`` (Mitsuba 3's ``rotate_stokes_basis``; the same
    rotation as :func:`goniometer.optics.stokes_rotation`)."""
    c = np.sum(x_from * x_to, axis=-1)
    s = np.sum(k * np.cross(x_from, x_to), axis=-1)
    c2, s2 = c * c - s * s, 2.0 * c * s
    out = np.zeros(c.shape + (4, 4))
    out[..., 0, 0] = out[..., 3, 3] = 1.0
    out[..., 1, 1] = out[..., 2, 2] = c2
    out[..., 1, 2] = s2
    out[..., 2, 1] = -s2
    return out


def convert_mueller(mueller: np.ndarray, l: np.ndarray, v: np.ndarray, source: str = "sp", target: str = "mitsuba",
            phi_l_deg=0.0, phi_v_deg=0.0) -> np.ndarray:
    """``mueller`` (``(..., 4, 4)``, light along ``-l`` to ``v``) from the frames ``source`` to the
    frames ``target`` (:data:`FRAMES`): ``R_out M R_in^T``. No cosine is added or removed (Mitsuba's
    ``eval`` multiplies the BRDF by ``cos theta_l``; ours is without it)."""
    l = np.asarray(l, dtype=float)
    v = np.asarray(v, dtype=float)
    a_in, a_out = frame_x(source, l, v, phi_l_deg, phi_v_deg)
    b_in, b_out = frame_x(target, l, v, phi_l_deg, phi_v_deg)
    r_in = rotator(-l, a_in, b_in)
    r_out = rotator(v, a_out, b_out)
    return r_out @ np.asarray(mueller, dtype=float) @ np.swapaxes(r_in, -1, -2)
