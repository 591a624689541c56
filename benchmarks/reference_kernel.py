"""The yardstick of the goniometer's kernel speed: a plain, textbook numba path tracer of the
same physics on the benchmark stacks (``benchmarks/README.md``, issue 15).

Deliberately simple, written by us, and never used for results: float64 everywhere, libm
trigonometry (``cos``/``sin`` of the VNDF azimuth, ``acos``/``atan2`` of the exit cell), one
private histogram per chunk holding only the exit weights per cell and channel (no bounce orders,
no second moments, no per-path energy records beyond the reflected and transmitted sums), the
random numbers of :mod:`goniometer.kernel.rng` drawn from the same per-chunk streams.

Physics (the same as :func:`goniometer.kernel.tracer._trace_chunk` for single-scattering stacks without
scattering media; ``docs/material-format.md``, transport): a path starts along ``-l`` with weight
(1, 1, 1); at an interface a GGX visible normal is drawn (spherical-cap construction) and the
path reflects with probability F (dielectric) or always with weight *= F (conductor base); the
weight is multiplied by the separable masking ``G1(o)`` and a direction on the wrong side ends
the path; media attenuate by Beer-Lambert; a Lambertian base reflects cosine-distributed with
weight *= rho; Russian roulette from the third event on below weight 0.05. Isotropic roughness
only, separable masking only.

``python benchmarks/reference_kernel.py --rays N`` traces the coated metal of issue 15
(alpha0 = 0.05, tau (0.1, 0.2, 0.5), conductor alpha1 = 0.2, theta_l = 30, classic 90 x 360)
on one thread and prints its rays per CPU-second (kernel only, compile excluded).
"""

from __future__ import annotations

import argparse
import math
import sys
import time

import numba
import numpy as np

from goniometer.kernel.rng import next_float, stream_state
from goniometer.grids.slice_grid import cell_index
from goniometer.stack import Stack
from goniometer.kernel.packing import pack

_TWO_PI = 2.0 * math.pi


@numba.njit(cache=True)
def _vndf(wx, wy, wz, a, u1, u2):
    """Textbook GGX visible normal (isotropic ``a``), spherical cap, libm trigonometry."""
    sx = a * wx
    sy = a * wy
    n = math.sqrt(sx * sx + sy * sy + wz * wz)
    sx /= n
    sy /= n
    sz = wz / n
    phi = _TWO_PI * u1
    z = (1.0 - u2) * (1.0 + sz) - sz
    st = math.sqrt(max(0.0, 1.0 - z * z))
    hx = a * (st * math.cos(phi) + sx)
    hy = a * (st * math.sin(phi) + sy)
    hz = max(1e-300, z + sz)
    n = math.sqrt(hx * hx + hy * hy + hz * hz)
    return hx / n, hy / n, hz / n


@numba.njit(cache=True)
def _fresnel_dielectric(c, eta):
    """Unpolarised Fresnel reflectance and refracted cosine, ``eta`` = n_far / n_near."""
    c = min(abs(c), 1.0)
    s2 = (1.0 - c * c) / (eta * eta)
    if s2 >= 1.0:
        return 1.0, 0.0
    ct = math.sqrt(1.0 - s2)
    rs = (c - eta * ct) / (c + eta * ct)
    rp = (eta * c - ct) / (eta * c + ct)
    return 0.5 * (rs * rs + rp * rp), ct


@numba.njit(cache=True)
def _fresnel_conductor(c, eta, k):
    """Unpolarised Fresnel reflectance of the complex relative index ``eta + i k``."""
    c = min(abs(c), 1.0)
    c2 = c * c
    s2 = 1.0 - c2
    t = eta * eta - k * k - s2
    a2b2 = math.sqrt(t * t + 4.0 * eta * eta * k * k)
    a = math.sqrt(max(0.0, 0.5 * (a2b2 + t)))
    rs = (a2b2 + c2 - 2.0 * a * c) / (a2b2 + c2 + 2.0 * a * c)
    rp = rs * (a2b2 * c2 + s2 * s2 - 2.0 * a * c * s2) / (a2b2 * c2 + s2 * s2 + 2.0 * a * c * s2)
    return 0.5 * (rs + rp)


@numba.njit(cache=True)
def _lambda(wx, wy, wz, a):
    t2 = (wx * wx + wy * wy) / (wz * wz)
    return 0.5 * (math.sqrt(1.0 + a * a * t2) - 1.0)


@numba.njit(cache=True)
def reference_chunk(alpha, region_eta, region_tau, cond, rho, base_kind, lx, ly, lz, n_rays, state,
                    param, n_theta, n_phi, brdf, btdf, energy, squares, brdf_sq):
    """Trace ``n_rays`` paths into ``brdf``/``btdf`` (n_theta, n_phi, 3) and ``energy`` (2, 3):
    reflected and transmitted weight sums. Arguments as :class:`goniometer.kernel.packing.PackedStack`.
    ``squares`` (for tests, off when timed): also sum the squared BRDF exit weights per cell into
    ``brdf_sq``."""
    n_if = region_eta.shape[0] - 1
    for _ in range(n_rays):
        dx = -lx
        dy = -ly
        dz = -lz
        region = 0
        w0 = 1.0
        w1 = 1.0
        w2 = 1.0
        events = 0
        while True:
            if region_tau[region, 0] + region_tau[region, 1] + region_tau[region, 2] > 0.0:
                w0 *= math.exp(-region_tau[region, 0] / abs(dz))
                w1 *= math.exp(-region_tau[region, 1] / abs(dz))
                w2 *= math.exp(-region_tau[region, 2] / abs(dz))
            if dz > 0.0 and region == 0:
                i, j = cell_index(param, False, lx, ly, lz, dx, dy, dz, n_theta, n_phi)
                if i >= 0:
                    brdf[i, j, 0] += w0
                    brdf[i, j, 1] += w1
                    brdf[i, j, 2] += w2
                    if squares:
                        brdf_sq[i, j, 0] += w0 * w0
                        brdf_sq[i, j, 1] += w1 * w1
                        brdf_sq[i, j, 2] += w2 * w2
                energy[0, 0] += w0
                energy[0, 1] += w1
                energy[0, 2] += w2
                break
            if dz < 0.0 and region == n_if:
                if base_kind == 0:
                    i, j = cell_index(param, True, lx, ly, lz, dx, dy, dz, n_theta, n_phi)
                    if i >= 0:
                        btdf[i, j, 0] += w0
                        btdf[i, j, 1] += w1
                        btdf[i, j, 2] += w2
                    energy[1, 0] += w0
                    energy[1, 1] += w1
                    energy[1, 2] += w2
                    break
                # Lambertian base
                events += 1
                w0 *= rho[0]
                w1 *= rho[1]
                w2 *= rho[2]
                r = math.sqrt(next_float(state))
                phi = _TWO_PI * next_float(state)
                dx = r * math.cos(phi)
                dy = r * math.sin(phi)
                dz = math.sqrt(max(0.0, 1.0 - r * r))
            else:
                events += 1
                from_above = dz < 0.0
                k = region if from_above else region - 1
                a = alpha[k, 0]
                wx = -dx
                wy = -dy
                wz = -dz if from_above else dz
                mx, my, mz = _vndf(wx, wy, wz, a, next_float(state), next_float(state))
                wm = wx * mx + wy * my + wz * mz
                transmitted = False
                if base_kind == 1 and k == n_if - 1:
                    w0 *= _fresnel_conductor(wm, cond[0], cond[3])
                    w1 *= _fresnel_conductor(wm, cond[1], cond[4])
                    w2 *= _fresnel_conductor(wm, cond[2], cond[5])
                    ox = 2.0 * wm * mx - wx
                    oy = 2.0 * wm * my - wy
                    oz = 2.0 * wm * mz - wz
                else:
                    eta = region_eta[k + 1] / region_eta[k] if from_above else region_eta[k] / region_eta[k + 1]
                    f, ct = _fresnel_dielectric(wm, eta)
                    if next_float(state) < f:
                        ox = 2.0 * wm * mx - wx
                        oy = 2.0 * wm * my - wy
                        oz = 2.0 * wm * mz - wz
                    else:
                        q = wm / eta - ct
                        ox = q * mx - wx / eta
                        oy = q * my - wy / eta
                        oz = q * mz - wz / eta
                        transmitted = True
                if (transmitted and oz >= 0.0) or (not transmitted and oz <= 0.0):
                    break
                g = 1.0 / (1.0 + _lambda(ox, oy, oz, a))
                w0 *= g
                w1 *= g
                w2 *= g
                dx = ox
                dy = oy
                dz = oz if from_above else -oz
                if transmitted:
                    region = k + 1 if from_above else k
            if events >= 3:
                wmax = max(w0, max(w1, w2))
                if wmax < 0.05:
                    if wmax <= 0.0 or next_float(state) >= wmax / 0.05:
                        break
                    p = wmax / 0.05
                    w0 /= p
                    w1 /= p
                    w2 /= p


@numba.njit(cache=True)
def reference_run(alpha, region_eta, region_tau, cond, rho, base_kind, lx, ly, lz, n_rays_total, chunk_rays,
                  seed, incident_index, param, n_theta, n_phi, squares):
    """All chunks of one incident direction on one thread, summed in chunk order: the BRDF and
    BTDF weight sums (n_theta, n_phi, 3), the reflected / transmitted sums (2, 3) and, if
    ``squares``, the BRDF's squared weight sums (n_theta, n_phi, 3; else zeros). Chunk ``c``
    draws from the stream ``(seed, incident_index, c)`` as in the simulator."""
    brdf = np.zeros((n_theta, n_phi, 3))
    btdf = np.zeros((n_theta, n_phi, 3))
    energy = np.zeros((2, 3))
    brdf_sq = np.zeros((n_theta, n_phi, 3))
    hb = np.empty((n_theta, n_phi, 3))
    ht = np.empty((n_theta, n_phi, 3))
    he = np.empty((2, 3))
    n_chunks = (n_rays_total + chunk_rays - 1) // chunk_rays
    for c in range(n_chunks):
        hb[:] = 0.0
        ht[:] = 0.0
        he[:] = 0.0
        state = stream_state(np.uint64(seed), np.uint64(incident_index), np.uint64(c))
        n = min(chunk_rays, n_rays_total - c * chunk_rays)
        reference_chunk(alpha, region_eta, region_tau, cond, rho, base_kind, lx, ly, lz, n, state,
                        param, n_theta, n_phi, hb, ht, he, squares, brdf_sq)
        brdf += hb
        btdf += ht
        energy += he
    return brdf, btdf, energy, brdf_sq


def supported(stack: Stack) -> bool:
    """Whether the yardstick traces ``stack``: isotropic single-scattering interfaces, absorbing
    (non-scattering) media."""
    p = pack(stack)
    return (not np.any(p.if_ms) and bool(np.all(p.if_alpha[:, 0] == p.if_alpha[:, 1]))
            and bool(np.all(p.if_rot[:, 1] == 0.0)) and bool(np.all(p.region_albedo == 0.0))
            and bool(np.all(p.if_alpha[:, 0] > 0.0)))


def trace_reference(stack: Stack, l: tuple[float, float, float], rays: int, param: int, n_theta: int,
                    n_phi: int, seed: int = 1, incident_index: int = 0, chunk_rays: int = 1 << 17,
                    squares: bool = False):
    """Run the yardstick for one light direction ``l`` (unit, pointing to the light);
    returns ``(brdf, btdf, energy, brdf_sq)`` weight sums (divide by ``rays`` for estimates)."""
    if not supported(stack):
        raise ValueError(f"reference kernel: stack {stack.name!r} has a feature the yardstick does not trace")
    p = pack(stack)
    return reference_run(p.if_alpha, p.region_eta, p.region_tau, p.cond, p.rho, p.base_kind,
                         float(l[0]), float(l[1]), float(l[2]), rays, chunk_rays, seed, incident_index,
                         param, n_theta, n_phi, squares)


def issue15_metal() -> Stack:
    """The coated metal of issue 15's goal: alpha0 = 0.05, tau (0.1, 0.2, 0.5), conductor alpha1 = 0.2."""
    from goniometer.stack import Interface, Medium
    return Stack("metal/issue15", (Interface(0.05, (1.5,) * 3), Medium((0.1, 0.2, 0.5)),
                                   Interface(0.2, (1.45,) * 3, (1.0, 0.01, 0.01))), "metal")


def main() -> int:
    ap = argparse.ArgumentParser(description="time the yardstick kernel (or, with --simulator, the simulator's kernel) on issue 15's metal")
    ap.add_argument("--rays", type=int, default=4_000_000)
    ap.add_argument("--simulator", action="store_true", help="time goniometer.run.tasks.trace_incident instead")
    args = ap.parse_args()
    from goniometer.run.settings import SimulationSettings
    from goniometer.grids.slice_grid import light_direction
    stack = issue15_metal()
    numba.set_num_threads(1)
    if args.simulator:
        from goniometer.run.tasks import trace_incident
        s = SimulationSettings(incident_deg=(30.0,), rays=args.rays, parametrization="classic", threads=1, seed=1)
        trace_incident(stack, SimulationSettings(incident_deg=(30.0,), rays=1000, parametrization="classic",
                                                 threads=1), 0)
        c0 = time.process_time()
        trace_incident(stack, s, 0)
    else:
        l = light_direction(30.0, 0.0)
        trace_reference(stack, l, 1000, 0, 90, 360)
        c0 = time.process_time()
        trace_reference(stack, l, args.rays, 0, 90, 360)
    cpu = time.process_time() - c0
    print(f"{'simulator' if args.simulator else 'reference'} {args.rays / cpu / 1e6:.3f} M rays/CPU-s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
