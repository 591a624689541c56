"""What a packed stack is, as the kernels need to know it, worked out once per run
(``docs/kernel.md``, variants; ``docs/gpu.md``, the seam).

:func:`stack_facts` reads a :class:`goniometer.kernel.packing.PackedStack` once: the base's kind, the
interface that is the base, anisotropy per interface, conductor channels that share their complex
index, multiple-scattering and scattering regions, films, the regions' modes
(:func:`goniometer.kernel.layout.tau_modes`) and the relative indices. Everything a kernel knows
about a stack comes from these facts: the lane kernel's variant (:func:`variant_flags`, a
:class:`Variant`) and the arguments of every kernel (:class:`Derived`, in a :data:`KernelStack`,
which :func:`goniometer.kernel.tracer.prepare` makes once per run), so no kernel works a fact out
again and no two kernels disagree about a stack.
"""

from __future__ import annotations

from collections import namedtuple
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from goniometer.kernel.layout import TAU_SCATTER, relative_indices, tau_modes
from goniometer.kernel.packing import BASE_CONDUCTOR, BASE_LAMBERTIAN, BASE_TRANSMIT, PackedStack

#: ``kernel`` of :func:`variant_flags`: the kernel commands use (the lane kernel for every stack),
#: the lane kernel, or the per-path kernel (the second implementation the tests check the lane
#: kernel against)
KERNEL_AUTO = 0
KERNEL_LANES = 1
KERNEL_PATHS = 2


@dataclass(frozen=True, eq=False)
class StackFacts:
    """The facts about a packed stack that select kernel code (see the module docstring).

    ``n_if`` interfaces; ``anisotropic``: some interface is anisotropic or rotated, ``if_aniso``
    per interface (its tangent frame is rotated); ``conductor`` / ``lambertian`` / ``transmit``:
    the base's kind; ``base_k``: the interface that is the base (the bottom layer), -1 for a
    Lambertian base; ``g_is_r`` / ``b_is_g``: a conductor's green channel has red's complex
    index, blue green's; ``multiple_scattering``: some interface walks, ``only_walks``: every
    interface does (the masking setting then changes nothing); ``scattering``: some region
    scatters; ``film``: some interface has a film; ``tau_mode`` per region and ``eta_dn`` /
    ``eta_up`` per interface as :mod:`goniometer.kernel.layout` computes them."""

    packed: PackedStack
    n_if: int
    anisotropic: bool
    if_aniso: np.ndarray
    conductor: bool
    lambertian: bool
    transmit: bool
    base_k: int
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
    lambertian = p.base_kind == BASE_LAMBERTIAN
    c = p.cond
    ms = bool(np.any(p.if_ms[:n_if])) if n_if > 0 else False
    if_aniso = (p.if_alpha[:, 0] != p.if_alpha[:, 1]) | (p.if_rot[:, 1] != 0.0)
    return StackFacts(
        packed=p, n_if=n_if, anisotropic=bool(np.any(if_aniso)), if_aniso=if_aniso,
        conductor=bool(cond), lambertian=bool(lambertian), transmit=p.base_kind == BASE_TRANSMIT,
        base_k=-1 if lambertian else n_if - 1,
        g_is_r=bool(cond and c[1] == c[0] and c[4] == c[3]), b_is_g=bool(cond and c[2] == c[1] and c[5] == c[4]),
        multiple_scattering=ms, only_walks=n_if > 0 and bool(np.all(p.if_ms[:n_if])),
        scattering=bool(np.any(tau_mode >= TAU_SCATTER)), film=p.has_film,
        tau_mode=tau_mode, eta_dn=eta_dn, eta_up=eta_up)


class Variant(NamedTuple):
    """The lane kernel's variant (:func:`variant_flags`): each field None or True. numba
    dispatches on None versus True and prunes the branch of a None *argument*, so the kernels take
    the fields unpacked, as separate arguments (``*variant``), and each variant is compiled (and
    cached) only when some stack needs it. The per-path transport's variant
    (:func:`goniometer.kernel.onepath.trace_path`: the per-path kernel, the CUDA kernel) is its
    ``height_correlated`` and ``film``."""

    lanes: bool | None
    height_correlated: bool | None
    tabulate: bool | None
    media: bool | None
    lambertian: bool | None
    conductor: bool | None
    g_is_r: bool | None
    b_is_g: bool | None
    aniso: bool | None
    ms: bool | None
    film: bool | None


def variant_flags(facts: StackFacts, height_correlated: bool, tabulate: bool, kernel: int = KERNEL_AUTO,
                  polarized: bool = False) -> Variant:
    """The :class:`Variant` of a stack. ``kernel``: ``KERNEL_AUTO`` (the lane kernel),
    ``KERNEL_LANES`` or ``KERNEL_PATHS`` (``lanes`` None: the per-path kernel, whose variants are
    the masking's and the films'). ``polarized``: a polarized run's variant (the lane kernel's is
    general in anisotropy and conductor channels, as a height-correlated one)."""
    if kernel not in (KERNEL_AUTO, KERNEL_LANES, KERNEL_PATHS):
        raise ValueError(f"kernel: {kernel!r} is not one of KERNEL_AUTO, KERNEL_LANES, KERNEL_PATHS")
    f = facts
    # the masking setting concerns single-scattering interfaces only (a walk is height-correlated
    # by construction): without one, both settings trace the same variant, hence the same bits
    height_correlated = height_correlated and f.n_if > 0 and not f.only_walks

    def flag(x: bool):
        return True if x else None

    if kernel == KERNEL_PATHS:
        return Variant(None, flag(height_correlated), None, None, None, None, None, None, None, None, flag(f.film))
    aniso, g_is_r, b_is_g = f.anisotropic, f.g_is_r, f.b_is_g
    if height_correlated or polarized:
        # the rarer masking and polarized light get fewer, more general variants (each is a compile
        # of its own): the tangent-frame rotation (exact for an isotropic stack) and three conductor
        # channels
        aniso = True
        g_is_r = b_is_g = False
    return Variant(True, flag(height_correlated), flag(tabulate), flag(f.scattering), flag(f.lambertian),
                   flag(f.conductor), flag(g_is_r), flag(b_is_g), flag(aniso), flag(f.multiple_scattering),
                   flag(f.film))


class Derived(NamedTuple):
    """What a run derives from its stack once for the kernels (:func:`derive`), after the packed
    arrays in a :data:`KernelStack`: the regions' modes and the relative indices (arrays),
    ``if_aniso`` per interface, the base (``n_if``, ``base_k``, ``transmit_base``,
    ``conductor_base``), the conductor's shared channels (``g_is_r``, ``b_is_g``: the stack's own,
    which walks use whatever the variant), ``any_ms``, and the lane kernel's stack table and the
    offset of its region part (:func:`goniometer.kernel.layout.stack_table`)."""

    tau_mode: np.ndarray
    eta_dn: np.ndarray
    eta_up: np.ndarray
    if_aniso: np.ndarray
    n_if: int
    base_k: int
    transmit_base: bool
    conductor_base: bool
    g_is_r: bool
    b_is_g: bool
    any_ms: bool
    table: np.ndarray
    off: int


#: the kernels' ``stack`` argument (:attr:`goniometer.kernel.tracer.Launch.stack_args`): the packed
#: arrays in :data:`goniometer.kernel.packing.PackedStack.KERNEL_FIELDS` order, then the fields of
#: :class:`Derived`; a named tuple, which numba (CPU and CUDA) reads by field name
KernelStack = namedtuple("KernelStack", PackedStack.KERNEL_FIELDS + Derived._fields)


def derive(facts: StackFacts, table: np.ndarray, off: int) -> Derived:
    """The :class:`Derived` arguments of a stack's facts and the lane kernel's table."""
    f = facts
    return Derived(f.tau_mode, f.eta_dn, f.eta_up, f.if_aniso, int(f.n_if), int(f.base_k), bool(f.transmit),
                   bool(f.conductor), bool(f.g_is_r), bool(f.b_is_g), bool(f.multiple_scattering), table, int(off))
