"""Errors between reference slices and model slices (Bati 2019, eq. 4; ``docs/slices-format.md``, "Errors").

Per colour channel c, over the M incident directions and the valid (unmasked) cells::

    E_c = sqrt( (1/M) sum_m sum_cells (f_ref,c - f_model,c)^2 Omega(cell) )

reported per channel, as the mean over channels, and for the luminance (Rec. 709 weights
0.2126, 0.7152, 0.0722 applied to the RGB values before differencing). The reference noise floor
is the same formula with ``(f_ref - f_model)^2`` replaced by the reference's squared standard
error: the error a perfect model would show, on average, because the reference is noisy
(``E[(f_ref - f_true)^2] = stderr^2``).

A stochastic model that reports its own standard errors (:class:`models.compare.integrate.ModelSlices`)
gets its **model noise** beside the floor: the same formula with the model's squared standard error,
the error an exact reference would show against this noisy model (``docs/models.md`` §3).

"internal" compares the internal paths only (bounce order 1 dropped from the reference and the
top lobe from the model: plastics, metals); "total" compares everything. For a BTDF both are the
whole BTDF.

Every error states its support: ``cells``, the cells it sums over, and ``cells_total``, the cells
the grid holds on the judged side (:class:`Coverage`). An error over no cell is refused
(:class:`NoCellsError`, :func:`require_cells`); one over less than :data:`LOW_COVERAGE` of the grid
comes with a warning (:meth:`Coverage.warning`; ``docs/models.md`` §3, "Support").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from goniometer.run.results import SimulationResult, SliceData
from goniometer.grids.slice_grid import light_direction
from models.base import ModelError
from models.compare.cells import grid_mask
from models.compare.integrate import ModelSlices, MuellerSlices

LUMINANCE = np.array([0.2126, 0.7152, 0.0722])

#: an error summed over fewer than this fraction of the cells its grid holds on the judged side is
#: reported with a warning: it then judges the models where the reference has data (e.g. near the
#: peak of a sparse measurement), not over the BSDF its name suggests (``docs/models.md`` §3)
LOW_COVERAGE = 0.5


class NoCellsError(ModelError):
    """A comparison over no cell: the reference has no valid cell on the judged side, so every error
    would be 0 whatever the model (the message says how many cells the grid holds and why);
    ``coverage``: the reference's :class:`Coverage` when known."""

    def __init__(self, message: str, coverage: "Coverage | None" = None) -> None:
        super().__init__(message)
        self.coverage = coverage


@dataclass(frozen=True)
class Coverage:
    """The support of a reference's errors: ``cells`` valid cells (mask True, projected solid angle
    > 0) over the ``cells_total`` cells that its grid holds on the judged side, summed over the
    incident directions (every cell of a classic grid; on a half grid those whose directions lie on
    the side, :meth:`goniometer.grids.slice_grid.SliceGrid.mask`). A simulation covers its whole grid; a
    measurement only the cells where it has data."""

    cells: int
    cells_total: int

    @property
    def fraction(self) -> float:
        return self.cells / self.cells_total if self.cells_total else 0.0

    @property
    def low(self) -> bool:
        """Fewer valid cells than :data:`LOW_COVERAGE` of the grid."""
        return self.cells < LOW_COVERAGE * self.cells_total

    def text(self) -> str:
        """``"1,234 of 3,600 cells (34.3 %)"``."""
        return f"{self.cells:,} of {self.cells_total:,} cells ({100.0 * self.fraction:.1f} %)"

    def warning(self) -> str | None:
        """One line when :attr:`low` (None otherwise)."""
        if not self.low:
            return None
        return (f"the reference has valid data in {self.text()} of its grid, under {100 * LOW_COVERAGE:g} %: the "
                f"errors are summed over those cells only, so they judge the models where the reference has "
                f"data, not over the whole BSDF")


def _subcells(reference: SimulationResult) -> int | None:
    """The sub-cells per axis the reference's mask was computed with: a measurement's resampling
    (``extra["measured"]``); None for a simulation (the grid's default, as the simulator uses it)."""
    measured = reference.extra.get("measured") if isinstance(reference.extra, dict) else None
    return int(measured["subcells"]) if measured and "subcells" in measured else None


def coverage(reference: SimulationResult, side: str) -> Coverage:
    """The :class:`Coverage` of ``reference``'s ``side`` ("brdf" or "btdf") slices."""
    sd = reference.brdf if side == "brdf" else reference.btdf
    if sd is None:
        raise ModelError(f"the reference file has no {side.upper()} slices")
    s = _subcells(reference)
    valid = sd.mask & (sd.proj_solid_angle > 0)
    total = 0
    for m, (t, p) in enumerate(zip(reference.theta_deg, reference.phi_deg)):
        grid = grid_mask(sd.grid, light_direction(float(t), float(p)), s)   # shared (models.compare.cells)
        total += int(np.count_nonzero((grid | sd.mask[m]) & (sd.proj_solid_angle[m] > 0)))
    return Coverage(int(np.count_nonzero(valid)), total)


def require_cells(reference: SimulationResult, side: str) -> Coverage:
    """:func:`coverage`, or :class:`NoCellsError` when no cell is valid: an error over no cell is 0
    whatever the model, a perfect score over no data."""
    cov = coverage(reference, side)
    if cov.cells == 0:
        s = _subcells(reference)
        why = (f"; a cell of a measurement is valid when all of its {s}x{s} sub-cells fall where the file has "
               f"data: fewer sub-cells (evaluate --subcells) or larger cells (--resolution) cover more"
               if s is not None else "")
        raise NoCellsError(f"the reference has no valid cell on its {side.upper()} (0 of {cov.cells_total:,} cells "
                           f"of the grid): an error over no cell would be 0 for any model{why}", cov)
    return cov


def rmse(ref: np.ndarray, model: np.ndarray, omega: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Eq. 4 per channel: ``ref``/``model`` (M, C, n_theta, n_phi), ``omega``/``mask`` (M, n_theta, n_phi)."""
    M = ref.shape[0]
    d2 = (ref - model) ** 2 * (omega * mask)[:, None]
    return np.sqrt(d2.sum(axis=(0, 2, 3)) / M)


def noise_floor(stderr: np.ndarray, omega: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Eq. 4 with the squared difference replaced by the squared standard error (per channel)."""
    M = stderr.shape[0]
    return np.sqrt((stderr**2 * (omega * mask)[:, None]).sum(axis=(0, 2, 3)) / M)


def luminance(rgb: np.ndarray, axis: int = 1, keepdims: bool = True) -> np.ndarray:
    """Rec. 709 luminance (:data:`LUMINANCE` weights) of RGB values whose channel axis is ``axis``
    (default: (M, 3, ...) values), that axis kept with length 1 (``keepdims``) or dropped."""
    axis = axis % rgb.ndim
    rest = [k for k in range(rgb.ndim) if k != axis]
    lum = np.einsum(LUMINANCE, [axis], rgb, list(range(rgb.ndim)), rest)
    return np.expand_dims(lum, axis) if keepdims else lum


def error_object(ref: np.ndarray, ref_stderr: np.ndarray, model: np.ndarray, omega: np.ndarray,
                 mask: np.ndarray, model_stderr: np.ndarray | None = None, cells_total: int | None = None) -> dict:
    """The JSON error object ``E`` of ``gonio evaluate --json``. ``reference_norm`` is eq. 4 of the
    reference against zero (per channel): the error of a model that predicts no light, the scale
    against which an error is small or large. ``cells`` is the number of cells the sums run over
    (mask True, ``omega`` > 0, over all incident directions); ``cells_total`` the cells of the grid
    on the judged side (:attr:`Coverage.cells_total`; when not given, every cell of the arrays).

    The luminance noise floor uses ``sum_c w_c stderr_c`` per cell, an upper bound on the
    standard error of the luminance (the channels of a simulation share their paths, so their
    errors are correlated; the bound is exact when they are fully correlated). A reference without
    standard errors (a measurement, ``goniometer.files.measured``: NaN) has the noise floors None.

    ``model_stderr`` (a stochastic model's standard errors of ``model``) adds ``model_noise``,
    ``model_noise_mean`` and ``model_noise_luminance``: :func:`noise_floor` of the model's errors,
    computed as the reference's. Without it the object has exactly the keys it always had.
    """
    e = rmse(ref, model, omega, mask)
    nf = noise_floor(ref_stderr, omega, mask)
    size = rmse(ref, np.zeros_like(ref), omega, mask)
    lum = rmse(luminance(ref), luminance(model), omega, mask)[0]
    lum_se = luminance(ref_stderr)
    # a measured reference has no standard errors (NaN): its noise floor is unknown, not invented
    known = bool(np.all(np.isfinite(nf)))
    out = {
        "rmse": [float(x) for x in e],
        "rmse_mean": float(np.mean(e)),
        "rmse_luminance": float(lum),
        "noise_floor": [float(x) for x in nf] if known else None,
        "noise_floor_mean": float(np.mean(nf)) if known else None,
        "noise_floor_luminance": float(noise_floor(lum_se, omega, mask)[0]) if known else None,
        "reference_norm": [float(x) for x in size],
        "cells": int(np.count_nonzero(mask & (omega > 0))),
        "cells_total": int(mask.size if cells_total is None else cells_total),
    }
    if model_stderr is not None:
        mn = noise_floor(model_stderr, omega, mask)
        out["model_noise"] = [float(x) for x in mn]
        out["model_noise_mean"] = float(np.mean(mn))
        out["model_noise_luminance"] = float(noise_floor(luminance(model_stderr), omega, mask)[0])
    return out


def reference_parts(sd: SliceData, internal: bool) -> tuple[np.ndarray, np.ndarray]:
    """Reference values and standard errors, internal paths only (order 1 dropped) or total.

    When a file lacks ``stderr_internal`` the total standard error is used, which bounds the
    internal one from above.
    """
    if not internal:
        return sd.value, sd.stderr
    # sum orders >= 2 rather than subtract order 1 from the total: orders may be stored in float32,
    # and a sharp first-order peak would leave its rounding error in the difference
    value = sd.orders[:, 1:].astype(np.float64).sum(axis=1)
    se = sd.stderr_internal if sd.stderr_internal is not None else sd.stderr
    return value, se


def compare(sd: SliceData, ms: ModelSlices, drop_first_order: bool, cells_total: int | None = None) -> dict:
    """``{"internal": E, "total": E}`` for one model on one side.

    ``drop_first_order``: plastics and metals (BRDF) compare internal paths for "internal";
    for a BTDF "internal" and "total" are the same comparison. ``cells_total``: the grid's cells on
    the side (:func:`coverage`), recorded in each error object.
    """
    total = error_object(sd.value, sd.stderr, ms.total, sd.proj_solid_angle, sd.mask, ms.stderr("total"),
                         cells_total)
    if not drop_first_order:
        return {"internal": total, "total": total}
    ref, se = reference_parts(sd, internal=True)
    internal = error_object(ref, se, ms.internal, sd.proj_solid_angle, sd.mask, ms.stderr("internal"), cells_total)
    return {"internal": internal, "total": total}


def mueller_errors(sd: SliceData, ms: MuellerSlices, cells_total: int | None = None) -> dict:
    """The per-element errors of a polarized model on a polarized reference's side ``sd``
    (``docs/models.md`` §3, "Polarized files"): eq. 4 per Mueller element ``M_ij`` and channel,
    against the file's ``mueller``, over the same valid cells as the intensity errors; the noise
    floor per element from the file's ``mueller_stderr`` (:func:`noise_floor`). Keys:
    ``mueller_rmse`` and ``mueller_noise`` ([4][4][C], 1/sr), their channel means
    ``mueller_rmse_mean`` and ``mueller_noise_mean`` ([4][4]), ``mueller_norm`` ([4][4][C], the
    reference against zero), ``cells``, ``cells_total``. The whole BSDF is compared (the files keep
    no Mueller matrices per bounce order). ``mueller_rmse[0][0]`` is the total intensity error of
    a model whose ``M00`` is its intensity."""
    if sd.mueller is None:
        raise ModelError("the reference file is not polarized: it has no Mueller matrices")

    def flat(a: np.ndarray) -> np.ndarray:     # (M, C, nt, nph, 4, 4) -> (M, C * 16, nt, nph)
        M, C, nt, nph = a.shape[:4]
        return np.moveaxis(a, (4, 5), (2, 3)).reshape(M, C * 16, nt, nph)

    def grid(x: np.ndarray) -> np.ndarray:     # (C * 16,) -> (4, 4, C)
        return np.moveaxis(x.reshape(-1, 4, 4), 0, -1)

    omega, mask = sd.proj_solid_angle, sd.mask
    ref = flat(sd.mueller)
    e = grid(rmse(ref, flat(ms.mueller), omega, mask))
    nf = grid(noise_floor(flat(sd.mueller_stderr), omega, mask))
    size = grid(rmse(ref, np.zeros_like(ref), omega, mask))
    return {"mueller_rmse": e.tolist(), "mueller_rmse_mean": e.mean(axis=-1).tolist(),
            "mueller_noise": nf.tolist(), "mueller_noise_mean": nf.mean(axis=-1).tolist(),
            "mueller_norm": size.tolist(),
            "cells": int(np.count_nonzero(mask & (omega > 0))),
            "cells_total": int(mask.size if cells_total is None else cells_total)}
