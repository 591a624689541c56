"""The data of a fit (:func:`fit_data`): which reference cells are fitted, their direction samples
(``s x s`` sub-cells, finer near the mirror direction) and their residual weights (``"paper"``:
Holzschuch & Pacanowski's eq. 29, grazing directions left out; ``"eq4"``: the project's eq. 4).
``docs/fitted.md``, "Fitting"."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from goniometer.run.results import SimulationResult, SliceData
from goniometer.grids.slice_grid import light_direction
from models.base import ModelError, require_slices
from models.fitted.samples import Samples

#: the paper's grazing cut-off (sec. 5.8): theta_i, theta_o >= 1.4 rad are left out of the fit
GRAZING_RAD = 1.4


@dataclass
class FitData:
    """The fitting problem of one reference: samples, reference values and residual weights."""

    samples: Samples
    ref: np.ndarray        # (n_cells, 3)
    stderr: np.ndarray     # (n_cells, 3)
    weight: np.ndarray     # (n_cells,) residual weight W (r = sqrt(W) (f - ref))
    subcells: int
    peak_subcells: int
    n_peak: int = 0
    note: str = ""


#: sub-cell sizes the automatic rules aim at (degrees): everywhere, and near the mirror direction
AUTO_SUBCELL_DEG = 1.0
AUTO_PEAK_SUBCELL_DEG = 0.25
#: cells whose centre lies within this angle of the mirror direction get ``peak_subcells``
PEAK_DEG = 8.0


def _cell_extent_deg(sd: SliceData) -> float:
    g = sd.grid
    return max(90.0 / g.n_theta, 360.0 / g.n_phi)


def auto_subcells(sd: SliceData) -> int:
    """Sub-cells per axis so that sub-cells are at most ~1 degree (1 to 5)."""
    return int(min(5, max(1, math.ceil(_cell_extent_deg(sd) / AUTO_SUBCELL_DEG - 1e-9))))


def auto_peak_subcells(sd: SliceData, subcells: int) -> int:
    """Sub-cells per axis near the mirror direction: ~0.25 degree for classic grids (at most 5).

    Half grids already concentrate small cells around the mirror direction; they keep ``subcells``.
    """
    if sd.grid.parametrization != "classic":
        return subcells
    return int(max(subcells, min(5, math.ceil(_cell_extent_deg(sd) / AUTO_PEAK_SUBCELL_DEG - 1e-9))))


def fit_data(reference: SimulationResult, subcells: int | None = None, weighting: str = "paper",
             grazing: float = GRAZING_RAD, peak_subcells: int | None = None,
             peak_deg: float = PEAK_DEG) -> FitData:
    """Select the cells to fit and build their samples and weights (``docs/fitted.md``, "Fitting").

    A cell is used if it is valid in the reference mask, its value is finite and (paper
    weighting) neither the incident direction nor the cell centre is beyond ``grazing`` rad.
    Cells whose centre is within ``peak_deg`` of the mirror direction get ``peak_subcells`` sub-cells
    per axis, the others ``subcells`` (None: automatic).
    """
    if weighting not in ("paper", "eq4"):
        raise ModelError(f"fit: weighting {weighting!r} is not one of paper, eq4")
    require_slices(reference)
    sd = reference.brdf
    s = auto_subcells(sd) if subcells is None else int(subcells)
    sp = auto_peak_subcells(sd, s) if peak_subcells is None else int(peak_subcells)
    if s < 1 or sp < 1:
        raise ModelError(f"fit: sub-cells ({s}, {sp}) must be >= 1")
    M = len(reference.theta_deg)
    cos_cut = math.cos(grazing)
    cos_peak = math.cos(math.radians(peak_deg))
    parts: dict[str, list] = {k: [] for k in ("l", "v", "w", "n", "ref", "se", "W", "keep")}
    n_peak = 0
    for m in range(M):
        light = light_direction(reference.theta_deg[m], reference.phi_deg[m])
        vb, wb = sd.grid.subcells(light, s)
        ref = sd.value[m].transpose(1, 2, 0)
        se = sd.stderr[m].transpose(1, 2, 0)
        ok = (sd.mask[m] & (wb.sum(axis=(2, 3)) > 0) & np.all(np.isfinite(ref), axis=-1)
              & (sd.proj_solid_angle[m] > 0))
        centre = np.einsum("ijab,ijabk->ijk", wb, vb)
        centre /= np.maximum(np.linalg.norm(centre, axis=-1, keepdims=True), 1e-300)
        mirror = np.array([-light[0], -light[1], light[2]])
        peak = ok & (centre @ mirror > cos_peak) if sp != s else np.zeros_like(ok)
        groups = [(ok & ~peak, vb, wb, s)]
        if peak.any():
            vp, wp = sd.grid.subcells(light, sp)
            peak &= wp.sum(axis=(2, 3)) > 0
            groups.append((peak, vp, wp, sp))
            n_peak += int(peak.sum())
        for sel, v, w, ss in groups:
            idx = np.nonzero(sel)
            if idx[0].size == 0:
                continue
            vv = v[idx].reshape(-1, ss * ss, 3)
            ww = w[idx].reshape(-1, ss * ss)
            ww = ww / ww.sum(axis=1, keepdims=True)
            vz = vv[..., 2]
            inv_cos = np.divide(1.0, vz, out=np.zeros_like(vz), where=vz > 0)
            omega = sd.proj_solid_angle[m][idx]
            if weighting == "paper":
                W = light[2] ** 2 * omega * np.sum(ww * inv_cos, axis=1) / M
                keep = (centre[idx][:, 2] > cos_cut) & (light[2] > cos_cut)
            else:
                W = omega / M
                keep = np.ones(W.shape, dtype=bool)
            parts["l"].append(np.broadcast_to(light, (vv.shape[0] * ss * ss, 3)))
            parts["v"].append(vv.reshape(-1, 3))
            parts["w"].append(ww.ravel())
            parts["n"].append(np.full(vv.shape[0], ss * ss))
            parts["ref"].append(ref[idx])
            parts["se"].append(np.where(np.isfinite(se[idx]), se[idx], 0.0))
            parts["W"].append(W)
            parts["keep"].append(keep)
    if not parts["W"]:
        raise ModelError("fit: the reference has no valid BRDF cells to fit")
    keep = np.concatenate(parts["keep"])
    note = ""
    if not keep.any():
        keep[:] = True
        note = f"no data left after excluding directions beyond {grazing:g} rad from the normal; fitted all valid cells"
    counts = np.concatenate(parts["n"])
    keep_s = np.repeat(keep, counts)
    start = np.concatenate([[0], np.cumsum(counts[keep])])
    smp = Samples(np.ascontiguousarray(np.concatenate(parts["l"])[keep_s]),
                  np.ascontiguousarray(np.concatenate(parts["v"])[keep_s]),
                  np.ascontiguousarray(np.concatenate(parts["w"])[keep_s]), start)
    return FitData(smp, np.ascontiguousarray(np.concatenate(parts["ref"])[keep]),
                   np.concatenate(parts["se"])[keep], np.concatenate(parts["W"])[keep], s, sp, n_peak, note)
