"""What a packed stack is, as the kernels need to know it, worked out once per run
(``docs/kernel.md``, variants; ``docs/gpu.md``, the seam).

:func:`stack_facts` reads a :class:`goniometer.kernel.packing.PackedStack` once: anisotropy, conductor
channels that share their complex index, multiple-scattering and scattering regions, films, the
regions' modes (:func:`goniometer.kernel.layout.tau_modes`) and the relative indices. The lane
kernel's variant arguments (:func:`variant_flags`, what :func:`goniometer.kernel.tracer.kernel_flags`
returns) and the CUDA kernel's table both come from these facts, so the two never disagree about a
stack.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from goniometer.kernel.layout import TAU_SCATTER, relative_indices, tau_modes
from goniometer.kernel.packing import BASE_CONDUCTOR, BASE_LAMBERTIAN, PackedStack

#: ``kernel`` of :func:`variant_flags`: the kernel commands use (the lane kernel for every stack),
#: the lane kernel, or the per-path kernel (the second implementation the tests check the lane
#: kernel against)
KERNEL_AUTO = 0
KERNEL_LANES = 1
KERNEL_PATHS = 2


@dataclass(frozen=True, eq=False)
class StackFacts:
    """The facts about a packed stack that select kernel code (see the module docstring).

    ``n_if`` interfaces; ``anisotropic``: some interface is anisotropic or rotated;
    ``conductor`` / ``lambertian``: the base's kind; ``g_is_r`` / ``b_is_g``: a conductor's green
    channel has red's complex index, blue green's; ``multiple_scattering``: some interface walks,
    ``only_walks``: every interface does (the masking setting then changes nothing);
    ``scattering``: some region scatters; ``film``: some interface has a film; ``tau_mode`` per
    region and ``eta_dn`` / ``eta_up`` per interface as :mod:`goniometer.kernel.layout` computes
    them."""

    packed: PackedStack
    n_if: int
    anisotropic: bool
    conductor: bool
    lambertian: bool
    g_is_r: bool
    b_is_g: bool
    multiple_scattering: bool
    only_walks: bool
    scattering: bool
    film: bool
    tau_mode: np.ndarray
    eta_dn: np.ndarray
    eta_up: np.ndarray


def stack_facts(packed: PackedStack) -> StackFacts:
    """The :class:`StackFacts` of ``packed``."""
    p = packed
    n_if = p.region_eta.shape[0] - 1
    tau_mode = tau_modes(p.region_tau, p.region_albedo)
    eta_dn, eta_up = relative_indices(p.region_eta)
    cond = p.base_kind == BASE_CONDUCTOR
    c = p.cond
    ms = bool(np.any(p.if_ms[:n_if])) if n_if > 0 else False
    return StackFacts(
        packed=p, n_if=n_if,
        anisotropic=bool(np.any(p.if_alpha[:, 0] != p.if_alpha[:, 1]) or np.any(p.if_rot[:, 1] != 0.0)),
        conductor=bool(cond), lambertian=p.base_kind == BASE_LAMBERTIAN,
        g_is_r=bool(cond and c[1] == c[0] and c[4] == c[3]), b_is_g=bool(cond and c[2] == c[1] and c[5] == c[4]),
        multiple_scattering=ms, only_walks=n_if > 0 and bool(np.all(p.if_ms[:n_if])),
        scattering=bool(np.any(tau_mode >= TAU_SCATTER)), film=p.has_film,
        tau_mode=tau_mode, eta_dn=eta_dn, eta_up=eta_up)


def variant_flags(facts: StackFacts, height_correlated: bool, tabulate: bool, kernel: int = KERNEL_AUTO) -> tuple:
    """The variant arguments of :func:`goniometer.kernel.tracer.trace_batch`, each None or True:
    ``(lanes, height_correlated, tabulate, media, lambertian, conductor, g_is_r, b_is_g, aniso, ms,
    film)``. ``kernel``: ``KERNEL_AUTO`` (the lane kernel), ``KERNEL_LANES`` or ``KERNEL_PATHS``.
    numba dispatches on None versus bool, so each variant is compiled (and cached) only when some
    stack needs it."""
    if kernel not in (KERNEL_AUTO, KERNEL_LANES, KERNEL_PATHS):
        raise ValueError(f"kernel: {kernel!r} is not one of KERNEL_AUTO, KERNEL_LANES, KERNEL_PATHS")
    f = facts
    # the masking setting concerns single-scattering interfaces only (a walk is height-correlated
    # by construction): without one, both settings trace the same variant, hence the same bits
    height_correlated = height_correlated and f.n_if > 0 and not f.only_walks

    def flag(x: bool):
        return True if x else None

    if kernel == KERNEL_PATHS:
        # the per-path kernel has no variants but the masking's (one compiled kernel per masking)
        return None, flag(height_correlated), None, None, None, None, None, None, None, None, None
    aniso, g_is_r, b_is_g = f.anisotropic, f.g_is_r, f.b_is_g
    if height_correlated:
        # the rarer masking gets fewer, more general variants (each is a compile of its own): the
        # tangent-frame rotation (exact for an isotropic stack) and three conductor channels
        aniso = True
        g_is_r = b_is_g = False
    return (True, flag(height_correlated), flag(tabulate), flag(f.scattering), flag(f.lambertian),
            flag(f.conductor), flag(g_is_r), flag(b_is_g), flag(aniso), flag(f.multiple_scattering), flag(f.film))
