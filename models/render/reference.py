"""The reference of a rendering: a BSDF ``f(l, v)`` read from a simulated file (``docs/render.md``).

* A **slices file** (``goniometer.slices``, ``docs/slices-format.md``): the file's incident
  directions are interpolated linearly in ``theta_l`` at fixed slice coordinates
  (:mod:`models.render.incidents`: the outgoing direction ``v`` for classic slices, the half
  vector for half slices, as Bati 2019 §3.2 renders its slices), and each slice bilinearly in its
  own parametrisation between cell centres (``theta`` or the square-root row index, and ``phi``,
  periodic; constant beyond the first and last row centres). Masked cells are left out and the
  weights of the others renormalised; a pair whose samples are all masked, or whose light lies
  outside the recorded elevations ``[theta_min, theta_max]``, has no value (NaN). Slices at the
  same elevation (other azimuths) are averaged: the material is isotropic.
* A **tabulated file** (``gonio tabulate``): ``goniometer.files.tabulated.read_tabulated(path).eval(l, v)``
  (:func:`tabulated_reference`, the one place that knows that format).

Only isotropic stacks are rendered. Slabs (stacks that transmit) are rendered from their BTDF.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from goniometer.files import slices as store
from goniometer.run.results import SimulationResult
from goniometer.stack import Interface, Stack
from models.evaluation import comparison_side
from models.render.incidents import align, bracket, half_vector
from models.render.sphere import BSDF, RenderError

SLICES_FORMAT = "goniometer.slices"
#: the root ``format`` attribute of ``gonio tabulate`` files
TABULATED_FORMAT = "goniometer.tabulated"
_TWO_PI = 2.0 * np.pi


@dataclass
class Reference:
    """A rendering reference: the stack, the side shown, the BSDF and what the caption says of it."""

    stack: Stack
    side: str
    #: None when only cached images of it are at hand (the report's sphere cache)
    bsdf: BSDF | None
    #: e.g. "slices interpolated between theta_l = 0, 15, ..., 80 deg (half parametrisation)"
    description: str
    #: recorded light elevations (degrees) the BSDF is defined between, or None (the whole range)
    theta_range_deg: tuple[float, float] | None = None


def _check_isotropic(stack: Stack, where: str) -> None:
    for i, x in enumerate(stack.layers):
        if isinstance(x, Interface) and x.is_anisotropic:
            raise RenderError(f"{where}: layers[{i}] is anisotropic; spheres are rendered for isotropic "
                              f"materials only (the slices do not cover the light azimuths a sphere needs)")


class SlicesBSDF:
    """``f(l, v)`` interpolated from the slices of one side of a simulated result (module docstring)."""

    def __init__(self, result: SimulationResult, side: str, cells: np.ndarray | None = None) -> None:
        """``cells``: what to interpolate instead of the side's ``value``, (M, N, n_theta, n_phi) for
        any N (e.g. a polarized file's Stokes columns, :mod:`models.render.stokes`); the call then
        returns (P, N)."""
        sd = result.brdf if side == "brdf" else result.btdf
        if sd is None:
            raise RenderError(f"{result.stack.name}: the file has no {side.upper()} slices")
        self.grid = sd.grid
        self.transmission = side == "btdf"
        self.value = np.asarray(sd.value if cells is None else cells, dtype=np.float64)
        self.mask = np.asarray(sd.mask, dtype=bool)
        self.phi = np.radians(np.asarray(result.phi_deg, dtype=np.float64))
        rounded = np.round(np.asarray(result.theta_deg, dtype=np.float64), 9)
        #: the recorded elevations (degrees, ascending) and in radians
        self.nodes_deg = np.unique(rounded)
        self.nodes = np.radians(self.nodes_deg)
        if len(self.nodes) < 2:
            raise RenderError(f"{result.stack.name}: the file has one incident elevation "
                              f"({self.nodes_deg[0]:g} deg); a lit sphere needs at least two to "
                              f"interpolate between (simulate with e.g. --incident 0,15,30,45,60,70,80)")
        self.groups = [np.flatnonzero(rounded == t) for t in self.nodes_deg]

    def coordinates(self, theta_l: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Polar and azimuthal slice coordinates (radians) of ``v`` (aligned: light azimuth 0):
        of ``v`` for classic slices, of the half vector for half slices."""
        if self.grid.parametrization == "classic":
            d = v * np.array([1.0, 1.0, -1.0]) if self.transmission else v
        else:
            l = np.stack([np.sin(theta_l), np.zeros_like(theta_l), np.cos(theta_l)], axis=-1)
            d = half_vector(l, v, self.transmission)
        th = np.arccos(np.clip(d[:, 2], -1.0, 1.0))
        ph = np.mod(np.arctan2(d[:, 1] + 0.0, d[:, 0] + 0.0), _TWO_PI)
        return th, ph

    def sample(self, m: int, th: np.ndarray, ph: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bilinear sample of slice ``m`` at slice coordinates ``(th, ph)`` (``ph`` relative to the
        slice's light azimuth): ``(sum of weight x value (N, 3), sum of weights (N,))`` over the
        unmasked corners (``(N, C)`` for cells of C channels)."""
        nt, nph = self.grid.n_theta, self.grid.n_phi
        if self.grid.parametrization == "classic":
            u = th / (0.5 * np.pi) * nt - 0.5
        else:
            u = np.sqrt(np.clip(th, 0.0, None) / (0.5 * np.pi)) * nt - 0.5
        w = np.mod(ph + self.phi[m], _TWO_PI) / _TWO_PI * nph - 0.5
        i0 = np.floor(u)
        a = u - i0
        r0 = np.clip(i0.astype(np.int64), 0, nt - 1)
        r1 = np.clip(i0.astype(np.int64) + 1, 0, nt - 1)
        j = np.floor(w)
        b = w - j
        j0 = np.mod(j.astype(np.int64), nph)
        j1 = np.mod(j0 + 1, nph)
        acc = np.zeros((len(th), self.value.shape[1]))
        wsum = np.zeros(len(th))
        value, mask = self.value[m], self.mask[m]
        for r, c, wt in ((r0, j0, (1 - a) * (1 - b)), (r0, j1, (1 - a) * b), (r1, j0, a * (1 - b)), (r1, j1, a * b)):
            wt = np.where(mask[r, c], wt, 0.0)
            acc += wt[:, None] * value[:, r, c].T
            wsum += wt
        return acc, wsum

    def __call__(self, l: np.ndarray, v: np.ndarray) -> np.ndarray:
        theta_l, vr = align(l, v)
        th, ph = self.coordinates(theta_l, vr)
        k0, k1, t, inside = bracket(theta_l, self.nodes)
        acc = np.zeros((len(theta_l), self.value.shape[1]))
        wsum = np.zeros(len(theta_l))
        for k, group in enumerate(self.groups):
            weight = np.where(k0 == k, 1.0 - t, 0.0) + np.where(k1 == k, t, 0.0)
            sel = np.flatnonzero(weight > 0.0)
            if not len(sel):
                continue
            for m in group:
                a, w = self.sample(int(m), th[sel], ph[sel])
                share = weight[sel] / len(group)
                acc[sel] += share[:, None] * a
                wsum[sel] += share * w
        out = np.full_like(acc, np.nan)
        ok = (wsum > 0.0) & inside
        out[ok] = acc[ok] / wsum[ok, None]
        return out


def slices_reference(result: SimulationResult, where: str | None = None) -> Reference:
    """The reference of a simulated result: its BRDF, or its BTDF for a stack that transmits."""
    where = where or result.stack.name
    if result.settings.parametrization == "rgl":
        raise RenderError(f"{where}: recorded on the RGL grid (for gonio export --format rgl); a sphere is drawn "
                          f"from classic or half slices or a tabulated file")
    _check_isotropic(result.stack, where)
    side = comparison_side(result.stack)
    f = SlicesBSDF(result, side)
    degs = f.nodes_deg
    listed = ", ".join(f"{d:g}" for d in degs)
    desc = (f"{side.upper()} slices interpolated between θ_l = {listed}° "
            f"({f.grid.parametrization} slices, {f.grid.n_theta}×{f.grid.n_phi})")
    return Reference(result.stack, side, f, desc, (float(degs[0]), float(degs[-1])))


def file_format(path: str | Path) -> str:
    """The root ``format`` attribute of an HDF5 file; RenderError if it is not a readable HDF5 file."""
    try:
        with h5py.File(path, "r") as fh:
            fmt = fh.attrs.get("format")
    except OSError as e:
        raise RenderError(f"{path}: not a readable HDF5 file ({e})") from None
    if isinstance(fmt, bytes):
        fmt = fmt.decode()
    return "" if fmt is None else str(fmt)


def tabulated_reference(path: str | Path) -> Reference:
    """The reference of a tabulated file (``gonio tabulate``): the one place that knows that format.

    Uses ``goniometer.files.tabulated.read_tabulated(path)``: its ``eval(l, v)`` lookup and its stack."""
    try:
        from goniometer.files.tabulated import TabulatedError, read_tabulated
    except ImportError:
        raise RenderError(f"{path}: a tabulated BRDF file ({TABULATED_FORMAT}), but this installation has no "
                          f"reader for it (goniometer.files.tabulated); render a slices file instead") from None
    try:
        table = read_tabulated(path).rgb()   # a spectral table in linear sRGB (docs/spectral.md section 4)
    except TabulatedError as e:
        raise RenderError(str(e)) from None
    stack = table.stack
    _check_isotropic(stack, str(path))
    return Reference(stack, "brdf", lambda l, v: np.asarray(table.eval(l, v), dtype=np.float64),
                     "tabulated BRDF (MERL half/difference grid, value of the cell holding each pair)", None)


def open_reference(path: str | Path) -> Reference:
    """The reference of ``path``: a slices file or a tabulated file (told apart by the root
    ``format`` attribute); RenderError naming the file otherwise."""
    fmt = file_format(path)
    if fmt == TABULATED_FORMAT:
        return tabulated_reference(path)
    if fmt != SLICES_FORMAT:
        raise RenderError(f"{path}: format {fmt or 'missing'!r} is neither a slices file ({SLICES_FORMAT}) "
                          f"nor a tabulated file ({TABULATED_FORMAT})")
    try:
        result = store.read(path)
    except store.StoreError as e:
        raise RenderError(str(e)) from None
    return slices_reference(result.rgb(), str(path))   # a spectral file is rendered in linear sRGB (docs/spectral.md)
