"""Measured BRDFs as references: a MERL ``.binary`` or an RGL tensor file (``.bsdf``) evaluated
like the renderers read them, and resampled onto the cells of a slices grid so that the harness
judges models against the measurement (``docs/measured.md``).

Conventions: ``l`` towards the light, ``v`` towards the viewer, both pointing away from the surface,
local frame z normal; values are the BRDF without the cosine, 1/sr, RGB last; NaN where the file
has no data (MERL's negative cells).

* MERL: the cell of the (half, difference) angles holding the pair (:mod:`goniometer.grids.halfdiff`),
  its stored value times the channel's scale; nearest cell, no interpolation (the format's own
  reading).
* RGL: the readers' evaluation (``docs/rgl-format.md`` section 3): the half vector through the warp
  of ``l`` (the ``vndf`` slices blended linearly between the incident nodes after normalisation,
  as the readers blend their distributions), the stored values bilinear in ``u`` and blended the
  same way, times ``D / (4 sigma)`` of the bilinear tables, divided by ``cos theta_v``. A spectral
  file is read at 610, 550 and 465 nm as R, G, B (the nodes of the RGB upsampling the export
  states; a measured spectrum is sampled, not integrated, until the project has its colour
  pipeline).

Reading checks the values (``docs/measured.md`` section 1, "What a file must hold"): every number
finite; no reflectance above :data:`MAX_REFLECTANCE` (MERL: the hemispherical reflectance
``sum f mu / pi`` over the cells with data, ``mu`` the cells' measure of :mod:`goniometer.grids.halfdiff`;
RGL: each incident node's mean stored value over the square, which is its directional albedo, the
stored values being ``f cos / p`` for the warp's density ``p``); for RGL no stored value negative
beyond :data:`NEGATIVE_TOLERANCE` of the largest, no negative ``ndf`` or ``vndf`` and a positive
``sigma``. A file that fails is a :class:`MeasuredError` naming the file and what is wrong.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from goniometer.grids import halfdiff
from goniometer.files.merl import MERL_SCALE
from goniometer.files.rgl_tensor import MAGIC, TensorError, read_tensor
from goniometer.grids.warp import Warp2D, bilinear

__all__ = ["MAX_REFLECTANCE", "MERL_SCALE", "NEGATIVE_TOLERANCE", "MeasuredBRDF", "MeasuredError", "measured_kind",
           "measured_reference", "read_measured"]

#: where a spectral tensor file is read as R, G, B (nm)
RGB_NM = (610.0, 550.0, 465.0)
#: the largest reflectance a file's values may imply: a passive material reflects at most the light
#: that reaches it (1); measurement noise and the formats' resampling stay far below twice that
#: (an exported simulation: within 10 %), so a file above it holds broken values (docs/measured.md)
MAX_REFLECTANCE = 2.0
#: an RGL stored value below -NEGATIVE_TOLERANCE x the file's largest is negative beyond rounding and
#: noise (the readers clamp negative values at 0: such a file is broken, not merely noisy)
NEGATIVE_TOLERANCE = 1e-3


class MeasuredError(ValueError):
    """A measured file that cannot be a reference (one line: the file and why)."""


@dataclass
class MeasuredBRDF:
    """A measured BRDF: ``kind`` "merl" or "rgl"; ``incident_deg`` the file's own incident
    elevations (the RGL file's theta_i nodes; None for MERL, which covers every direction);
    ``resampling``: how :meth:`eval` reads the file, as a sentence for reports."""

    path: str
    kind: str
    isotropic: bool
    incident_deg: tuple[float, ...] | None
    resampling: str
    _data: dict = field(default_factory=dict, repr=False)

    def eval(self, l: np.ndarray, v: np.ndarray) -> np.ndarray:
        """f(l, v) for one light direction ``l`` (3,) and directions ``v`` (..., 3): (..., 3)."""
        l = np.asarray(l, dtype=np.float64)
        l = l / np.linalg.norm(l)
        v = np.asarray(v, dtype=np.float64)
        v = v / np.linalg.norm(v, axis=-1, keepdims=True)
        if self.kind == "merl":
            return self._eval_merl(l, v)
        return self._eval_rgl(l, v)

    # ------------------------------------------------------------------ MERL

    def _eval_merl(self, l: np.ndarray, v: np.ndarray) -> np.ndarray:
        cells = halfdiff.cell_indices(np.broadcast_to(l, v.shape), v)
        planes = self._data["planes"]                                   # (3, N_CELLS), 1/sr, NaN: no data
        out = np.zeros(v.shape[:-1] + (3,))
        ok = cells >= 0
        out[ok] = planes[:, cells[ok]].T
        return out

    # ------------------------------------------------------------------ RGL

    def _slice_weights(self, theta: float, phi: float) -> list[tuple[int, int, float]]:
        """(phi index, theta index, weight) of the incident slices blended at (theta, phi)."""
        def bracket(nodes: np.ndarray, x: float) -> list[tuple[int, float]]:
            if len(nodes) == 1:
                return [(0, 1.0)]
            x = min(max(x, float(nodes[0])), float(nodes[-1]))
            k = int(min(np.searchsorted(nodes, x, side="right") - 1, len(nodes) - 2))
            t = (x - nodes[k]) / (nodes[k + 1] - nodes[k])
            return [(k, 1.0 - t), (k + 1, t)]
        th = bracket(self._data["theta_i"], theta)
        ph = bracket(self._data["phi_i"], phi) if not self.isotropic else [(0, 1.0)]
        return [(a, b, wa * wb) for a, wa in ph for b, wb in th if wa * wb > 0]

    def _eval_rgl(self, l: np.ndarray, v: np.ndarray) -> np.ndarray:
        d = self._data
        theta_l = math.atan2(math.hypot(l[0], l[1]), l[2])
        phi_l = math.atan2(l[1] + 0.0, l[0] + 0.0)
        weights = self._slice_weights(theta_l, phi_l)
        dens = sum(w * d["vndf_n"][a, b] for a, b, w in weights)
        values = sum(w * d["values"][a, b] for a, b, w in weights)        # (3, n, n)
        warp = Warp2D.from_density(dens)
        h = l + v
        theta_m = np.arctan2(np.hypot(h[..., 0], h[..., 1]), h[..., 2])
        phi_m = np.arctan2(h[..., 1] + 0.0, h[..., 0] + 0.0) - (phi_l if self.isotropic else 0.0)
        x = np.sqrt(theta_m / (0.5 * math.pi))
        y = np.mod((phi_m + math.pi) / (2.0 * math.pi), 1.0)
        ux, uy = warp.invert(x, y)
        s = np.stack([bilinear(values[c], ux, uy) for c in range(3)], axis=-1)
        D = bilinear(d["ndf"], x, y)
        sig = float(bilinear(d["sigma"], np.array(math.sqrt(theta_l / (0.5 * math.pi))),
                              np.array((phi_l + math.pi) / (2.0 * math.pi))))
        vz = v[..., 2]
        ok = (vz > 0) & (l[2] > 0)
        f = s * (D / (4.0 * sig))[..., None] / np.where(ok, vz, 1.0)[..., None]
        return np.where(ok[..., None], np.maximum(f, 0.0), 0.0)


def measured_kind(path: str | os.PathLike) -> str | None:
    """``"merl"`` (the 90x90x180 header and the format's size) or ``"rgl"`` (the tensor file's magic)
    by content, without reading the values; None for anything else or an unreadable file."""
    p = Path(path)
    try:
        with open(p, "rb") as fh:
            head = fh.read(16)
        size = p.stat().st_size
    except OSError:
        return None
    if head.startswith(MAGIC):
        return "rgl"
    if (len(head) >= 12 and tuple(np.frombuffer(head[:12], dtype="<i4")) == halfdiff.SHAPE
            and size == 12 + 24 * halfdiff.N_CELLS):
        return "merl"
    return None


def read_measured(path: str | os.PathLike) -> MeasuredBRDF:
    """A MERL ``.binary`` or an RGL tensor file, told apart by content (:func:`measured_kind`), its
    values checked (module docstring). Raises :class:`MeasuredError` (one line) for anything else."""
    p = Path(path)
    try:
        p.stat()
    except OSError as e:
        raise MeasuredError(f"{p}: cannot be read ({e.strerror or e})") from None
    kind = measured_kind(p)
    if kind == "rgl":
        return _read_rgl(p)
    n = halfdiff.N_CELLS
    if kind == "merl":
        raw = np.frombuffer(p.read_bytes(), dtype="<f8", offset=12).reshape(3, n)
        planes = raw * np.array(MERL_SCALE)[:, None]
        _check_merl(p, raw, planes)
        planes = np.where(raw < 0, np.nan, planes)
        return MeasuredBRDF(str(p), "merl", True, None,
                            "MERL cells (theta_h, theta_d, phi_d, 90 x 90 x 180), nearest cell; cells without "
                            "data (negative) masked", {"planes": planes})
    raise MeasuredError(f"{p}: neither a MERL .binary (90x90x180 header, {12 + 24 * n:,} bytes) nor an RGL tensor "
                        f"file (.bsdf)")


CHANNELS = ("R", "G", "B")


def _cell(k: int) -> tuple[int, int, int]:
    """The (i_h, i_d, i_p) indices of flat MERL cell ``k``."""
    return tuple(int(x) for x in np.unravel_index(k, halfdiff.SHAPE))


def _check_merl(p: Path, raw: np.ndarray, planes: np.ndarray) -> None:
    """MeasuredError unless every stored value is finite and the cells with data (stored value >= 0)
    reflect at most :data:`MAX_REFLECTANCE` of the light: ``sum f mu / pi`` per channel, the
    hemispherical reflectance of the cells (``mu``: :func:`goniometer.grids.halfdiff.cell_measure`, whose
    sum is ``pi^2``)."""
    bad = ~np.isfinite(raw)
    if bad.any():
        c, k = (int(x[0]) for x in np.nonzero(bad))
        raise MeasuredError(f"{p}: {int(bad.sum()):,} stored value(s) are not finite (NaN or infinite), e.g. "
                            f"{CHANNELS[c]} of cell {_cell(k)} (theta_h, theta_d, phi_d) = "
                            f"{raw[c, k]}: not a BRDF (a cell without data is stored negative)")
    mu = halfdiff.cell_measure().reshape(-1)
    reflectance = np.where(raw >= 0, planes, 0.0) @ mu / math.pi
    worst = int(np.argmax(reflectance))
    if reflectance[worst] > MAX_REFLECTANCE:
        k = int(np.argmax(np.where(raw[worst] >= 0, planes[worst] * mu, 0.0)))
        raise MeasuredError(f"{p}: implausible values: the cells with data reflect {reflectance[worst]:.3g} times the "
                            f"light that reaches them ({CHANNELS[worst]}; a measurement of a passive material "
                            f"reflects at most {MAX_REFLECTANCE:g}), e.g. {planes[worst, k]:.3g} 1/sr in cell "
                            f"{_cell(k)} (theta_h, theta_d, phi_d)")


def _check_rgl(p: Path, f: dict, stored: str) -> None:
    """MeasuredError unless the fields the readers use are finite, ``ndf`` and ``vndf`` not negative,
    ``sigma`` positive, the ``stored`` values (``rgb`` or ``spectra``) not negative beyond
    :data:`NEGATIVE_TOLERANCE` of the largest, and no incident node's directional albedo (the mean
    stored value over the square, trapezoidal in both axes) above :data:`MAX_REFLECTANCE`."""
    names = ["theta_i", "phi_i", "ndf", "sigma", "vndf", stored] + (["wavelengths"] if stored == "spectra" else [])
    for name in names:
        a = np.asarray(f[name], dtype=np.float64)
        bad = ~np.isfinite(a)
        if bad.any():
            raise MeasuredError(f"{p}: field {name}: {int(bad.sum()):,} value(s) are not finite (NaN or infinite), "
                                f"e.g. at index {tuple(int(x[0]) for x in np.nonzero(bad))}: not a BRDF")
    for name in ("ndf", "vndf"):
        if np.min(f[name]) < 0:
            raise MeasuredError(f"{p}: field {name} holds a negative density ({float(np.min(f[name])):.3g})")
    if np.min(f["sigma"]) <= 0:
        raise MeasuredError(f"{p}: field sigma holds {float(np.min(f['sigma'])):.3g}; the projected area must be "
                            f"positive (the readers divide by it)")
    values = np.asarray(f[stored], dtype=np.float64)             # (N_phi_i, N_theta_i, C, n, n)
    top = float(np.max(np.abs(values))) if values.size else 0.0
    if values.size and float(np.min(values)) < -NEGATIVE_TOLERANCE * top:
        raise MeasuredError(f"{p}: field {stored} holds {float(np.min(values)):.3g}, negative beyond rounding (the "
                            f"largest value is {top:.3g}): a BRDF is not negative")
    if values.ndim != 5 or min(values.shape[-2:]) < 2:
        return   # the reader's own shape checks name it
    n_y, n_x = values.shape[-2:]
    wy, wx = np.full(n_y, 1.0 / (n_y - 1)), np.full(n_x, 1.0 / (n_x - 1))
    wy[[0, -1]] *= 0.5
    wx[[0, -1]] *= 0.5
    albedo = np.einsum("abcij,i,j->abc", values, wy, wx)
    a, b, c = np.unravel_index(int(np.argmax(albedo)), albedo.shape)
    if albedo[a, b, c] > MAX_REFLECTANCE:
        theta = math.degrees(float(f["theta_i"][b]))
        what = f"wavelength {float(f['wavelengths'][c]):g} nm" if stored == "spectra" else CHANNELS[c]
        raise MeasuredError(f"{p}: implausible values: at theta_i = {theta:.4g} deg ({what}) the stored values imply a "
                            f"directional albedo of {albedo[a, b, c]:.3g} (their mean over the square; a measurement "
                            f"of a passive material reflects at most {MAX_REFLECTANCE:g}; largest value {top:.3g})")


def _read_rgl(p: Path) -> MeasuredBRDF:
    try:
        t = read_tensor(p)
    except TensorError as e:
        raise MeasuredError(str(e)) from None
    f = t.fields
    need = ("theta_i", "phi_i", "ndf", "sigma", "vndf")
    missing = [k for k in need if k not in f]
    if missing or not ("rgb" in f or ("spectra" in f and "wavelengths" in f)):
        raise MeasuredError(f"{p}: not an RGL BRDF file (missing {', '.join(missing) or 'rgb or spectra'})")
    _check_rgl(p, f, "rgb" if "rgb" in f else "spectra")
    if "rgb" in f:
        values = f["rgb"].astype(np.float64)
        colour = "its rgb field"
    else:
        lam = f["wavelengths"].astype(np.float64)
        spec = f["spectra"].astype(np.float64)                         # (Nphi, Ntheta, L, n, n)
        idx = [np.clip(np.searchsorted(lam, x) - 1, 0, len(lam) - 2) for x in RGB_NM]
        values = np.stack([spec[:, :, k] + (spec[:, :, k + 1] - spec[:, :, k]) * (x - lam[k]) / (lam[k + 1] - lam[k])
                           for k, x in zip(idx, RGB_NM)], axis=2)
        colour = "its spectra read at 610, 550, 465 nm as R, G, B"
    vndf = f["vndf"].astype(np.float64)
    # each slice normalised to a unit integral of its bilinear density, as the readers do before
    # they blend neighbouring slices
    H, W = vndf.shape[2:]
    wx = np.full(W, 1.0 / (W - 1))
    wx[[0, -1]] *= 0.5
    wy = np.full(H, 1.0 / (H - 1))
    wy[[0, -1]] *= 0.5
    total = np.einsum("abkj,k,j->ab", vndf, wy, wx)[:, :, None, None]
    if np.any(total <= 0):
        raise MeasuredError(f"{p}: a vndf slice is empty")
    phi_i = f["phi_i"].astype(np.float64)
    data = {"theta_i": f["theta_i"].astype(np.float64), "phi_i": phi_i, "ndf": f["ndf"].astype(np.float64),
            "sigma": f["sigma"].astype(np.float64), "vndf_n": vndf / total, "values": values}
    iso = phi_i.shape[0] <= 2
    theta_deg = tuple(float(x) for x in np.degrees(data["theta_i"]))
    return MeasuredBRDF(str(p), "rgl", iso, theta_deg,
                        f"the RGL readers' evaluation ({colour}; slices blended linearly between theta_i"
                        + (" and phi_i" if not iso else "") + " nodes)", data)


def measured_reference(measured: MeasuredBRDF, stack, settings, subcells: int = 5):
    """A :class:`goniometer.run.results.SimulationResult` whose BRDF slices are the measurement's cell
    means on the grid of ``settings`` (classic or half; its incident directions): each cell the
    projected-solid-angle weighted mean of ``measured.eval`` over ``subcells`` x ``subcells``
    sub-cells. Cells with a sub-cell without data are masked. Standard errors are unknown (NaN),
    bounce orders too (the measurement is all one order: ``orders`` holds it in the last,
    "K or more" row and the first rows are NaN); energies other than the reflected one are NaN.
    ``extra["measured"]`` says where it comes from and how it was resampled."""
    from goniometer.run.results import SimulationResult, SliceData
    from goniometer.grids.slice_grid import SliceGrid, light_direction
    if settings.parametrization not in ("classic", "half"):
        raise MeasuredError(f"{measured.path}: a measurement is resampled onto classic or half slices")
    nt, nph = settings.resolution
    grid = SliceGrid(settings.parametrization, nt, nph, "reflection")
    M = len(settings.incident_deg)
    value = np.zeros((M, 3, nt, nph))
    mask = np.zeros((M, nt, nph), dtype=bool)
    omega = np.zeros((M, nt, nph))
    for m, (t, ph) in enumerate(zip(settings.incident_deg, settings.incident_phi_deg)):
        light = light_direction(t, ph)
        v, w = grid.subcells(light, subcells)
        f = measured.eval(light, v)                                     # (nt, nph, s, s, 3)
        has = np.all(np.isfinite(f), axis=-1) | (w == 0)
        fw = np.where(np.isfinite(f), f, 0.0) * w[..., None]
        den = w.sum(axis=(2, 3))
        value[m] = np.moveaxis(np.divide(fw.sum(axis=(2, 3)), den[..., None], out=np.zeros(den.shape + (3,)),
                                         where=den[..., None] > 0), -1, 0)
        mask[m] = grid.mask(light, subcells) & np.all(has, axis=(2, 3)) & (den > 0)
        omega[m] = grid.proj_solid_angle(light)
    K = settings.max_order
    orders = np.full((M, K, 3, nt, nph), np.nan)
    orders[:, -1] = value
    unknown = np.full_like(value, np.nan)
    brdf = SliceData(grid, value, unknown, orders, mask, omega, unknown.copy())
    refl = np.einsum("mcij,mij->mc", value, omega * mask)
    nan = np.full((M, 3), np.nan)
    energy = {"reflected": refl, "transmitted": nan.copy(), "absorbed": nan.copy(), "masking_loss": nan.copy()}
    return SimulationResult(
        stack=stack, settings=settings, theta_deg=np.array(settings.incident_deg),
        phi_deg=np.array(settings.incident_phi_deg), brdf=brdf, btdf=None, energy=energy,
        energy_stderr={k: nan.copy() for k in energy}, roulette=np.zeros((M, 3)), capped=np.zeros((M, 3)),
        capped_paths=np.zeros(M, dtype=np.int64), mean_events=np.full(M, np.nan), elapsed_s=np.zeros(M), threads=1,
        extra={"measured": {"file": measured.path, "kind": measured.kind, "resampling": measured.resampling,
                            "subcells": subcells}})
