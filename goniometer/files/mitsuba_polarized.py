"""A polarized tabulation to the tensor file of Mitsuba 3's ``measured_polarized`` BSDF (a
``.pbsdf``; ``docs/polarization.md`` section 5, ``docs/tabulated-format.md``, export).

The plugin (Baek et al. 2020's layout) reads five fields of a tensor file
(:mod:`goniometer.files.rgl_tensor`): ``theta_h``, ``theta_d``, ``phi_d`` (float32, shape (1, N),
radians, ascending), ``wvls`` (uint16, (5,), nm) and ``M`` (float32, ``[phi_d, theta_d, theta_h,
lambda, 4, 4]``): a Mueller pBRDF in 1/sr without the cosine, indexed by the Rusinkiewicz angles of
(direction to the light, direction to the viewer), ``phi_d`` in (-pi, pi], interpolated linearly in
each of the four parameters and clamped beyond the end nodes. Its Stokes frames are our "plane"
frames (``x = normalize(l x v)`` for both beams), the frames a polarized tabulation stores, so the
matrices are written as they are:

* the nodes are the MERL cells' centres (``theta_h`` mid-row in the square-root coordinate,
  ``theta_d``, and ``phi_d`` on both sides: ``c - 180`` and ``c`` degrees for the centre ``c`` in
  [0, 180) of each folded cell);
* the half ``phi_d < 0``, which the MERL grid folds onto ``phi_d + 180`` by reciprocity (the pair
  ``(v, l)``), is the reciprocal matrix ``D M^T D``, ``D = diag(1, 1, -1, 1)`` (section 2; the plane
  frame of the exchanged pair is turned by 180 degrees, which leaves Stokes vectors as they are);
* cells no path left through hold 0 (the estimate there).

Wavelengths: the plugin reads exactly five (``wvls`` of another length is read past or beyond its
array), linear between them and constant beyond. An RGB tabulation's channels are written at their
stated wavelengths (:data:`goniometer.files.rgl_export.CHANNEL_NM`: B 465, G 550, R 610 nm) with the
two end channels repeated at 360 and 830 nm (constant beyond, the RGL export's upsampling); a
spectral tabulation of 3 bins likewise at its bin centres; one of more bins at five of its bins,
evenly spread (the first, the last and three between: :func:`spectral_bins`), each at its centre
rounded to the nanometre.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from goniometer.files.rgl_export import CHANNEL_NM
from goniometer.files.rgl_tensor import write_tensor
from goniometer.grids import halfdiff

__all__ = ["FIELDS", "N_WAVELENGTHS", "PAD_NM", "PolarizedExportError", "RECIPROCAL", "export_pbsdf",
           "pbsdf_fields", "spectral_bins", "wavelengths"]

#: wavelengths the plugin reads
N_WAVELENGTHS = 5
#: where a three-channel file repeats its end channels (nm): the spectral variants' range
PAD_NM = (360, 830)
#: the fields the plugin reads
FIELDS = ("theta_h", "theta_d", "phi_d", "wvls", "M")
#: reciprocity's signs in the s/p or plane frames: M(v -> l)[i, j] = RECIPROCAL[i, j] M(l -> v)[j, i]
#: (D M^T D, D = diag(1, 1, -1, 1), docs/polarization.md section 2)
RECIPROCAL = np.outer([1.0, 1.0, -1.0, 1.0], [1.0, 1.0, -1.0, 1.0])


class PolarizedExportError(ValueError):
    """A file that cannot be exported to ``measured_polarized`` (the message says why)."""


def spectral_bins(n_bins: int) -> np.ndarray:
    """The five bins (indices) of a spectral tabulation of ``n_bins`` >= 5 bins that the file holds:
    ``round(linspace(0, n_bins - 1, 5))``."""
    return np.round(np.linspace(0.0, n_bins - 1, N_WAVELENGTHS)).astype(np.int64)


def wavelengths(tab) -> tuple[np.ndarray, np.ndarray]:
    """``(wvls, channels)``: the file's five wavelengths (uint16, nm, ascending) and the channel of
    ``tab`` each holds (module docstring)."""
    if tab.settings.spectral:
        centres = np.asarray(tab.wavelengths_nm, dtype=np.float64)
        if len(centres) >= N_WAVELENGTHS:
            ch = spectral_bins(len(centres))
            return np.round(centres[ch]).astype(np.uint16), ch
        order = np.argsort(centres)
    else:
        centres = np.asarray(CHANNEL_NM, dtype=np.float64)
        order = np.argsort(centres)            # B, G, R
    if len(order) != 3:
        raise PolarizedExportError(f"{len(order)} channels: the file holds 5 wavelengths, from 3 channels or 5 bins "
                                   f"and more")
    nm = np.concatenate([[PAD_NM[0]], np.round(centres[order]), [PAD_NM[1]]])
    ch = np.concatenate([[order[0]], order, [order[-1]]])
    return nm.astype(np.uint16), ch.astype(np.int64)


def pbsdf_fields(tab) -> dict[str, np.ndarray]:
    """The tensor file's fields of a polarized :class:`~goniometer.run.results.TabulatedBRDF`
    (module docstring); raises :class:`PolarizedExportError` for a scalar one."""
    if tab.mueller is None:
        raise PolarizedExportError("a scalar tabulation: measured_polarized holds Mueller matrices; tabulate with "
                                   "--polarized (gonio tabulate CONFIG --polarized --out T.h5)")
    wvls, ch = wavelengths(tab)
    c = np.radians(halfdiff.phi_d_centers_deg())
    n_pd = len(c)
    M = np.empty((2 * n_pd, halfdiff.N_THETA_D, halfdiff.N_THETA_H, N_WAVELENGTHS, 4, 4), dtype=np.float32)
    for k, channel in enumerate(ch):
        m = np.moveaxis(tab.mueller[channel], (0, 1, 2), (2, 1, 0))     # (phi_d, theta_d, theta_h, 4, 4)
        M[n_pd:, :, :, k] = m
        M[:n_pd, :, :, k] = np.swapaxes(m, -1, -2) * RECIPROCAL
    return {
        "theta_h": np.radians(halfdiff.theta_h_centers_deg()).astype(np.float32)[None, :],
        "theta_d": np.radians(halfdiff.theta_d_centers_deg()).astype(np.float32)[None, :],
        "phi_d": np.concatenate([c - np.pi, c]).astype(np.float32)[None, :],
        "wvls": wvls,
        "M": M,
    }


def export_pbsdf(tab, path: str | os.PathLike) -> Path:
    """Write the ``measured_polarized`` tensor file of ``tab`` at ``path``, atomically
    (:func:`goniometer.files.rgl_tensor.write_tensor`); returns the path."""
    return write_tensor(path, pbsdf_fields(tab))
