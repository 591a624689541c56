"""The polarized state of a path and the events that change it (``docs/polarization.md``).

A polarized path carries ``pol``, a float64 (4, 16) array: rows 0 to 2 the accumulated Mueller
matrices of its three channels (row-major 4 x 4 each; the incident beam's Stokes vector to the
path's), row 3 the x axis of the path's Stokes frame (columns 0 to 2, a unit vector normal to the
path's direction, in the stack's frame). The path's weight of channel ``c`` is ``pol[c, 0]``: the
intensity it carries for unpolarized light.

Every frame is handled in the stack's frame (z the macro-surface normal; right-handed), never in
an interface's local frame, whose z flips for light from below: a Fresnel event turns the frame
about the path's direction to the ``s`` of the microfacet's plane of incidence
(:func:`to_plane`), applies the event's Mueller matrix there (:mod:`goniometer.optics`,
polarization) and keeps ``s`` as the new frame. Lambertian bases and Henyey-Greenstein
scattering depolarize (:func:`depolarize`); absorption and masking scale all four Stokes
components alike.

A path chooses between reflection and refraction as an unpolarized one does (probability the
unpolarized Fresnel reflectance, or a film's ``P``) and divides the event's Mueller matrix by
that probability: the same random choices as a scalar run, an unbiased estimate of every element.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from goniometer import optics
from goniometer.kernel.packing import FL_DL0, FL_K0, FL_KB0, FL_N0, FL_NA, FL_NB0

#: the row of ``pol`` that holds the frame's x axis
P_FRAME = 3


def initial_state(x: tuple[float, float, float]) -> np.ndarray:
    """A path's ``pol`` at its start: identity Mueller matrices and the incident beam's frame ``x``
    (:func:`goniometer.optics.normal_frame` of ``-l``, ``docs/polarization.md`` section 2)."""
    pol = np.zeros((4, 16))
    pol[:3, [0, 5, 10, 15]] = 1.0
    pol[P_FRAME, :3] = x
    return pol


@numba.njit(cache=True, error_model='numpy', inline='always')
def beam_frame(dx, dy, dz):
    """The s/p frame's ``x`` of a beam along ``d`` (:func:`goniometer.optics.normal_frame`; along the
    normal, the limit from ``d``'s own horizontal part, ``(1, 0)`` straight up or down): the frame a
    path starts with, leaves a depolarizing event with and is recorded in at its exit."""
    n = math.sqrt(dx * dx + dy * dy)
    hx = dx / n if n > 0.0 else 1.0
    hy = dy / n if n > 0.0 else 0.0
    return optics.normal_frame(dx, dy, dz, hx, hy)


@numba.njit(cache=True, error_model='numpy', inline='always')
def start(pol, polar, dx, dy, dz) -> None:
    """Reset ``pol`` to the driver's initial state ``polar`` (:func:`initial_state`); for a path
    that drew its own light direction (a tabulation, ``polar`` has a zero frame) the frame of its
    incident direction ``d``."""
    for i in range(4):
        for j in range(16):
            pol[i, j] = polar[i, j]
    if polar[P_FRAME, 0] == 0.0 and polar[P_FRAME, 1] == 0.0 and polar[P_FRAME, 2] == 0.0:
        pol[P_FRAME, 0], pol[P_FRAME, 1], pol[P_FRAME, 2] = beam_frame(dx, dy, dz)


@numba.njit(cache=True, error_model='numpy', inline='always')
def to_frame(pol, kx, ky, kz, sx, sy, sz) -> None:
    """Turn every channel's Stokes frame about the path's direction ``k`` to the unit ``s``."""
    c2, s2 = optics.stokes_rotation(kx, ky, kz, pol[P_FRAME, 0], pol[P_FRAME, 1], pol[P_FRAME, 2], sx, sy, sz)
    for ch in range(3):
        optics.mueller_rotate(pol, ch, c2, s2)
    pol[P_FRAME, 0] = sx
    pol[P_FRAME, 1] = sy
    pol[P_FRAME, 2] = sz


@numba.njit(cache=True, error_model='numpy', inline='always')
def to_plane(pol, kx, ky, kz, mx, my, mz) -> None:
    """Turn the frames to the ``s = normalize(m x k)`` of the plane of incidence of the path (along
    ``k``) on the microfacet of normal ``m``; at normal incidence on the microfacet, where any frame
    is the event's, the frame stays."""
    sx = my * kz - mz * ky
    sy = mz * kx - mx * kz
    sz = mx * ky - my * kx
    n2 = sx * sx + sy * sy + sz * sz
    if n2 < 1e-28:
        return
    inv = 1.0 / math.sqrt(n2)
    to_frame(pol, kx, ky, kz, sx * inv, sy * inv, sz * inv)


@numba.njit(cache=True, error_model='numpy', inline='always')
def to_exit(pol, dx, dy, dz) -> None:
    """Turn the frames to the exit beam's s/p frame (``docs/polarization.md`` section 2)."""
    sx, sy, sz = beam_frame(dx, dy, dz)
    to_frame(pol, dx, dy, dz, sx, sy, sz)


@numba.njit(cache=True, error_model='numpy', inline='always')
def scale(pol, f0, f1, f2) -> None:
    """Absorption, masking, Russian roulette: every element of channel ``c`` times ``f_c``."""
    for j in range(16):
        pol[0, j] *= f0
        pol[1, j] *= f1
        pol[2, j] *= f2


@numba.njit(cache=True, error_model='numpy', inline='always')
def rescale(pol, w0, w1, w2, v0, v1, v2) -> None:
    """Channel ``c`` from weight ``w_c`` to weight ``v_c`` (a free flight's change, computed on the
    weights): every element times ``v_c / w_c``."""
    scale(pol, v0 / w0 if w0 != 0.0 else 0.0, v1 / w1 if w1 != 0.0 else 0.0, v2 / w2 if w2 != 0.0 else 0.0)


@numba.njit(cache=True, error_model='numpy', inline='always')
def depolarize(pol, f0, f1, f2, dx, dy, dz) -> None:
    """A depolarizing event of albedos ``f_c`` (a Lambertian base, a Henyey-Greenstein scattering),
    the path leaving along ``d``: its light unpolarized, its frame any normal to ``d``."""
    optics.mueller_depolarize(pol, 0, f0)
    optics.mueller_depolarize(pol, 1, f1)
    optics.mueller_depolarize(pol, 2, f2)
    pol[P_FRAME, 0], pol[P_FRAME, 1], pol[P_FRAME, 2] = beam_frame(dx, dy, dz)


@numba.njit(cache=True, error_model='numpy', inline='always')
def weights(pol):
    """The path's weights: each channel's intensity for unpolarized light, ``M[0, 0]``."""
    return pol[0, 0], pol[1, 0], pol[2, 0]


@numba.njit(cache=True, error_model='numpy')
def dielectric(pol, cos_i, eta, reflected, p) -> None:
    """A dielectric microfacet (relative index ``eta``) at ``cos_i``: the reflection's or the
    refraction's Mueller matrix on every channel, divided by its probability (``p`` the reflection's)."""
    ra, rb, rc, rs, ta, tb, tc, ts = optics.fresnel_dielectric_mueller(cos_i, eta)
    if not reflected:
        ra, rb, rc, rs, p = ta, tb, tc, ts, 1.0 - p
    for ch in range(3):
        optics.mueller_event(pol, ch, ra, rb, rc, rs, 1.0 / p)


@numba.njit(cache=True, error_model='numpy')
def conductor(pol, cos_i, cond) -> None:
    """A conductor microfacet of packed relative index ``cond`` (``n`` per channel, then ``k``; a
    channel with its predecessor's index shares its matrix)."""
    a, b, c, s = optics.fresnel_conductor_mueller(cos_i, cond[0], cond[3])
    optics.mueller_event(pol, 0, a, b, c, s, 1.0)
    for ch in range(1, 3):
        if cond[ch] != cond[ch - 1] or cond[3 + ch] != cond[2 + ch]:
            a, b, c, s = optics.fresnel_conductor_mueller(cos_i, cond[ch], cond[3 + ch])
        optics.mueller_event(pol, ch, a, b, c, s, 1.0)


@numba.njit(cache=True, error_model='numpy')
def film(pol, cos_i, fr, down, reflected, p) -> None:
    """A microfacet under a thin film (packed row ``fr``; ``down``: the light arrives from above, as
    :func:`goniometer.kernel.steps.film_rt3`): the reflection's Mueller matrix (a filmed conductor:
    ``p`` 1) or the refraction's, divided by its probability ``p`` (the reflection's)."""
    n_in = fr[FL_NA] if down else fr[FL_NB0]
    for ch in range(3):
        ra, rb, rc, rs, ta, tb, tc, ts = optics.film_mueller(
            cos_i, n_in, fr[FL_N0 + ch], fr[FL_K0 + ch], fr[FL_NB0 + ch] if down else fr[FL_NA],
            fr[FL_KB0 + ch] if down else 0.0, fr[FL_DL0 + ch])
        if reflected:
            optics.mueller_event(pol, ch, ra, rb, rc, rs, 1.0 / p)
        else:
            optics.mueller_event(pol, ch, ta, tb, tc, ts, 1.0 / (1.0 - p))


@numba.njit(cache=True, error_model='numpy', inline='always')
def tabulated_exit(pol, lx, ly, lz, vx, vy, vz, folded, out) -> None:
    """A tabulation's record of a reflected exit (``docs/polarization.md`` section 5): ``out``
    (16, 3) the path's Mueller matrices per channel (element, channel) in the "plane" frames,
    ``x = normalize(l x v)`` for both beams (``pol`` holds them in the s/p frames of the incident
    beam ``-l`` and of the exit ``v``, as :func:`to_exit` leaves them; it is changed here).
    ``folded``: the pair lies in the half of its MERL cell that reciprocity folds (``phi_d < 0``,
    :mod:`goniometer.grids.halfdiff`): the record is then the reciprocal matrix ``D M^T D``,
    ``D = diag(1, 1, -1, 1)``, the cell's matrix for the exchanged pair ``(v, l)``. Where ``l`` and
    ``v`` are parallel (the plane is not defined) the s/p frames are kept."""
    xx = ly * vz - lz * vy
    xy = lz * vx - lx * vz
    xz = lx * vy - ly * vx
    n2 = xx * xx + xy * xy + xz * xz
    if n2 > 1e-28:
        inv = 1.0 / math.sqrt(n2)
        xx *= inv
        xy *= inv
        xz *= inv
        to_frame(pol, vx, vy, vz, xx, xy, xz)
        # the incident beam (along -l): its frame is the one start() set, turned to x on the right
        sx, sy, sz = beam_frame(-lx, -ly, -lz)
        c2, s2 = optics.stokes_rotation(-lx, -ly, -lz, sx, sy, sz, xx, xy, xz)
        for ch in range(3):
            for i in range(4):
                m1 = pol[ch, 4 * i + 1]
                m2 = pol[ch, 4 * i + 2]
                pol[ch, 4 * i + 1] = c2 * m1 + s2 * m2
                pol[ch, 4 * i + 2] = c2 * m2 - s2 * m1
    for ch in range(3):
        for i in range(4):
            for j in range(4):
                if folded:
                    sign = -1.0 if (i == 2) != (j == 2) else 1.0
                    out[4 * i + j, ch] = sign * pol[ch, 4 * j + i]
                else:
                    out[4 * i + j, ch] = pol[ch, 4 * i + j]


# ---- the lane kernel's event (goniometer.kernel.event.step): functions of numbers, inlined into its
# vectorised loop, which keeps each lane's state in its fields F_MUELLER .. F_FRAME + 2

@numba.njit(cache=True, error_model='numpy', inline='always')
def lane_plane(kx, ky, kz, fx, fy, fz, mx, my, mz):
    """``(c2, s2, sx, sy, sz)``: the rotation (:func:`goniometer.optics.stokes_rotation`) that turns
    the frame ``f`` of a beam along ``k`` to the ``s = normalize(m x k)`` of its plane of incidence on
    the microfacet ``m`` (stack's frame), and ``s``; at normal incidence on the microfacet the
    identity and ``f`` (as :func:`to_plane`)."""
    sx = my * kz - mz * ky
    sy = mz * kx - mx * kz
    sz = mx * ky - my * kx
    n2 = sx * sx + sy * sy + sz * sz
    ok = n2 >= 1e-28
    inv = 1.0 / math.sqrt(max(n2, 1e-300))
    sx = sx * inv if ok else fx
    sy = sy * inv if ok else fy
    sz = sz * inv if ok else fz
    c2, s2 = optics.stokes_rotation(kx, ky, kz, fx, fy, fz, sx, sy, sz)
    return (c2 if ok else 1.0), (s2 if ok else 0.0), sx, sy, sz


@numba.njit(cache=True, error_model='numpy', inline='always')
def lane_coefficients(lamb, coll, fresnel, rho, a, b, c, s, f):
    """One channel's event as the six numbers ``(A0, A1, B, C, S, F)`` of the matrix ``F [[A0, B, 0,
    0], [B, A1, 0, 0], [0, 0, C, S], [0, 0, -S, C]]``: the Lambertian base (albedo ``rho``) and a
    Henyey-Greenstein collision depolarize (``A0`` the base's albedo, or 1: a collision's albedo is
    in its traversal's factor; the rest 0), a Fresnel event
    ``(a, b, c, s)`` divided by its choice's probability (``f`` = 1 / probability), otherwise (an
    index-matched interface) the identity."""
    d = lamb or coll
    return ((rho if lamb else (1.0 if coll else (a if fresnel else 1.0))), (0.0 if d else (a if fresnel else 1.0)),
            (b if fresnel else 0.0), (0.0 if d else (c if fresnel else 1.0)), (s if fresnel else 0.0),
            (f if fresnel else 1.0))


@numba.njit(cache=True, error_model='numpy', inline='always')
def lane_m00(r0, r1, r2, c2, s2, k):
    """The new ``M[0, 0]`` of a channel (its weight) from its column 0's rows 0 to 2 (after the
    traversal), the frame's rotation and the event ``k`` (:func:`lane_coefficients`): the same
    arithmetic as the event's pass over the matrix gives that element."""
    t1 = c2 * r1 + s2 * r2
    return k[5] * (k[0] * r0 + k[2] * t1)


@numba.njit(cache=True, error_model='numpy')
def lane_load(S, i, ln, f_mueller, f_frame, pol) -> None:
    """Lane ``i``'s state (fields of ``S``, ``ln`` lanes) into a path state ``pol`` (4, 16)."""
    for c in range(3):
        for e in range(16):
            pol[c, e] = S[(f_mueller + 16 * c + e) * ln + i]
    for q in range(3):
        pol[P_FRAME, q] = S[(f_frame + q) * ln + i]


@numba.njit(cache=True, error_model='numpy')
def lane_store(S, i, ln, f_mueller, f_frame, pol) -> None:
    """A path state ``pol`` back into lane ``i``'s fields (:func:`lane_load`)."""
    for c in range(3):
        for e in range(16):
            S[(f_mueller + 16 * c + e) * ln + i] = pol[c, e]
    for q in range(3):
        S[(f_frame + q) * ln + i] = pol[P_FRAME, q]


@numba.njit(cache=True, error_model='numpy', inline='always')
def lane_film(cos_i, n_in, nf, kf, n3, k3, d_lam, reflected, f):
    """One channel's thin-film event ``(a, b, c, s, f)`` for :func:`lane_coefficients`: the
    reflection's or the refraction's terms (:func:`goniometer.optics.film_mueller`, the film seen
    from the side the light arrives from, as :func:`film` takes it) and ``f``, 1 / the probability of
    the choice (1 for a filmed conductor)."""
    ra, rb, rc, rs, ta, tb, tc, ts = optics.film_mueller(cos_i, n_in, nf, kf, n3, k3, d_lam)
    return (ra, rb, rc, rs, f) if reflected else (ta, tb, tc, ts, f)


@numba.njit(cache=True, error_model='numpy', boundscheck=False)
def lane_exit(S, i, ln, f_mueller, f_frame, dx, dy, dz, out, n) -> None:
    """Lane ``i``'s Mueller matrices (fields of ``S``, ``ln`` lanes) for its exit along ``d``, turned
    to the exit beam's s/p frame (as :func:`to_exit` turns a path's), into row ``n`` of ``out``
    (element ``e`` of channel ``c`` at column ``3 e + c``)."""
    sx, sy, sz = beam_frame(dx, dy, dz)
    c2, s2 = optics.stokes_rotation(dx, dy, dz, S[f_frame * ln + i], S[(f_frame + 1) * ln + i],
                                    S[(f_frame + 2) * ln + i], sx, sy, sz)
    for c in range(3):
        for j in range(4):
            r1 = S[(f_mueller + 16 * c + 4 + j) * ln + i]
            r2 = S[(f_mueller + 16 * c + 8 + j) * ln + i]
            out[n, 3 * j + c] = S[(f_mueller + 16 * c + j) * ln + i]
            out[n, 3 * (4 + j) + c] = c2 * r1 + s2 * r2
            out[n, 3 * (8 + j) + c] = c2 * r2 - s2 * r1
            out[n, 3 * (12 + j) + c] = S[(f_mueller + 16 * c + 12 + j) * ln + i]
