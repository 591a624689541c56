"""A run recorded on the RGL grid to the tensor files Mitsuba 3's and pbrt-v4's ``measured``
materials read (``docs/rgl-format.md``, export).

The run's ``/brdf/value`` at node ``u`` of incident direction ``l`` estimates the energy per unit
sample-space area of the node's dual cell, ``int_cell f cos theta_o dw_o / |cell|``. The readers
evaluate ``f cos theta_o = S(u) D(h) / (4 sigma(l))`` with ``D`` and ``sigma`` their bilinear tables,
while the warp they build from ``vndf`` (also bilinear) has its own density ``p(w_o)``; near the
normal (``x -> 0``) the two differ most. So the stored value is the estimate divided by the dual
cell's mean of ``D / (4 sigma p)`` (sub-points above the horizon): then the readers' product gives
``f cos theta_o`` back wherever ``S`` is smooth over a cell. The rows ``u_y = 0`` and ``u_y = 1`` are
the two halves of the cell at the seam ``phi = +-pi`` (the readers wrap one to the other): both get
their area-weighted mean. At normal incidence an isotropic material's rows (u_y) are one azimuth-free
set: each holds their mean. Nodes whose dual cell lies wholly below the horizon get the mean of their
filled neighbours (the readers interpolate into them).

Colour: from an RGB run, the RGB file holds the run's channels and the spectral file's ``spectra``
are the RGB values upsampled piecewise linearly through B at 465 nm, G at 550 nm and R at 610 nm,
constant beyond (a grey stays flat, values stay within their channels' range), on 360-830 nm in
10 nm steps. From a spectral run (``docs/spectral.md``) the spectral file holds the traced spectra
at the run's bin centres, and the RGB file their linear sRGB (D65), negative values (outside the
sRGB gamut) clipped to 0; ``luminance`` is then the CIE Y of the bins.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np

import goniometer
from goniometer.grids.rgl import VALID_SUB, RGLGrid
from goniometer.files.rgl_tensor import TensorFile, write_tensor
from goniometer.grids.warp import bilinear

__all__ = ["ExportError", "WAVELENGTHS_NM", "bsdf_fields", "check_readers", "export_rgl", "fields_from_spectra",
           "fields_from_values", "rgb_to_spectrum", "stored_values"]

#: the spectral file's wavelengths (the visible range pbrt-v4 samples, 360-830 nm)
WAVELENGTHS_NM = np.arange(360.0, 831.0, 10.0)
#: where the RGB channels sit on the wavelength axis of the stated upsampling
CHANNEL_NM = (610.0, 550.0, 465.0)
#: Rec. 709 luminance of linear RGB (the luminance field: importance sampling only)
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


class ExportError(ValueError):
    """A file that cannot be exported to the RGL format (the message says why)."""


def rgb_to_spectrum(rgb: np.ndarray, wavelengths_nm: np.ndarray = WAVELENGTHS_NM) -> np.ndarray:
    """(..., 3) linear RGB -> (..., n_lambda) by the stated piecewise-linear upsampling."""
    rgb = np.asarray(rgb, dtype=np.float64)
    xs = np.array(CHANNEL_NM[::-1])                  # 465, 550, 610: B, G, R
    lam = np.clip(np.asarray(wavelengths_nm, dtype=np.float64), xs[0], xs[-1])
    j = np.clip(np.searchsorted(xs, lam, side="right") - 1, 0, 1)
    t = (lam - xs[j]) / (xs[j + 1] - xs[j])
    bgr = rgb[..., ::-1]
    return bgr[..., j] * (1.0 - t) + bgr[..., j + 1] * t


def _inverse_correction(grid: RGLGrid, m: int) -> np.ndarray:
    """Per node of incident ``m``: the mean over its dual cell's sub-points above the horizon of
    ``D_tab(h) / (4 sigma_tab(l) p(w_o))``, the readers' density proxy over the warp's true one
    (0 where no sub-point is above the horizon)."""
    n, s = grid.n, VALID_SUB
    tab = grid.tables()
    edges = np.clip((np.arange(n + 1) - 0.5) / (n - 1), 0.0, 1.0)
    width = np.diff(edges)
    sub = edges[:-1, None] + width[:, None] * (np.arange(s) + 0.5)[None, :] / s
    ux = np.broadcast_to(sub[None, :, None, :], (n, n, s, s))
    uy = np.broadcast_to(sub[:, None, :, None], (n, n, s, s))
    warp = grid.warp(m)
    x, y = warp.sample(ux, uy)
    h, v = grid.node_directions(m, ux, uy)
    l = grid.light(m)
    theta_m = 0.5 * math.pi * x * x
    jac = 2.0 * math.pi ** 2 * x * np.sin(theta_m)
    cos_lh = np.maximum(h @ l, 0.0)
    p = warp.pdf(x, y) / np.maximum(jac * 4.0 * cos_lh, 1e-300)
    # the readers' D at the half vector's absolute azimuth, sigma at the light's
    phi_abs = np.arctan2(h[..., 1], h[..., 0])
    D = bilinear(tab["ndf"].astype(np.float64), np.sqrt(theta_m / (0.5 * math.pi)), (phi_abs + math.pi) / (2.0 * math.pi))
    th_l = math.acos(min(1.0, l[2]))
    ph_l = math.atan2(l[1], l[0])
    S = float(bilinear(tab["sigma"].astype(np.float64), np.array(math.sqrt(th_l / (0.5 * math.pi))), np.array((ph_l + math.pi) / (2.0 * math.pi))))
    ratio = np.where(p > 0, D / (4.0 * S * np.where(p > 0, p, 1.0)), 0.0)
    ok = v[..., 2] > 0.0
    count = ok.sum(axis=(2, 3))
    return np.where(count > 0, np.sum(np.where(ok, ratio, 0.0), axis=(2, 3)) / np.maximum(count, 1), 0.0)


def _fill(values: np.ndarray, known: np.ndarray) -> np.ndarray:
    """``values`` (C, n, n) with the nodes not ``known`` (n, n) set to the mean of their known or
    filled 4-neighbours, ring after ring."""
    v = values.copy()
    k = known.copy()
    if not k.any():
        return np.zeros_like(v)
    while not k.all():
        acc = np.zeros_like(v)
        cnt = np.zeros(k.shape)
        for dy, dx in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            kk = np.roll(k, (dy, dx), axis=(0, 1))
            vv = np.roll(v, (dy, dx), axis=(1, 2))
            # no wrap-around at the square's edges
            if dy == 1:
                kk[0, :] = False
            if dy == -1:
                kk[-1, :] = False
            if dx == 1:
                kk[:, 0] = False
            if dx == -1:
                kk[:, -1] = False
            acc += np.where(kk, vv, 0.0)
            cnt += kk
        new = (~k) & (cnt > 0)
        v[:, new] = acc[:, new] / cnt[new]
        k = k | new
    return v


def stored_values(grid: RGLGrid, value: np.ndarray) -> np.ndarray:
    """The stored values ``S`` (N_phi_i, N_theta_i, 3, n, n) of estimates ``value`` (M, 3, n, n) on
    ``grid`` (a run's ``/brdf/value``): corrected to the readers' density and filled below the
    horizon (module docstring); for an anisotropic grid the slice at phi_i = 180 deg repeats the one
    at -180 deg."""
    n_t = len(grid.theta_i_deg)
    n_sim = len(grid.simulated_phi_deg())
    out = np.empty((len(grid.phi_i_deg), n_t, value.shape[1], grid.n, grid.n))
    for m in range(value.shape[0]):
        area, _ = grid.cell_geometry(m)
        inv = _inverse_correction(grid, m)
        known = (area > 0) & (inv > 0)
        s = np.where(known, value[m] / np.where(known, inv, 1.0), 0.0)
        # rows u_y = 0 and 1 are the two halves of the cell at the seam phi = +-pi (one set of
        # directions; the readers wrap u_y = 1 to 0): both hold their area-weighted mean
        w0, w1 = area[0] * known[0], area[-1] * known[-1]
        both = w0 + w1 > 0
        seam = np.where(both, (s[:, 0] * w0 + s[:, -1] * w1) / np.where(both, w0 + w1, 1.0), 0.0)
        s[:, 0] = np.where(both, seam, s[:, 0])
        s[:, -1] = np.where(both, seam, s[:, -1])
        known[0] |= both
        known[-1] |= both
        a, b = divmod(m, n_t)
        if grid.isotropic and grid.theta_i_deg[b] == 0.0:
            # an isotropic BRDF at normal incidence does not depend on the azimuth, nor S on u_y (the
            # slice's warp is uniform in y): every row holds the rows' area-weighted mean (noise / n,
            # and the readers' pole, whose azimuth is undefined, reads the same whatever it takes)
            w = area * known
            tot = w.sum(axis=0)
            col = np.where(tot > 0, (s * w).sum(axis=1) / np.where(tot > 0, tot, 1.0), 0.0)   # (3, n)
            s = np.broadcast_to(col[:, None, :], s.shape).copy()
            known = np.broadcast_to(tot > 0, known.shape).copy()
        out[a, b] = _fill(np.maximum(s, 0.0), known)
    if not grid.isotropic:
        out[n_sim] = out[0]
    return out


def bsdf_fields(result, spectral: bool = False, description: str | None = None) -> dict[str, np.ndarray]:
    """The fields of the RGB (or, with ``spectral``, the spectral) tensor file of ``result``, a run
    recorded on the RGL grid, in the order they are written."""
    grid: RGLGrid | None = getattr(result.settings, "rgl", None)
    if grid is None:
        raise ExportError(f"{result.stack.name}: not recorded on the RGL grid (parametrization "
                          f"{result.settings.parametrization}); simulate with --parametrization rgl")
    aniso = result.stack.is_anisotropic
    if aniso and grid.isotropic:
        raise ExportError(f"{result.stack.name}: the stack is anisotropic but the file records one incident "
                          f"azimuth, which the readers take as an isotropic material; simulate with "
                          f"--rgl-grid N_THETA_IxN_PHI_IxN, N_PHI_I >= 3 (azimuths over [-180, 180])")
    s = result.settings
    traced = s.spectral
    if description is None:
        colour = ((f"spectra traced at {s.wavelength_bins} wavelength bins" if spectral else
                   f"linear sRGB (D65) of spectra traced at {s.wavelength_bins} wavelength bins") if traced else
                  ("spectra upsampled from RGB (B 465, G 550, R 610 nm, piecewise linear)" if spectral
                   else "linear RGB"))
        description = (f"{result.stack.name}: simulated by goniometer {goniometer.__version__} "
                       f"({s.rays:,} rays per incident direction{' and wavelength bin' if traced else ''}, seed "
                       f"{s.seed}, {s.masking} masking); stack {result.stack.to_json()}; warp NDF "
                       f"{json.dumps(grid.to_dict())}; " + colour)
    if traced:
        return fields_from_spectra(grid, result.brdf.value, s.wavelength_bins, description, spectral)
    return fields_from_values(grid, result.brdf.value, description, spectral)


def fields_from_spectra(grid: RGLGrid, value: np.ndarray, bins: int, description: str,
                        spectral: bool = True) -> dict[str, np.ndarray]:
    """The tensor file's fields from a spectral run's estimates ``value`` (M, bins, n, n): the
    traced spectra at the bin centres (``spectral``), or their linear sRGB clipped to >= 0."""
    from goniometer.spectral import rgb_weights, wavelength_bins, xyz_weights
    centres, edges = wavelength_bins(bins)
    S = stored_values(grid, value)                       # (Nphi, Ntheta, bins, n, n)
    y = xyz_weights(edges)[:, 1]
    lum = _luminance(np.tensordot(S, y, axes=([2], [0])))
    fields = _common_fields(grid, description, lum)
    if spectral:
        fields["spectra"] = S.astype(np.float32)
        fields["wavelengths"] = centres.astype(np.float32)
    else:
        rgb = np.moveaxis(np.tensordot(S, rgb_weights(edges), axes=([2], [0])), -1, 2)
        fields["rgb"] = np.maximum(rgb, 0.0).astype(np.float32)
    return fields


def _luminance(lum: np.ndarray) -> np.ndarray:
    """The ``luminance`` field (importance sampling only): floored at 1e-4 of each slice's peak."""
    for idx in np.ndindex(lum.shape[:2]):
        sl = lum[idx]
        top = float(sl.max())
        lum[idx] = np.maximum(sl, 1e-4 * top) if top > 0 else 1.0
    return lum.astype(np.float32)


def _common_fields(grid: RGLGrid, description: str, lum: np.ndarray) -> dict[str, np.ndarray]:
    tab = grid.tables()
    return {
        "description": np.frombuffer(description.encode("utf-8"), dtype=np.uint8),
        "jacobian": np.array([1], dtype=np.uint8),
        "theta_i": tab["theta_i"], "phi_i": tab["phi_i"],
        "ndf": tab["ndf"], "sigma": tab["sigma"], "vndf": tab["vndf"],
        "luminance": lum,
    }


def fields_from_values(grid: RGLGrid, value: np.ndarray, description: str, spectral: bool = False) -> dict[str, np.ndarray]:
    """The tensor file's fields from estimates ``value`` (M, 3, n, n) on ``grid`` (see
    :func:`stored_values`)."""
    S = stored_values(grid, value).astype(np.float32)  # (Nphi, Ntheta, 3, n, n)
    lum = _luminance(np.tensordot(S.astype(np.float64), LUMINANCE, axes=([2], [0])))
    fields = _common_fields(grid, description, lum)
    if spectral:
        spec = rgb_to_spectrum(np.moveaxis(S.astype(np.float64), 2, -1))      # (..., n, n, L)
        fields["spectra"] = np.ascontiguousarray(np.moveaxis(spec, -1, 2)).astype(np.float32)
        fields["wavelengths"] = WAVELENGTHS_NM.astype(np.float32)
    else:
        fields["rgb"] = S
    return fields


def check_readers(fields: dict[str, np.ndarray] | TensorFile) -> dict[str, list[str]]:
    """What keeps each reader from taking a file: ``{"mitsuba-rgb": [...], "mitsuba-spectral":
    [...], "pbrt-v4": [...]}`` (empty lists: the reader takes it), from the readers' own rules
    (``docs/rgl-format.md``, the readers)."""
    f = fields.fields if isinstance(fields, TensorFile) else fields
    common: list[str] = []
    need = {"description": np.uint8, "jacobian": np.uint8, "theta_i": np.float32, "phi_i": np.float32,
            "ndf": np.float32, "sigma": np.float32, "vndf": np.float32, "luminance": np.float32}
    for name, dt in need.items():
        if name not in f:
            common.append(f"no field {name}")
        elif f[name].dtype != np.dtype(dt):
            common.append(f"{name} is {f[name].dtype}, not {np.dtype(dt).name}")
    if not common:
        nt, nph = f["theta_i"].shape[0], f["phi_i"].shape[0]
        v, lum = f["vndf"], f["luminance"]
        if f["ndf"].ndim != 2 or f["sigma"].ndim != 2 or min(f["ndf"].shape + f["sigma"].shape) < 2:
            common.append("ndf and sigma must be 2-D tables of at least 2 x 2")
        if v.ndim != 4 or v.shape[:2] != (nph, nt):
            common.append(f"vndf has shape {v.shape}, not ({nph}, {nt}, H, W)")
        if lum.ndim != 4 or lum.shape[:2] != (nph, nt) or lum.shape[2] != lum.shape[3]:
            common.append(f"luminance has shape {lum.shape}, not ({nph}, {nt}, n, n)")
    out = {"mitsuba-rgb": list(common), "mitsuba-spectral": list(common), "pbrt-v4": list(common)}
    n = f["luminance"].shape[2:] if "luminance" in f and f["luminance"].ndim == 4 else None
    lead = f["luminance"].shape[:2] if n is not None else None
    rgb_ok = "rgb" in f and f["rgb"].dtype == np.float32 and n is not None and f["rgb"].shape == lead + (3,) + n
    spec_ok = ("spectra" in f and "wavelengths" in f and f["spectra"].dtype == np.float32 and n is not None
               and f["wavelengths"].dtype == np.float32 and f["spectra"].shape == lead + f["wavelengths"].shape + n)
    if "wavelengths" in f:
        out["mitsuba-rgb"].append("has wavelengths: Mitsuba's RGB variants refuse spectral files")
    elif not rgb_ok:
        out["mitsuba-rgb"].append("no rgb field of shape (N_phi_i, N_theta_i, 3, n, n) float32")
    if not spec_ok:
        out["mitsuba-spectral"].append("no spectra + wavelengths fields of matching shapes (float32)")
        out["pbrt-v4"].append("pbrt-v4 reads spectra + wavelengths only")
    if "phi_i" in f and f["phi_i"].shape[0] > 2:
        span = float(f["phi_i"][-1]) - float(f["phi_i"][0])
        reduction = round(2.0 * math.pi / span) if span > 0 else 0
        if reduction != 1:
            out["pbrt-v4"].append(f"anisotropic with reduction {reduction}: pbrt-v4 needs phi_i over [-pi, pi]")
        if reduction not in (1, 2, 4):
            for k in ("mitsuba-rgb", "mitsuba-spectral"):
                out[k].append(f"anisotropic with reduction {reduction}: Mitsuba folds by 1, 2 or 4 only")
    return out


def export_rgl(result, path: str | os.PathLike, spectral: bool = False) -> Path:
    """Write the tensor file of ``result`` (see :func:`bsdf_fields`) at ``path``, atomically."""
    fields = bsdf_fields(result, spectral=spectral)
    return write_tensor(path, fields)
