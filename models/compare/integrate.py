"""Integrate analytic models onto the cells of a simulated file (``docs/slices-format.md``, "Cell value").

Every cell is split into ``s x s`` sub-cells uniform in the slice's own coordinates; the model is
evaluated at the sub-cell centres and weighted by each sub-cell's projected solid angle
(:meth:`goniometer.slices.SliceGrid.subcells`), so a model cell value is
``sum_k f(l, v_k) w_k / sum_k w_k`` -- the same average the simulator estimates. Geometry (grid,
incident directions) comes from the reference; masks and projected solid angles for the errors
are the reference file's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from goniometer.results import SimulationResult, SliceData
from goniometer.slices import SliceGrid, light_direction
from goniometer.stack import Stack
from models.base import Model, ModelError

SIDE_OF_GRID = {"reflection": "brdf", "transmission": "btdf"}


@dataclass
class ModelSlices:
    """A model integrated onto the cells of one side of a reference: (M, 3, n_theta, n_phi) each."""

    model: str
    side: str                 # "brdf" | "btdf"
    grid: SliceGrid
    top: np.ndarray
    internal: np.ndarray
    subcells: int

    @property
    def total(self) -> np.ndarray:
        return self.top + self.internal


def integrate_slice(model: Model, stack: Stack, grid: SliceGrid, light: np.ndarray, s: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """(top, internal) cell values of ``model`` for one light direction, each (3, n_theta, n_phi)."""
    side = SIDE_OF_GRID[grid.side]
    v, w = grid.subcells(light, s)
    value = model.evaluate(stack, light, v.reshape(-1, 3), side)
    den = w.sum(axis=(2, 3))
    inv = np.divide(1.0, den, out=np.zeros_like(den), where=den > 0)
    out = []
    for part in (value.top, value.internal):
        f = part.reshape(w.shape + (3,))
        if not np.all(np.isfinite(f)):
            raise ModelError(f"{model.name}: produced non-finite values for {side} at l = {np.round(light, 6).tolist()}")
        cells = np.einsum("ijabc,ijab->cij", f, w, optimize=True) * inv
        out.append(cells)
    return out[0], out[1]


def integrate(model: Model, reference: SimulationResult, side: str, s: int = 5, stack: Stack | None = None
              ) -> ModelSlices:
    """Integrate ``model`` onto the ``side`` ("brdf"/"btdf") cells of ``reference``, for the
    reference's stack or, if given, ``stack`` (e.g. an isotropized stand-in)."""
    sd: SliceData | None = reference.brdf if side == "brdf" else reference.btdf
    if sd is None:
        raise ModelError(f"the reference file has no {side.upper()} slices")
    M = len(reference.theta_deg)
    nt, nph = sd.grid.shape
    top = np.zeros((M, 3, nt, nph))
    internal = np.zeros((M, 3, nt, nph))
    for m, (t, p) in enumerate(zip(reference.theta_deg, reference.phi_deg)):
        top[m], internal[m] = integrate_slice(model, stack or reference.stack, sd.grid, light_direction(t, p), s)
    return ModelSlices(model.name, side, sd.grid, top, internal, s)
