"""A stack as the kernels read it: flat arrays (:class:`PackedStack`, :func:`pack`), the base kinds
(``BASE_*``) and the thin films' columns (``FILM_COLS``, ``FL_*``); ``docs/kernel.md``.

Regions are numbered 0 (air) .. n_if; interface k separates region k (above) from region k + 1
(below). A stack packs once per run (:func:`goniometer.kernel.tracer.prepare`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from goniometer.kernel.codegen import STACK_BLOCK
from goniometer.kernel.layout import IF_STRIDE, RG_STRIDE
from goniometer.stack import Interface, Lambertian, Medium, Stack, StackError

__all__ = ["BASE_CONDUCTOR", "BASE_LAMBERTIAN", "BASE_TRANSMIT", "FILM_COLS", "FL_DL0", "FL_K0", "FL_KB0", "FL_N0",
           "FL_NA", "FL_NB0", "FL_ON", "MAX_FILM_INTERFACES", "PackedStack", "check_films", "pack"]

#: base kinds in the packed form (``PackedStack.base_kind``)
BASE_TRANSMIT = 0
BASE_CONDUCTOR = 1
BASE_LAMBERTIAN = 2


@dataclass(frozen=True)
class PackedStack:
    """Flat arrays the tracer reads. Regions are numbered 0 (air) .. n_if; interface k
    separates region k (above) from region k + 1 (below).

    ``if_alpha[k] = (alpha_x, alpha_y)``; ``if_rot[k] = (cos, sin)`` of the tangent-frame rotation;
    ``region_eta[r]`` real index; ``region_tau[r]`` RGB extinction optical depth (region 0 and a
    semi-infinite bottom region have 0); ``region_albedo[r]`` RGB scattering albedo and
    ``region_g[r]`` Henyey-Greenstein asymmetry (both 0 where nothing scatters, see
    :attr:`Medium.scatters`); ``cond[0:3]``/``cond[3:6]`` the conductor's complex index
    **relative** to the region above it; ``rho`` the Lambertian albedo; ``base_kind`` one of
    ``BASE_*``; ``if_ms[k]`` True where interface k scatters multiply (Heitz et al. 2016);
    ``if_film[k]`` the thin film of interface k, :data:`FILM_COLS` columns (``FL_*``; all 0 where
    it has none, or one of thickness 0, which is optically absent).
    """

    if_alpha: np.ndarray
    if_rot: np.ndarray
    region_eta: np.ndarray
    region_tau: np.ndarray
    cond: np.ndarray
    rho: np.ndarray
    base_kind: int
    region_albedo: np.ndarray
    region_g: np.ndarray
    if_ms: np.ndarray
    if_film: np.ndarray

    #: the order in which every kernel takes the packed arrays (the CPU kernels' leading arguments,
    #: the CUDA kernel's too: one order in one place, beside the event's table,
    #: :func:`goniometer.kernel.layout.stack_table`)
    KERNEL_FIELDS: ClassVar[tuple[str, ...]] = ("if_alpha", "if_rot", "if_ms", "if_film", "region_eta", "region_tau",
                                                "region_albedo", "region_g", "cond", "rho", "base_kind")

    @property
    def has_film(self) -> bool:
        """True when some interface carries a film (of thickness > 0)."""
        return bool(np.any(self.if_film[:, FL_ON] != 0.0))

    def as_tuple(self) -> tuple:
        """The packed arrays as the kernels take them (the first fields of
        :data:`goniometer.kernel.variants.KernelStack`), in
        :data:`KERNEL_FIELDS` order."""
        return tuple(getattr(self, f) for f in self.KERNEL_FIELDS)


#: columns of ``PackedStack.if_film`` per interface: 1.0 where a film is present; the film's thickness
#: in vacuum wavelengths of each channel (``d / lambda_c``); its absolute index ``n + i k`` per
#: channel; the absolute (real) index of the region above the interface; the absolute index of the
#: medium below per channel (a dielectric's, ``k = 0``, or the conductor's)
FILM_COLS = 17
FL_ON = 0
FL_DL0 = 1
FL_N0 = 4
FL_K0 = 7
FL_NA = 10
FL_NB0 = 11
FL_KB0 = 14
#: most interfaces a stack with a film may have: the event's table (``docs/kernel.md``), a block of
#: :data:`~goniometer.kernel.codegen.STACK_BLOCK` numbers, holds per interface its row and its film's
#: columns, and per region (one more than interfaces) the region's row
MAX_FILM_INTERFACES = (STACK_BLOCK - RG_STRIDE) // (IF_STRIDE + FILM_COLS + RG_STRIDE)


def check_films(stack: Stack) -> None:
    """Raise :class:`StackError` if a film of thickness > 0 is in a stack that is not one wavelength
    triple of a spectral run (``wavelengths_nm`` None), or in one with too many interfaces."""
    n_if = len(stack.interfaces)
    for i, x in enumerate(stack.layers):
        if isinstance(x, Interface) and x.film is not None and x.film.thickness_nm > 0.0:
            if stack.wavelengths_nm is None:
                raise StackError(f"layers[{i}].film: a thin film needs a spectral run (its colours come from "
                                 f"interference at wavelengths; give --spectral)")
            if n_if > MAX_FILM_INTERFACES:
                raise StackError(f"layers: {n_if} interfaces; a stack with a thin film may have at most "
                                 f"{MAX_FILM_INTERFACES}")


def pack(stack: Stack) -> PackedStack:
    """Pack a stack into the flat arrays of :class:`PackedStack` (a film needs the stack's
    wavelengths: :func:`check_films`)."""
    check_films(stack)
    ifs = stack.interfaces
    n = len(ifs)
    if_film = np.zeros((max(n, 1), FILM_COLS))
    if_alpha = np.zeros((max(n, 1), 2))
    if_rot = np.zeros((max(n, 1), 2))
    if_rot[:, 0] = 1.0
    if_ms = np.zeros(max(n, 1), dtype=np.bool_)
    region_eta = np.ones(n + 1)
    region_tau = np.zeros((n + 1, 3))
    region_albedo = np.zeros((n + 1, 3))
    region_g = np.zeros(n + 1)
    cond = np.zeros(6)
    rho = np.zeros(3)
    region = 0
    k = 0
    for layer in stack.layers:
        if isinstance(layer, Interface):
            if_alpha[k] = layer.alpha_xy
            if layer.is_anisotropic:
                psi = np.radians(layer.rotation_deg)
                if_rot[k] = (np.cos(psi), np.sin(psi))
            if_ms[k] = layer.multiple_scattering
            if layer.is_conductor:
                above = region_eta[region]
                cond[0:3] = np.asarray(layer.ior) / above
                cond[3:6] = np.asarray(layer.extinction) / above
            else:
                region_eta[region + 1] = layer.ior[0]
            f = layer.film
            # (a film of thickness 0 is optically absent: the bare interface, bit for bit)
            if f is not None and f.thickness_nm > 0.0:
                row = if_film[k]
                row[FL_ON] = 1.0
                row[FL_DL0:FL_DL0 + 3] = f.thickness_nm / np.asarray(stack.wavelengths_nm, dtype=float)
                row[FL_N0:FL_N0 + 3] = f.ior
                row[FL_K0:FL_K0 + 3] = f.extinction
                row[FL_NA] = region_eta[region]
                row[FL_NB0:FL_NB0 + 3] = layer.ior if layer.is_conductor else (layer.ior[0],) * 3
                row[FL_KB0:FL_KB0 + 3] = layer.extinction if layer.is_conductor else (0.0,) * 3
            region += 1
            k += 1
        elif isinstance(layer, Medium):
            region_tau[region] = layer.optical_depth
            if layer.scatters:
                region_albedo[region] = layer.scattering_albedo
                region_g[region] = layer.g
        else:
            rho[:] = layer.albedo
    last = stack.layers[-1]
    if isinstance(last, Lambertian):
        base = BASE_LAMBERTIAN
    elif last.is_conductor:
        base = BASE_CONDUCTOR
    else:
        base = BASE_TRANSMIT
    return PackedStack(if_alpha, if_rot, region_eta, region_tau, cond, rho, base, region_albedo, region_g, if_ms,
                       if_film)
