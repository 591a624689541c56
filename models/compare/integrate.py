"""Integrate analytic models onto the cells of a simulated file (``docs/slices-format.md``, "Cell value").

Every cell is split into ``s x s`` sub-cells uniform in the slice's own coordinates; the model is
evaluated at the sub-cell centres and weighted by each sub-cell's projected solid angle
(:meth:`goniometer.grids.slice_grid.SliceGrid.subcells`), so a model cell value is
``sum_k f(l, v_k) w_k / sum_k w_k`` -- the same average the simulator estimates. Geometry (grid,
incident directions) comes from the reference; masks and projected solid angles for the errors
are the reference file's. The sub-cells of a (grid, light) are computed once and shared by every
model and material (:mod:`models.compare.cells`); a model reads them read-only.

Mirror symmetry (``docs/models.md`` §3, "Mirror symmetry"): a model that declares
:attr:`models.base.Model.mirror_symmetric`, on a stack without an anisotropic interface, lit from
``l_y = 0`` exactly, on a classic or half grid (:func:`models.compare.cells.mirrors`), is evaluated
at the sub-cells of half of the cell columns (:func:`models.compare.cells.mirror_half`); each other
column is reduced from its mirror's values, every sub-cell weighted by its own projected solid
angle (:func:`models.compare.cells.cell_sums`). A mirrored cell's values are the model's at the
mirrors of its sub-cell directions, which differ from its own by rounding (the cosine and sine of
``2 pi - phi`` against those of ``phi``), summed in the mirror's sub-cell order: its mean moves in
the last bits, and no error printed by the harness moves. Mueller matrices are always evaluated on
every cell (a mirror is no identity on them).

Delta lobes (``docs/models.md`` §3, "Delta lobes"): a model's Dirac lobes
(:meth:`models.base.Model.delta_lobes`, :class:`models.base.DeltaLobe`) are no function the
sub-cells can sample; each is added whole to the cell that holds its direction, as
``value / Omega`` with ``Omega`` the cell's exact projected solid angle
(:meth:`~goniometer.grids.slice_grid.SliceGrid.proj_solid_angle`, what the simulator divides by):
the exact cell mean ``Int_cell f |cos theta_v| dw / Omega`` of the lobe. The cell is found by the
tracer's own binning (:func:`~goniometer.grids.slice_grid.cell_index_fast` against
:func:`~goniometer.grids.slice_grid.boundary_tables`, as the simulator's integrated first order
bins a smooth mirror), so a direction on a cell border goes where the tracer puts the same
direction. A lobe on the other side of the surface (or exactly at the horizon) adds nothing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from goniometer.run.results import SimulationResult, SliceData
from goniometer.grids.slice_grid import SliceGrid, boundary_tables, cell_index_fast, light_direction
from goniometer.stack import Stack
from models.base import DeltaLobe, Model, ModelError, ModelFailure, failure
from models.compare.cells import cell_geometry, cell_sums, mirror_half, mirrors

SIDE_OF_GRID = {"reflection": "brdf", "transmission": "btdf"}


@dataclass
class ModelSlices:
    """A model integrated onto the cells of one side of a reference: (M, 3, n_theta, n_phi) each.

    ``top_stderr`` and ``internal_stderr``: a stochastic model's own standard errors of the cell
    values (None for an exact model or part; :class:`models.base.ModelValue`)."""

    model: str
    side: str                 # "brdf" | "btdf"
    grid: SliceGrid
    top: np.ndarray
    internal: np.ndarray
    subcells: int
    top_stderr: np.ndarray | None = None
    internal_stderr: np.ndarray | None = None

    @property
    def total(self) -> np.ndarray:
        return self.top + self.internal

    @property
    def stochastic(self) -> bool:
        """Whether the model reported its own noise."""
        return self.top_stderr is not None or self.internal_stderr is not None

    def stderr(self, part: str) -> np.ndarray | None:
        """The model's standard error of ``part`` ("top", "internal" or "total": the two added in
        quadrature), None for an exact model."""
        if not self.stochastic:
            return None
        top = np.zeros_like(self.top) if self.top_stderr is None else self.top_stderr
        internal = np.zeros_like(self.internal) if self.internal_stderr is None else self.internal_stderr
        return {"top": top, "internal": internal, "total": np.sqrt(top**2 + internal**2)}[part]


def integrate_slice(model: Model, stack: Stack, grid: SliceGrid, light: np.ndarray, s: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """(top, internal) cell values of ``model`` for one light direction, each (3, n_theta, n_phi)."""
    top, internal, _, _ = integrate_slice_parts(model, stack, grid, light, s)
    return top, internal


def integrate_slice_parts(model: Model, stack: Stack, grid: SliceGrid, light: np.ndarray, s: int = 5
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """(top, internal, top_stderr, internal_stderr) of ``model`` for one light direction, each
    (3, n_theta, n_phi) or None (an exact part). The standard error of a cell mean of independent
    sub-cell estimates is ``sqrt(sum_k se_k^2 w_k^2) / sum_k w_k``. A model evaluated on half of the
    cells (:func:`mirrored`) is reduced with :func:`models.compare.cells.cell_sums`' mirrored weights."""
    side = SIDE_OF_GRID[grid.side]
    geo = cell_geometry(grid, light, s)   # shared by every model and material (models.compare.cells)
    half = mirror_half(grid, light, s) if mirrored(model, stack, grid, light) else None
    value = model.evaluate(stack, light, geo.v if half is None else half.v, side)
    out = []
    for part in (value.top, value.internal):
        if not np.all(np.isfinite(part)):
            raise ModelFailure(model.name, f"produced non-finite values for {side} at l = {np.round(light, 6).tolist()}")
        out.append(cell_sums(part, geo, half) * geo.inv)
    for lobe, i, j, omega in delta_cells(model, grid, light, "delta_lobes", stack, (3,)):
        out[0 if lobe.part == "top" else 1][:, i, j] += lobe.value / omega
    for se in (value.stderr_top, value.stderr_internal):
        if se is None:
            out.append(None)
            continue
        e = np.broadcast_to(np.asarray(se, dtype=np.float64), value.top.shape)
        if not np.all(np.isfinite(e)):
            raise ModelFailure(model.name, f"produced non-finite standard errors for {side} at "
                                           f"l = {np.round(light, 6).tolist()}")
        out.append(np.sqrt(cell_sums(e**2, geo, half, power=2)) * geo.inv)
    return out[0], out[1], out[2], out[3]


def mirrored(model: Model, stack: Stack, grid: SliceGrid, light: np.ndarray) -> bool:
    """Whether ``model`` is evaluated on half of ``grid``'s cells for ``light`` (module docstring):
    it declares :attr:`~models.base.Model.mirror_symmetric`, ``stack`` has no anisotropic interface
    and the cells mirror onto each other (:func:`models.compare.cells.mirrors`)."""
    return (model.mirror_symmetric is True and not stack.is_anisotropic
            and mirrors(grid, light))


#: how far from 1 the length of a delta lobe's direction may be (it is binned as given, not normalised:
#: normalising would move an exact mirror direction off a cell border by rounding)
UNIT_TOLERANCE = 1e-6


def delta_cells(model: Model, grid: SliceGrid, light: np.ndarray, method: str, stack: Stack,
                shape: tuple[int, ...]) -> list[tuple[DeltaLobe, int, int, float]]:
    """``model``'s delta lobes on ``grid``'s side for the light ``light`` (``method``:
    ``"delta_lobes"`` or ``"delta_lobes_mueller"``, values of ``shape``), each with the cell
    ``(i, j)`` that holds its direction and that cell's projected solid angle ``Omega > 0`` (module
    docstring); lobes on the other side, at the horizon or in a cell of no projected solid angle
    are left out. A hook that raises or returns something else than a list of :class:`DeltaLobe`
    of unit, finite directions and finite real values of ``shape`` and a part ``"top"`` or
    ``"internal"`` is the model's failure (:class:`ModelFailure`)."""
    side = SIDE_OF_GRID[grid.side]
    try:
        lobes = list(getattr(model, method)(stack, light, side))
    except Exception as e:  # noqa: BLE001 -- any failure of the model's own code is its failure
        raise failure(model.name, method, e) from None
    if not lobes:
        return []
    row_cos, col_cos, col_sin = boundary_tables(grid.parametrization, grid.n_theta, grid.n_phi)
    omega = grid.proj_solid_angle(light)
    out = []
    for lobe in lobes:
        lobe = _checked_lobe(model.name, method, lobe, shape)
        v = lobe.v
        i, j = cell_index_fast(grid.code, grid.transmission, light[0], light[1], light[2], v[0], v[1], v[2],
                               grid.n_theta, grid.n_phi, row_cos, col_cos, col_sin)
        if i >= 0 and omega[i, j] > 0.0:
            out.append((lobe, int(i), int(j), float(omega[i, j])))
    return out


def _checked_lobe(name: str, method: str, lobe: object, shape: tuple[int, ...]) -> DeltaLobe:
    """``lobe`` with its direction a float64 vector of unit length (to :data:`UNIT_TOLERANCE`) and its
    value a float64 array of ``shape``; :class:`ModelFailure` (one line naming ``method``) otherwise."""
    if not isinstance(lobe, DeltaLobe):
        raise ModelFailure(name, f"{method} returned a {type(lobe).__name__}, not a DeltaLobe")
    try:
        v = np.asarray(lobe.v, dtype=np.float64)
        value = np.asarray(lobe.value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ModelFailure(name, f"{method} returned a lobe whose direction or value is not real numbers") from None
    if v.shape != (3,) or not np.all(np.isfinite(v)) or abs(float(np.linalg.norm(v)) - 1.0) > UNIT_TOLERANCE:
        raise ModelFailure(name, f"{method} returned a lobe direction {np.round(v, 6).tolist()}, "
                                 f"not a unit vector (3,)")
    if value.shape != shape or not np.all(np.isfinite(value)):
        raise ModelFailure(name, f"{method} returned a lobe value of shape {value.shape} (finite: "
                                 f"{bool(np.all(np.isfinite(value)))}); expected finite values of shape {shape}")
    if lobe.part not in ("top", "internal"):
        raise ModelFailure(name, f"{method} returned a lobe of part {lobe.part!r}, not 'top' or 'internal'")
    # binned as given; + 0.0 turns -0.0 into 0.0, so that a lobe at the pole has the azimuth 0 in the
    # frames' conversion too (as in the binning, goniometer.grids.slice_grid.cell_index)
    return DeltaLobe(v + 0.0, value, lobe.part)


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
    errors: dict[str, np.ndarray] = {}
    for m, (t, p) in enumerate(zip(reference.theta_deg, reference.phi_deg)):
        top[m], internal[m], se_top, se_internal = integrate_slice_parts(
            model, stack or reference.stack, sd.grid, light_direction(t, p), s)
        for key, se in (("top", se_top), ("internal", se_internal)):
            if se is not None:
                errors.setdefault(key, np.zeros((M, 3, nt, nph)))[m] = se
    return ModelSlices(model.name, side, sd.grid, top, internal, s, errors.get("top"), errors.get("internal"))


# ---------------------------------------------------------------------- Mueller matrices (polarized files)

@dataclass
class MuellerSlices:
    """A polarized model's Mueller matrices integrated onto the cells of one side of a polarized
    reference: ``mueller`` (M, 3, n_theta, n_phi, 4, 4), 1/sr, in the file's s/p frames
    (``docs/polarization.md`` §2), laid out as the file's ``mueller``."""

    model: str
    side: str
    grid: SliceGrid
    mueller: np.ndarray
    subcells: int


def to_file_frames(mueller: np.ndarray, frames: str, l: np.ndarray, v: np.ndarray, phi_l_deg: float) -> np.ndarray:
    """Mueller matrices ``(N, ..., 4, 4)`` of light along ``-l`` to each ``v`` (N, 3), given in the
    frame family ``frames`` (:attr:`models.base.Model.mueller_frames`), in the file's s/p frames of
    an incident direction of azimuth ``phi_l_deg`` (:func:`goniometer.grids.stokes.frame_x`; a
    model's ``"sp"`` frames take the limit along the azimuth 0 at ``l = z``, each exit the limit
    along its own azimuth at ``v = z``)."""
    from goniometer.grids.stokes import FRAMES, frame_x, rotator
    if frames not in FRAMES:
        raise ModelError(f"mueller_frames: {frames!r} is not one of {', '.join(FRAMES)}")
    phi_v = np.degrees(np.arctan2(v[:, 1], v[:, 0]))
    L = np.broadcast_to(np.asarray(l, dtype=np.float64), v.shape)
    a_in, a_out = frame_x(frames, L, v, np.zeros(len(v)), phi_v)
    b_in, b_out = frame_x("sp", L, v, np.full(len(v), float(phi_l_deg)), phi_v)
    r_in = rotator(-L, a_in, b_in)
    r_out = rotator(v, a_out, b_out)
    extra = (None,) * (mueller.ndim - 3)          # the channel axes between the direction and the matrix
    return r_out[(slice(None), *extra)] @ mueller @ np.swapaxes(r_in, -1, -2)[(slice(None), *extra)]


def integrate_mueller_slice(model: Model, stack: Stack, grid: SliceGrid, light: np.ndarray, phi_l_deg: float,
                            s: int = 5) -> np.ndarray:
    """The cell means (3, n_theta, n_phi, 4, 4) of ``model``'s Mueller matrices for one light
    direction, each sub-cell's matrix taken to the file's s/p frames of its own direction before
    the projected-solid-angle average (the simulator's cell mean of its exits' matrices)."""
    side = SIDE_OF_GRID[grid.side]
    geo = cell_geometry(grid, light, s)
    w, inv = geo.w, geo.inv
    value = model.evaluate_mueller(stack, light, geo.v, side)          # (N, 3, 4, 4)
    if not np.all(np.isfinite(value)):
        raise ModelFailure(model.name, f"produced non-finite Mueller matrices for {side} at "
                                       f"l = {np.round(light, 6).tolist()}")
    try:
        with np.errstate(invalid="ignore", divide="ignore"):
            sp = to_file_frames(value, model.mueller_frames, light, geo.v, phi_l_deg)
    except ModelError as e:
        raise ModelFailure(model.name, str(e)) from None
    if not np.all(np.isfinite(sp)):
        raise ModelFailure(model.name, f"its {model.mueller_frames!r} frames are undefined at some sub-cell direction "
                                       f"for l = {np.round(light, 6).tolist()} (v parallel to l)")
    f = sp.reshape(w.shape + (3, 4, 4))
    out = np.einsum("ijabcxy,ijab->cijxy", f, w, optimize=True) * inv[None, :, :, None, None]
    for lobe, i, j, omega in delta_cells(model, grid, light, "delta_lobes_mueller", stack, (3, 4, 4)):
        with np.errstate(invalid="ignore", divide="ignore"):
            m = to_file_frames(lobe.value[None], model.mueller_frames, light, lobe.v[None], phi_l_deg)[0]
        if not np.all(np.isfinite(m)):
            raise ModelFailure(model.name, f"its {model.mueller_frames!r} frames are undefined at the delta lobe "
                                           f"{np.round(lobe.v, 6).tolist()} for l = {np.round(light, 6).tolist()}")
        out[:, i, j] += m / omega
    return out


def integrate_mueller(model: Model, reference: SimulationResult, side: str, s: int = 5, stack: Stack | None = None
                      ) -> MuellerSlices:
    """Integrate ``model``'s Mueller matrices onto the ``side`` cells of the polarized ``reference``
    (:func:`integrate_mueller_slice` per incident direction)."""
    sd: SliceData | None = reference.brdf if side == "brdf" else reference.btdf
    if sd is None:
        raise ModelError(f"the reference file has no {side.upper()} slices")
    M = len(reference.theta_deg)
    nt, nph = sd.grid.shape
    out = np.zeros((M, 3, nt, nph, 4, 4))
    for m, (t, p) in enumerate(zip(reference.theta_deg, reference.phi_deg)):
        out[m] = integrate_mueller_slice(model, stack or reference.stack, sd.grid, light_direction(t, p), float(p), s)
    return MuellerSlices(model.name, side, sd.grid, out, s)
