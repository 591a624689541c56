"""What a run produces, what identifies a run, and how raw kernel sums become estimates.

:class:`SliceData` and :class:`SimulationResult` are what :mod:`goniometer.files.slices` writes and the
models read; :class:`IncidentPart` holds one incident direction's raw sums (what checkpoints and
Dask tasks return); :data:`RUN_KEYS` and :func:`run_description` say when two runs are the same.
Cell values follow ``docs/slices-format.md``: ``fbar = (sum of exit weights in the cell) / (N
Omega)``, with ``N`` the rays of the incident direction and ``Omega`` the cell's projected solid
angle; standard errors come from the per-cell sums of squared weights.

:class:`TabulatedBRDF` is what a tabulation produces (``docs/tabulated-format.md``): a cell's value
is the mean of ``f`` over the cell's pairs of directions weighted by ``cos theta_l cos theta_v``
(the cell measure of :mod:`goniometer.grids.halfdiff`), estimated from paths whose incident
directions have density ``cos theta_l / pi``: ``fbar = pi S / (N mu)`` with ``S`` the sum of the
exit weights in the cell, ``N`` the number of paths and ``mu`` the cell measure; standard errors
from the per-cell sums of squared weights. :mod:`goniometer.files.tabulated` writes and reads it.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import numba
import numpy as np

from goniometer import atomic
from goniometer.kernel import tracer
from goniometer.run.first_order import first_order_fractions
from goniometer.run.settings import SimulationSettings, TabulationSettings
from goniometer.grids import halfdiff
from goniometer.grids.slice_grid import SliceGrid, light_direction
from goniometer.stack import Stack

ENERGY_TERMS = ("reflected", "transmitted", "absorbed", "masking_loss")
#: elements of a Mueller matrix (row-major 4 x 4), per exit of a polarized run
N_MUELLER = 16

#: the settings that make two runs of one stack the same run (``threads`` is not one of them:
#: results are bit-identical whatever the thread count)
RUN_KEYS = ("incident_deg", "incident_phi_deg", "rays", "parametrization", "resolution", "seed", "masking",
            "max_order", "chunk_rays", "chunks_per_task", "event_cap", "first_order", "rgl", "spectral",
            "wavelength_bins", "device", "polarized")


def run_description(stack: Stack, settings: SimulationSettings) -> dict[str, Any]:
    """What makes two runs the same, as JSON-ready data: the stack and the :data:`RUN_KEYS`
    (``first_order`` only when it is not the default "traced": descriptions of traced runs keep
    their bytes, ``docs/file-identity.md``)."""
    d = settings.to_dict()
    s = {k: d[k] for k in RUN_KEYS
         if not (k == "first_order" and settings.first_order == "traced") and not (k == "rgl" and settings.rgl is None)
         and k in d}   # an RGB run's dict has no spectral keys, a CPU run's no device, a scalar run's no polarized
    return {"stack": json.loads(stack.to_json()), "settings": json.loads(json.dumps(s))}


def same_run(a: SimulationSettings, b: SimulationSettings) -> bool:
    """True if the two settings describe the same run (they differ at most in ``threads``)."""
    return all(getattr(a, k) == getattr(b, k) for k in RUN_KEYS)


@dataclass
class SliceData:
    """Simulated slices of one side (reflection or transmission) for all M incident directions.

    ``value``/``stderr``: (M, 3, n_theta, n_phi) in 1/sr, no cosine; ``orders``:
    (M, K, 3, n_theta, n_phi), order K meaning "K or more"; ``mask`` and
    ``proj_solid_angle``: (M, n_theta, n_phi); ``stderr_internal``: standard error of the
    internal part (orders >= 2, i.e. ``value - orders[:, 0]``), or None if unknown.
    ``mueller``/``mueller_stderr``: a polarized run's Mueller matrices, ``value.shape + (4, 4)``
    (1/sr, no cosine; the incident beam's Stokes vector to the exit beam's, in the s/p frames of
    ``docs/polarization.md`` section 2), ``mueller[..., 0, 0]`` equal to ``value``; None for scalar
    light.
    """

    grid: SliceGrid
    value: np.ndarray
    stderr: np.ndarray
    orders: np.ndarray
    mask: np.ndarray
    proj_solid_angle: np.ndarray
    stderr_internal: np.ndarray | None = None
    mueller: np.ndarray | None = None
    mueller_stderr: np.ndarray | None = None

    @property
    def polarized(self) -> bool:
        """True when the slices hold Mueller matrices (a polarized run)."""
        return self.mueller is not None


@dataclass
class SimulationResult:
    """Everything one simulation produced (what :mod:`goniometer.files.slices` writes)."""

    stack: Stack
    settings: SimulationSettings
    theta_deg: np.ndarray
    phi_deg: np.ndarray
    brdf: SliceData
    btdf: SliceData | None
    energy: dict[str, np.ndarray]          # (M, 3) per term, fractions of the incident flux
    energy_stderr: dict[str, np.ndarray]   # (M, 3)
    roulette: np.ndarray                   # (M, 3) net weight booked by Russian roulette / N
    capped: np.ndarray                     # (M, 3) weight stopped by the event cap / N
    capped_paths: np.ndarray               # (M,) int
    mean_events: np.ndarray                # (M,) events per path
    elapsed_s: np.ndarray                  # (M,) wall time of each incident direction
    threads: int
    compile_s: float = 0.0
    extra: dict[str, Any] = field(default_factory=dict)
    #: (M, 3) reflected fraction carried by paths that never had an event at the base (the bottom
    #: layer), a part of ``energy["reflected"]``; None for files written before it was recorded
    reflected_without_base: np.ndarray | None = None
    reflected_without_base_stderr: np.ndarray | None = None

    @property
    def rays_per_s(self) -> float:
        """Paths traced per second of tracing (a spectral run traces ``paths_per_incident``)."""
        total = float(np.sum(self.elapsed_s))
        return self.paths_per_incident * len(self.theta_deg) / total if total > 0 else float("nan")

    @property
    def paths_per_incident(self) -> int:
        """Paths traced per incident direction: ``rays``, times the launches of a spectral run
        (:func:`goniometer.run.launches.launches`)."""
        if not self.settings.spectral:
            return self.settings.rays
        from goniometer.run.launches import launches
        return self.settings.rays * len(launches(self.stack, self.settings))

    @property
    def wavelengths_nm(self) -> np.ndarray | None:
        """The wavelength-bin centres (nm) of a spectral run's channels; None for an RGB run."""
        return self.settings.wavelengths_nm

    def rgb(self) -> "SimulationResult":
        """This result in linear sRGB (a spectral run through the colour pipeline of
        ``docs/spectral.md`` section 4; an RGB run is returned as it is)."""
        if not self.settings.spectral:
            return self
        from goniometer.run.rgb import to_rgb
        return to_rgb(self)


@dataclass
class Sums:
    """Raw kernel sums in the kernel's layout: what a task returns and an incident accumulates.

    ``brdf``/``btdf``: (n_theta, n_phi, K + 2, 3) (see :func:`goniometer.kernel.tracer._trace_chunk`;
    ``btdf`` is (1, 1, K + 2, 3) for opaque stacks); ``energy`` (N_ENERGY, 3); ``energy_sq``
    (N_ENERGY_SQ, 3); ``counts`` (N_COUNTS,) int64. A polarized run's ``mbrdf``/``mbtdf``:
    (n_theta, n_phi, 2 * N_MUELLER, 3), the sums of the 16 Mueller elements of the exits (row-major)
    then of their squares; None for scalar light.
    """

    brdf: np.ndarray
    btdf: np.ndarray
    energy: np.ndarray
    energy_sq: np.ndarray
    counts: np.ndarray
    mbrdf: np.ndarray | None = None
    mbtdf: np.ndarray | None = None

    @classmethod
    def zeros(cls, stack: Stack, settings: SimulationSettings) -> "Sums":
        nt, nph = settings.resolution
        k2 = settings.max_order + 2
        bt = (nt, nph) if stack.transmits else (1, 1)
        pol = (lambda shape: np.zeros(shape + (2 * N_MUELLER, 3))) if settings.polarized else (lambda shape: None)
        return cls(np.zeros((nt, nph, k2, 3)), np.zeros(bt + (k2, 3)), np.zeros((tracer.N_ENERGY, 3)),
                   np.zeros((tracer.N_ENERGY_SQ, 3)), np.zeros(tracer.N_COUNTS, dtype=np.int64), pol((nt, nph)),
                   pol(bt))

    def add(self, other: "Sums") -> None:
        """In-place ``self += other`` (field by field; the order of additions is the caller's)."""
        self.brdf += other.brdf
        self.btdf += other.btdf
        self.energy += other.energy
        self.energy_sq += other.energy_sq
        self.counts += other.counts
        if self.mbrdf is not None:
            self.mbrdf += other.mbrdf
            self.mbtdf += other.mbtdf


@dataclass
class IncidentPart:
    """Raw sums for one incident direction, split into orders and squares (what checkpoints hold)."""

    index: int
    brdf: np.ndarray           # (K, 3, n_theta, n_phi) weight sums per order
    brdf_sq: np.ndarray        # (2, 3, n_theta, n_phi) squared weights: all exits, orders >= 2
    btdf: np.ndarray | None
    btdf_sq: np.ndarray | None
    energy: np.ndarray         # (N_ENERGY, 3)
    energy_sq: np.ndarray      # (N_ENERGY_SQ, 3)
    counts: np.ndarray         # (N_COUNTS,)
    elapsed_s: float
    #: a polarized run's Mueller element sums and sums of squares, (N_MUELLER, 3, n_theta, n_phi) each
    brdf_mueller: np.ndarray | None = None
    brdf_mueller_sq: np.ndarray | None = None
    btdf_mueller: np.ndarray | None = None
    btdf_mueller_sq: np.ndarray | None = None

    #: the arrays with a channel axis (axis 1), which a spectral run's launches write into their bins
    PER_CHANNEL = ("brdf", "brdf_sq", "btdf", "btdf_sq", "brdf_mueller", "brdf_mueller_sq", "btdf_mueller",
                   "btdf_mueller_sq")

    @classmethod
    def from_sums(cls, m: int, acc: Sums, K: int, transmits: bool, elapsed_s: float) -> "IncidentPart":
        def split(h: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
            # (n_theta, n_phi, rows, 3) -> rows [0, k) and [k, rows) as (rows, 3, n_theta, n_phi): orders
            # (K) and squared weights (2: all exits, internal exits (order >= 2)); Mueller element sums and
            # their squares
            return (np.ascontiguousarray(h[:, :, :k, :].transpose(2, 3, 0, 1)),
                    np.ascontiguousarray(h[:, :, k:, :].transpose(2, 3, 0, 1)))

        brdf, brdf_sq = split(acc.brdf, K)
        btdf, btdf_sq = split(acc.btdf, K) if transmits else (None, None)
        mueller: tuple = (None,) * 4
        if acc.mbrdf is not None:
            mueller = split(acc.mbrdf, N_MUELLER) + (split(acc.mbtdf, N_MUELLER) if transmits else (None, None))
        return cls(m, brdf, brdf_sq, btdf, btdf_sq, acc.energy, acc.energy_sq, acc.counts, elapsed_s, *mueller)

    def save(self, path) -> None:
        """Checkpoint to an ``.npz`` file, compressed (lossless: :meth:`load` gives the same bits) and
        atomically (temporary name, then rename)."""
        arrays = {k: v for k, v in self.__dict__.items() if isinstance(v, np.ndarray)}
        atomic.write_npz_compressed(path, index=self.index, elapsed_s=self.elapsed_s, **arrays)

    @classmethod
    def load(cls, path) -> "IncidentPart":
        """A part saved by :meth:`save` (compressed or, written before checkpoints were, not)."""
        with np.load(path) as z:
            get = (lambda k: z[k] if k in z.files else None)
            return cls(int(z["index"]), z["brdf"], z["brdf_sq"], get("btdf"), get("btdf_sq"), z["energy"],
                       z["energy_sq"], z["counts"], float(z["elapsed_s"]), get("brdf_mueller"),
                       get("brdf_mueller_sq"), get("btdf_mueller"), get("btdf_mueller_sq"))


def _slice_from_sums(grid: SliceGrid, omegas: list[np.ndarray], masks: list[np.ndarray],
                     sums: list[np.ndarray], sqs: list[np.ndarray], n: int,
                     first: list[np.ndarray] | None = None, mueller: list[np.ndarray] | None = None,
                     mueller_sq: list[np.ndarray] | None = None) -> SliceData:
    """Cell values and standard errors from the traced sums; ``first`` (per direction, (3, n_theta,
    n_phi) flux fractions) is bounce order 1 integrated (:mod:`goniometer.run.first_order`): it is added
    to order 1, whose traced exits were not deposited, and adds no variance. ``mueller``,
    ``mueller_sq``: a polarized run's Mueller element sums and their squares per direction
    ((N_MUELLER, C, n_theta, n_phi)), estimated as the values are."""
    M = len(omegas)
    K = sums[0].shape[0]
    nt, nph = grid.shape
    C = sums[0].shape[1]
    value = np.zeros((M, C, nt, nph))
    stderr = np.zeros((M, C, nt, nph))
    stderr_internal = np.zeros((M, C, nt, nph))
    orders = np.zeros((M, K, C, nt, nph))

    def std_error(s1: np.ndarray, s2: np.ndarray, inv: np.ndarray) -> np.ndarray:
        # standard error of the mean of N per-ray contributions, divided by N Omega
        var = np.maximum(s2 - s1 * s1 / n, 0.0) / max(n - 1, 1)
        return np.sqrt(var * n) * inv

    for m, om in enumerate(omegas):
        inv = np.divide(1.0, n * om, out=np.zeros_like(om), where=om > 0)
        s1 = sums[m].sum(axis=0)
        value[m] = s1 * inv
        orders[m] = sums[m] * inv
        stderr[m] = std_error(s1, sqs[m][0], inv)
        stderr_internal[m] = std_error(sums[m][1:].sum(axis=0), sqs[m][1], inv)
        if first is not None:
            orders[m, 0] += first[m] * (n * inv)
            value[m] += first[m] * (n * inv)
    out = SliceData(grid, value, stderr, orders, np.array(masks), np.array(omegas), stderr_internal)
    if mueller is not None:
        mu = np.empty((M, C, nt, nph, N_MUELLER))
        mu_se = np.empty((M, C, nt, nph, N_MUELLER))
        for m, om in enumerate(omegas):
            inv = np.divide(1.0, n * om, out=np.zeros_like(om), where=om > 0)
            _mueller_cells(mueller[m], mueller_sq[m], inv, n, mu[m], mu_se[m])
        out.mueller, out.mueller_stderr = mu.reshape(mu.shape[:-1] + (4, 4)), mu_se.reshape(mu.shape[:-1] + (4, 4))
    return out


@numba.njit(cache=True, error_model="numpy")
def _mueller_cells(sums: np.ndarray, sums_sq: np.ndarray, inv: np.ndarray, n: int, value: np.ndarray,
                   stderr: np.ndarray) -> None:
    """``value[c, t, p, e] = sums[e, c, t, p] inv[t, p]`` and its standard error, for the 16 Mueller
    elements ``e`` (row-major) of every cell: ``_slice_from_sums``' ``std_error`` element by element,
    its operations in its order (numpy's ``maximum(x, 0.0)``: ``x`` if above 0 or NaN, else +0.0),
    without the arrays' temporaries."""
    nf = float(n)
    dof = float(max(n - 1, 1))
    for c in range(sums.shape[1]):
        for t in range(sums.shape[2]):
            for p in range(sums.shape[3]):
                w = inv[t, p]
                for e in range(sums.shape[0]):
                    s1 = sums[e, c, t, p]
                    d = sums_sq[e, c, t, p] - s1 * s1 / nf
                    if not (d > 0.0 or d != d):
                        d = 0.0
                    value[c, t, p, e] = s1 * w
                    stderr[c, t, p, e] = math.sqrt(d / dof * nf) * w


@lru_cache(maxsize=64)
def cell_geometry(parametrization: str, n_theta: int, n_phi: int, theta_deg: float,
                  phi_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Projected solid angles and comparison mask of a slice grid for one incident direction
    (:meth:`SliceGrid.proj_solid_angle`, :meth:`SliceGrid.mask`), read-only and memoised: the
    materials of a database share their incident directions and grids, and the exact half-cell
    solid angles cost ~7 ms per direction (90 x 360, one core)."""
    grid = SliceGrid(parametrization, n_theta, n_phi, "reflection")
    light = light_direction(theta_deg, phi_deg)
    omega, mask = grid.proj_solid_angle(light), grid.mask(light)
    omega.setflags(write=False)
    mask.setflags(write=False)
    return omega, mask


def cell_geometries(settings: SimulationSettings) -> list[tuple[np.ndarray, np.ndarray]]:
    """(Omega, mask) of the grid of ``settings`` for each of its incident directions
    (:func:`cell_geometry`, memoised). The CLI calls it before tracing, where Ctrl-C is deferred,
    so that the numba kernels of the final assembly are compiled and run there. On the RGL grid
    Omega is the dual cells' sample-space area above the horizon (:meth:`RGLGrid.cell_geometry`)."""
    if settings.rgl is not None:
        return [settings.rgl.cell_geometry(m) for m in range(len(settings.incident_deg))]
    nt, nph = settings.resolution
    return [cell_geometry(settings.parametrization, nt, nph, t, p)
            for t, p in zip(settings.incident_deg, settings.incident_phi_deg)]


def assemble(stack: Stack, settings: SimulationSettings, parts: list[IncidentPart],
             compile_s: float = 0.0) -> SimulationResult:
    """Turn the raw per-incident sums into cell values, errors and energies."""
    parts = sorted(parts, key=lambda p: p.index)
    n = settings.rays
    nt, nph = settings.resolution
    grid = SliceGrid(settings.parametrization, nt, nph, "reflection")
    # |cos theta_v| and the validity of sub-cells are the same on both sides: computed once
    geometry = cell_geometries(settings)
    omegas = [g[0] for g in geometry]
    masks = [g[1] for g in geometry]
    first = None
    if settings.first_order == "integrated":
        first = [_first_order(stack, settings, light_direction(t, p))
                 for t, p in zip(settings.incident_deg, settings.incident_phi_deg)]
    def mueller(name: str) -> list[np.ndarray] | None:
        return [getattr(p, name) for p in parts] if settings.polarized else None

    brdf = _slice_from_sums(grid, omegas, masks, [p.brdf for p in parts], [p.brdf_sq for p in parts], n, first,
                            mueller("brdf_mueller"), mueller("brdf_mueller_sq"))
    btdf = None
    if stack.transmits and settings.rgl is None:  # the RGL format is reflection-only
        btdf = _slice_from_sums(SliceGrid(settings.parametrization, nt, nph, "transmission"), omegas, masks,
                                [p.btdf for p in parts], [p.btdf_sq for p in parts], n, None,
                                mueller("btdf_mueller"), mueller("btdf_mueller_sq"))
    energy: dict[str, np.ndarray] = {}
    energy_se: dict[str, np.ndarray] = {}
    for t, name in enumerate(ENERGY_TERMS):
        energy[name], energy_se[name] = _mean_stderr(parts, t, n)
    unbased, unbased_se = _mean_stderr(parts, tracer.E_REFLECTED_WITHOUT_BASE, n)
    return SimulationResult(
        stack=stack, settings=settings,
        theta_deg=np.array(settings.incident_deg), phi_deg=np.array(settings.incident_phi_deg),
        brdf=brdf, btdf=btdf, energy=energy, energy_stderr=energy_se,
        roulette=np.array([p.energy[tracer.E_ROULETTE] for p in parts]) / n,
        capped=np.array([p.energy[tracer.E_CAPPED] for p in parts]) / n,
        capped_paths=np.array([p.counts[tracer.C_CAPPED] for p in parts]),
        mean_events=np.array([p.counts[tracer.C_EVENTS] for p in parts]) / (n * _launch_count(stack, settings)),
        elapsed_s=np.array([p.elapsed_s for p in parts]),
        threads=tracer.thread_count(settings.threads), compile_s=compile_s,
        reflected_without_base=unbased, reflected_without_base_stderr=unbased_se,
    )


def _first_order(stack: Stack, settings: SimulationSettings, light: np.ndarray) -> np.ndarray:
    """Bounce order 1 integrated (:func:`goniometer.run.first_order.first_order_fractions`) for one
    incident direction, (C, n_theta, n_phi): per RGB channel, or per wavelength bin of a spectral
    run from the three-channel stack of the launch that traced the bin (``docs/spectral.md`` §2)."""
    nt, nph = settings.resolution
    if not settings.spectral:
        return first_order_fractions(stack, settings.parametrization, nt, nph, light, settings.masking)
    from goniometer.run.launches import launch_stacks
    out = np.zeros((settings.wavelength_bins, nt, nph))
    for bins, st, _ in launch_stacks(stack, settings):
        out[list(bins)] = first_order_fractions(st, settings.parametrization, nt, nph, light,
                                                settings.masking)[:len(bins)]
    return out


def _launch_count(stack: Stack, settings: SimulationSettings) -> int:
    """Kernel launches per incident direction: 1, or a spectral run's launches (each of ``rays`` paths)."""
    if not settings.spectral:
        return 1
    from goniometer.run.launches import launches
    return len(launches(stack, settings))


def _mean_stderr(parts: list[IncidentPart], row: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-path mean of energy row ``row`` and its standard error, (M, 3) each."""
    s1 = np.array([p.energy[row] for p in parts])
    s2 = np.array([p.energy_sq[row] for p in parts])
    mean = s1 / n
    return mean, np.sqrt(np.maximum(s2 / n - mean * mean, 0.0) / max(n - 1, 1))


# ---------------------------------------------------------------------- tabulations

#: energy terms of a tabulation: the four of a slices file and the part of ``reflected`` that never
#: reached the base
TAB_ENERGY_TERMS = ENERGY_TERMS + ("reflected_without_base",)
_ENERGY_ROWS = {"reflected": tracer.E_REFLECTED, "transmitted": tracer.E_TRANSMITTED,
                "absorbed": tracer.E_ABSORBED, "masking_loss": tracer.E_MASKING,
                "reflected_without_base": tracer.E_REFLECTED_WITHOUT_BASE}


@dataclass
class TabulatedBRDF:
    """An isotropic BRDF tabulated on the MERL grid (``docs/tabulated-format.md``).

    ``value``/``stderr``: (C, 90, 90, 180) in 1/sr, no cosine, indexed (channel, theta_h,
    theta_d, phi_d), C = 3 (R, G, B) or a spectral tabulation's wavelength bins
    (:attr:`wavelengths_nm`); ``hits`` and ``measure`` (sr^2): (90, 90, 180), ``hits`` counting
    the paths of every launch. Energy terms are (C,) fractions of the flux of uniform diffuse
    illumination (incident directions ``cos theta / pi``).

    ``mueller``/``mueller_stderr``: a polarized tabulation's Mueller matrices, ``value.shape + (4,
    4)``, in the "plane" frames of the cell's pair with ``phi_d`` in [0, 180) (``x = normalize(l x
    v)`` for both beams, ``docs/polarization.md`` section 5), ``mueller[..., 0, 0]`` equal to
    ``value``; None for scalar light.
    """

    stack: Stack
    settings: TabulationSettings
    value: np.ndarray
    stderr: np.ndarray
    hits: np.ndarray
    measure: np.ndarray
    energy: dict[str, np.ndarray]
    energy_stderr: dict[str, np.ndarray]
    roulette: np.ndarray
    capped: np.ndarray
    capped_paths: int
    mean_events: float
    elapsed_s: float
    threads: int
    compile_s: float = 0.0
    #: kernel launches of ``settings.rays`` paths each: 1, or a spectral tabulation's (``docs/spectral.md``)
    launches: int = 1
    mueller: np.ndarray | None = None
    mueller_stderr: np.ndarray | None = None

    @property
    def polarized(self) -> bool:
        """True when the cells hold Mueller matrices (a polarized tabulation)."""
        return self.mueller is not None

    @property
    def has_data(self) -> np.ndarray:
        """(90, 90, 180) bool: at least one path left through the cell."""
        return self.hits > 0

    @property
    def rays_per_s(self) -> float:
        """Paths traced per second (a spectral tabulation traces ``rays`` per launch)."""
        return self.paths / self.elapsed_s if self.elapsed_s > 0 else float("nan")

    @property
    def paths(self) -> int:
        """Paths traced in all."""
        return self.settings.rays * self.launches

    @property
    def wavelengths_nm(self) -> np.ndarray | None:
        """The wavelength-bin centres (nm) of a spectral tabulation's channel axis; None for RGB."""
        return self.settings.wavelengths_nm

    def rgb(self) -> "TabulatedBRDF":
        """This tabulation in linear sRGB (a spectral one through the colour pipeline of
        ``docs/spectral.md`` section 4, standard errors by its stated upper bound; an RGB one is
        returned as it is). The stack is the material's RGB equivalent; the settings say RGB."""
        if not self.settings.spectral:
            return self
        from dataclasses import replace

        from goniometer.spectral import combined_stderr, rgb_weights, wavelength_bins
        from goniometer.run.launches import bin_groups
        s = self.settings
        W = rgb_weights(wavelength_bins(s.wavelength_bins)[1])      # (B, 3)
        groups = bin_groups(self.stack, s)

        def lin(a: np.ndarray) -> np.ndarray:
            return np.moveaxis(np.tensordot(np.moveaxis(a, 0, -1), W, axes=([-1], [0])), -1, 0)

        def se(a: np.ndarray) -> np.ndarray:
            return combined_stderr(a, W, groups, axis=0)

        pol = {} if self.mueller is None else {"mueller": lin(self.mueller), "mueller_stderr": se(self.mueller_stderr)}
        return replace(self, stack=Stack(self.stack.name, self.stack.layers, self.stack.category),
                       settings=replace(s, spectral=False), value=lin(self.value), stderr=se(self.stderr), **pol,
                       energy={k: lin(v) for k, v in self.energy.items()},
                       energy_stderr={k: se(v) for k, v in self.energy_stderr.items()},
                       roulette=lin(self.roulette), capped=lin(self.capped))

    def eval(self, l: np.ndarray, v: np.ndarray) -> np.ndarray:
        """The BRDF ``f(l, v)`` per channel (RGB, or per wavelength bin) in 1/sr without the
        cosine, shape ``(..., C)``.

        ``l`` and ``v``: (..., 3) directions (normalised here) pointing away from the surface,
        broadcast together. The value is that of the cell holding the pair (nearest cell, no
        interpolation); 0 where ``l`` or ``v`` is at or below the horizon, and 0 in cells no path
        left through (the estimate there; :attr:`has_data` tells them apart).
        """
        cells = halfdiff.cell_indices(l, v)
        C = self.value.shape[0]
        flat = self.value.reshape(C, halfdiff.N_CELLS)
        out = np.zeros(cells.shape + (C,))
        ok = cells >= 0
        out[ok] = flat[:, cells[ok]].T
        return out

    @classmethod
    def from_sums(cls, stack: Stack, settings: TabulationSettings, sums: np.ndarray, sums_sq: np.ndarray,
                  hits: np.ndarray, energy: np.ndarray, energy_sq: np.ndarray, counts: np.ndarray,
                  elapsed_s: float, threads: int, compile_s: float = 0.0, launches: int = 1,
                  mueller: np.ndarray | None = None, mueller_sq: np.ndarray | None = None) -> "TabulatedBRDF":
        """Estimates from the raw sums of a tabulation: ``sums``/``sums_sq`` (N_CELLS, C) exit weights
        and their squares per flat MERL cell, ``hits`` (N_CELLS,), and the kernel's energy sums; every
        channel was estimated from ``settings.rays`` paths (a spectral run: ``launches`` launches of
        ``rays`` paths, whose counters are summed). ``mueller``/``mueller_sq``: a polarized run's
        (N_CELLS, C, 16) Mueller element sums and their squares', estimated as the values are; the
        element ``[0, 0]`` is the path's weight, so it is taken from ``sums`` (the same numbers, up to
        the last bit of a free flight's rescaling): ``mueller[..., 0, 0]`` is ``value``."""
        n = settings.rays
        C = sums.shape[1]
        mu = np.asarray(halfdiff.cell_measure()).reshape(-1)
        scale = np.divide(np.pi, n * mu, out=np.zeros_like(mu), where=mu > 0)[:, None]
        value = sums * scale
        var = np.maximum(sums_sq - sums * sums / n, 0.0) / max(n - 1, 1)
        stderr = np.sqrt(var * n) * scale

        def planes(x: np.ndarray) -> np.ndarray:
            return np.ascontiguousarray(x.T).reshape((C,) + halfdiff.SHAPE)

        pol = {}
        if mueller is not None:     # (the cells no path left through hold zero sums: computed where hits > 0)
            nz = np.flatnonzero(hits)
            s1, s2, sc = mueller[nz], mueller_sq[nz], scale[nz, :, None]
            m = s1 * sc
            m_se = np.sqrt(np.maximum(s2 - s1 * s1 / n, 0.0) / max(n - 1, 1) * n) * sc
            m[:, :, 0] = value[nz]
            m_se[:, :, 0] = stderr[nz]

            def matrices(x: np.ndarray) -> np.ndarray:     # (cells with data, C, 16) -> (C, 90, 90, 180, 4, 4)
                out = np.zeros((C, halfdiff.N_CELLS, 16))
                out[:, nz] = np.moveaxis(x, 0, 1)
                return out.reshape((C,) + halfdiff.SHAPE + (4, 4))
            pol = {"mueller": matrices(m), "mueller_stderr": matrices(m_se)}

        en: dict[str, np.ndarray] = {}
        en_se: dict[str, np.ndarray] = {}
        for name in TAB_ENERGY_TERMS:
            row = _ENERGY_ROWS[name]
            mean = energy[row] / n
            en[name] = mean
            en_se[name] = np.sqrt(np.maximum(energy_sq[row] / n - mean * mean, 0.0) / max(n - 1, 1))
        return cls(
            stack=stack, settings=settings, value=planes(value), stderr=planes(stderr),
            hits=hits.reshape(halfdiff.SHAPE).astype(np.int64), measure=np.array(halfdiff.cell_measure()),
            energy=en, energy_stderr=en_se, roulette=energy[tracer.E_ROULETTE] / n,
            capped=energy[tracer.E_CAPPED] / n, capped_paths=int(counts[tracer.C_CAPPED]),
            mean_events=float(counts[tracer.C_EVENTS]) / (n * launches), elapsed_s=elapsed_s, threads=threads,
            compile_s=compile_s, launches=launches, **pol)
