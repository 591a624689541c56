"""What to simulate: :class:`SimulationSettings` and its validation (``docs/material-format.md``,
the ``[simulation]`` table).

``chunk_rays`` and ``chunks_per_task`` belong to the determinism contract
(``docs/architecture.md``): the same (seed, chunk_rays, chunks_per_task) gives the same bits
whatever ``threads``, locally or distributed.

The data contract stands without the kernel: the vocabularies (:data:`PARAMETRIZATIONS`,
:data:`MASKING`, :data:`FIRST_ORDER`, :data:`DEVICES`) and the defaults live here, and the command
line takes them from here. What only the machine can say -- whether CUDA is there, how many numba
threads it has -- is checked where the paths are launched
(:func:`goniometer.kernel.tracer.check_device`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import Any, Mapping

from typing import TYPE_CHECKING

import numpy as np

from goniometer.stack import SIMULATION_KEYS

if TYPE_CHECKING:
    from goniometer.grids.rgl import RGLGrid

#: the incident elevations (degrees) of a run that gives none: the paper's seven (Bati et al. 2019)
DEFAULT_INCIDENT = (0.0, 15.0, 30.0, 45.0, 60.0, 70.0, 80.0)
#: cell grids: theta/phi of v, of the half vector, or the RGL format's sample space (docs/rgl-format.md)
PARAMETRIZATIONS = ("classic", "half", "rgl")
MASKING = ("separable", "height-correlated")
#: how bounce order 1 (a single reflection on the top interface) gets into the reflection slices:
#: traced like every other order, or integrated over the cells (``docs/first-order.md``)
FIRST_ORDER = ("traced", "integrated")
#: where the paths are traced: numba threads, or an NVIDIA GPU through numba-cuda (``docs/gpu.md``)
DEVICES = ("cpu", "cuda")
#: default hard cap on the number of events of one path (reported if ever reached)
EVENT_CAP = 10_000
#: most numba threads a setting may ask for; the machine's own limit (``NUMBA_NUM_THREADS``) is
#: checked at launch (:func:`goniometer.kernel.tracer.check_device`)
MAX_THREADS = 1 << 12


class SettingsError(ValueError):
    """Invalid simulation settings; the message names the field and the allowed range."""


class _Channels:
    """The channel axis of a run's per-channel quantities (fields ``spectral`` and ``wavelength_bins``)."""

    spectral: bool
    wavelength_bins: int

    @property
    def wavelengths_nm(self) -> np.ndarray | None:
        """The centres (nm) of the wavelength bins of a spectral run; None for an RGB run."""
        if not self.spectral:
            return None
        from goniometer.spectral import wavelength_bins
        return wavelength_bins(self.wavelength_bins)[0]

    @property
    def n_channels(self) -> int:
        """Entries per per-channel quantity: 3 (R, G, B) or the wavelength bins."""
        return self.wavelength_bins if self.spectral else 3


@dataclass(frozen=True)
class SimulationSettings(_Channels):
    """What to simulate. ``rays`` is per incident direction.

    ``incident_deg`` are elevations theta_l in [0, 90); ``incident_phi_deg`` azimuths in
    [0, 360) (default 0 for all). ``chunk_rays`` (rays per random stream and histogram) and
    ``chunks_per_task`` (chunks summed together before being added to the total) are part of the
    determinism contract: the same (seed, chunk_rays, chunks_per_task) gives the same bits
    whatever ``threads``, locally or distributed. ``first_order`` is ``"traced"`` (the default) or
    ``"integrated"``: the top interface's single reflection computed per cell instead of traced, a
    variance reduction for the total BRDF (``docs/first-order.md``). ``parametrization = "rgl"``
    records on the RGL format's grid ``rgl`` (:class:`goniometer.grids.RGLGrid`, which then sets the
    incident directions and ``resolution = (n, n)``; ``docs/rgl-format.md``).
    """

    incident_deg: tuple[float, ...] = DEFAULT_INCIDENT
    incident_phi_deg: tuple[float, ...] | None = None
    rays: int = 1_000_000
    parametrization: str = "classic"
    resolution: tuple[int, int] = (90, 360)
    seed: int = 1
    masking: str = "separable"
    max_order: int = 5
    threads: int | None = None
    chunk_rays: int = 1 << 17
    chunks_per_task: int = 8
    event_cap: int = EVENT_CAP
    first_order: str = "traced"
    rgl: RGLGrid | None = None
    #: trace wavelengths instead of RGB channels (``docs/spectral.md``): every per-channel quantity
    #: then has one entry per wavelength bin, and ``rays`` is the number of paths per bin
    spectral: bool = False
    #: equal bins over 360-830 nm of a spectral run (a multiple of 3: a path carries three)
    wavelength_bins: int = 30
    #: where the paths are traced: "cpu" (the numba lane kernel) or "cuda" (an NVIDIA GPU through
    #: numba-cuda, ``docs/gpu.md``; the same transport, other summation: the same run statistically,
    #: not in bits)
    device: str = "cpu"
    #: trace polarized light (``docs/polarization.md``): every path carries the Mueller matrices of
    #: its channels, and the slices hold each cell's Mueller matrix beside its intensity
    polarized: bool = False

    def __post_init__(self) -> None:
        inc = tuple(float(x) for x in self.incident_deg)
        object.__setattr__(self, "incident_deg", inc)
        phi = self.incident_phi_deg
        phi = tuple(0.0 for _ in inc) if phi is None else tuple(float(x) for x in phi)
        object.__setattr__(self, "incident_phi_deg", phi)
        object.__setattr__(self, "resolution", tuple(self.resolution))
        self.validate()

    def validate(self) -> None:
        if not self.incident_deg:
            raise SettingsError("incident_deg: at least one incident direction is required")
        for t in self.incident_deg:
            if not (math.isfinite(t) and 0.0 <= t < 90.0):
                raise SettingsError(f"incident_deg: {t:g} is outside [0, 90)")
        if len(self.incident_phi_deg) != len(self.incident_deg):
            raise SettingsError("incident_phi_deg: needs one azimuth per incident elevation")
        for p in self.incident_phi_deg:
            if not (math.isfinite(p) and 0.0 <= p < 360.0):
                raise SettingsError(f"incident_phi_deg: {p:g} is outside [0, 360)")
        seen: set[tuple[float, float]] = set()
        for t, p in zip(self.incident_deg, self.incident_phi_deg):
            if (t, p) in seen:
                at = f"{t:g}" + (f" (phi {p:g})" if p else "")
                raise SettingsError(f"incident_deg: {at} is given twice; each incident direction is traced once")
            seen.add((t, p))
        _int_in(self.rays, "rays", 1, 10**13)
        if self.parametrization not in PARAMETRIZATIONS:
            raise SettingsError(f"parametrization: {self.parametrization!r} is not one of {', '.join(PARAMETRIZATIONS)}")
        self._validate_rgl()
        if len(self.resolution) != 2:
            raise SettingsError(f"resolution: {list(self.resolution)} must be [n_theta, n_phi]")
        _int_in(self.resolution[0], "resolution (n_theta)", 1, 10_000)
        _int_in(self.resolution[1], "resolution (n_phi)", 1, 40_000)
        _int_in(self.seed, "seed", 0, 2**63 - 1)
        if self.masking not in MASKING:
            raise SettingsError(f"masking: {self.masking!r} is not one of {', '.join(MASKING)}")
        _int_in(self.max_order, "max_order", 1, 64)
        if self.threads is not None:
            _int_in(self.threads, "threads", 1, MAX_THREADS)
        _int_in(self.chunk_rays, "chunk_rays", 1, 1 << 30)
        _int_in(self.chunks_per_task, "chunks_per_task", 1, 1 << 20)
        _int_in(self.event_cap, "event_cap", 1, 10**9)
        if self.first_order not in FIRST_ORDER:
            raise SettingsError(f"first_order: {self.first_order!r} is not one of {', '.join(FIRST_ORDER)}")
        if not isinstance(self.spectral, (bool, np.bool_)):
            raise SettingsError(f"spectral: {self.spectral!r} is not a boolean (true or false)")
        if not isinstance(self.polarized, (bool, np.bool_)):
            raise SettingsError(f"polarized: {self.polarized!r} is not a boolean (true or false)")
        if self.polarized and self.first_order == "integrated":
            raise SettingsError("first_order: integrated is for scalar runs (it integrates the intensity of order 1, "
                                "not its Mueller matrix); a polarized run traces it")
        _int_in(self.wavelength_bins, "wavelength_bins", 3, 471)
        if self.wavelength_bins % 3:
            raise SettingsError(f"wavelength_bins: {self.wavelength_bins} must be a multiple of 3 (each path "
                                f"carries three wavelengths), e.g. {3 * max(1, round(self.wavelength_bins / 3))}")
        if self.device not in DEVICES:
            raise SettingsError(f"device: {self.device!r} is not one of {', '.join(DEVICES)}")

    def _validate_rgl(self) -> None:
        if self.parametrization != "rgl":
            if self.rgl is not None:
                raise SettingsError(f"rgl: an RGL grid goes with parametrization rgl, not {self.parametrization}")
            return
        from goniometer.grids.rgl import RGLGrid
        if not isinstance(self.rgl, RGLGrid):
            raise SettingsError("rgl: parametrization rgl needs its grid (goniometer.grids.grid_for(stack); "
                                "gonio simulate --parametrization rgl makes it from the stack)")
        if (self.incident_deg, self.incident_phi_deg) != self.rgl.incidents():
            raise SettingsError("incident_deg: on the RGL grid the incident directions are the grid's theta_i and "
                                "phi_i nodes (set them with --rgl-grid, not --incident)")
        if tuple(self.resolution) != (self.rgl.n, self.rgl.n):
            raise SettingsError(f"resolution: on the RGL grid it is the grid's {self.rgl.n} x {self.rgl.n} nodes "
                                f"(set it with --rgl-grid, not --resolution)")
        if self.first_order != "traced":
            raise SettingsError("first_order: integrated is for classic and half slices; the RGL grid traces it")

    @classmethod
    def on_rgl_grid(cls, grid: RGLGrid, **kw: Any) -> "SimulationSettings":
        """Settings recording on ``grid``: its incident directions and resolution, the other fields
        from ``kw``."""
        theta, phi = grid.incidents()
        return cls(incident_deg=theta, incident_phi_deg=phi, parametrization="rgl", resolution=(grid.n, grid.n),
                   rgl=grid, **kw)

    def with_overrides(self, **kw: Any) -> "SimulationSettings":
        """A copy with the given non-None fields replaced."""
        return replace(self, **{k: v for k, v in kw.items() if v is not None})

    def to_dict(self) -> dict[str, Any]:
        """Every field, JSON-ready (tuples as lists, the RGL grid as its dict); :meth:`from_dict`
        reads it back. The spectral fields are left out of an RGB run's dict, the device out of a
        CPU run's (whose identities predate them)."""
        def plain(name: str, v: Any) -> Any:
            return list(v) if isinstance(v, tuple) else v.to_dict() if name == "rgl" and v is not None else v

        out = {f.name: plain(f.name, getattr(self, f.name)) for f in fields(self)}
        if not self.spectral:
            out.pop("spectral")
            out.pop("wavelength_bins")
        if not self.polarized:   # (the identities of scalar runs predate the field)
            out.pop("polarized")
        if self.device == "cpu":   # (the dicts of CPU runs predate the field: their identity stays)
            out.pop("device")
        return out

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "SimulationSettings":
        """Settings from a :meth:`to_dict` mapping; a missing key takes the field's default (the one
        place defaults live: files that predate a field are read with it). An unknown key is an
        error."""
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - names)
        if unknown:
            raise SettingsError(f"{unknown[0]}: unknown key (expected some of {', '.join(sorted(names))})")
        kw = {k: tuple(v) if isinstance(v, list) else v for k, v in d.items()}
        if isinstance(kw.get("rgl"), dict):
            from goniometer.grids.rgl import RGLGrid
            kw["rgl"] = RGLGrid.from_dict(kw["rgl"])
        return cls(**kw)

    @classmethod
    def from_mapping(cls, table: Mapping[str, Any], source: str = "simulation", stack: Any = None) -> "SimulationSettings":
        """Settings from a material file's ``[simulation]`` table (``docs/material-format.md``).
        ``parametrization = "rgl"`` (with ``rgl_grid = [N_THETA_I, N_PHI_I, N]``, optional) needs the
        ``stack``: the grid's warp follows its top interface (:func:`goniometer.grids.grid_for`)."""
        if table.get("parametrization") == "rgl" or "rgl_grid" in table:
            return cls._rgl_from_mapping(table, source, stack)
        unknown = sorted(set(table) - SIMULATION_KEYS)
        if unknown:
            raise SettingsError(f"{source}.{unknown[0]}: unknown key (allowed: {', '.join(sorted(SIMULATION_KEYS))})")
        kw: dict[str, Any] = {}
        for key, value in table.items():
            if key == "incident_deg":
                if not isinstance(value, list) or not all(_is_num(x) for x in value):
                    raise SettingsError(f"{source}.incident_deg: must be a list of numbers")
                kw[key] = tuple(value)
            elif key == "resolution":
                if not isinstance(value, list) or len(value) != 2:
                    raise SettingsError(f"{source}.resolution: must be [n_theta, n_phi]")
                kw[key] = tuple(value)
            else:   # a scalar field, validated by the settings themselves
                kw[key] = value
        try:
            return cls(**kw)
        except SettingsError as e:
            raise SettingsError(f"{source}.{e}") from None

    @classmethod
    def _rgl_from_mapping(cls, table: Mapping[str, Any], source: str, stack: Any) -> "SimulationSettings":
        from goniometer.grids.rgl import RGLGridError, grid_for
        if table.get("parametrization") != "rgl":
            raise SettingsError(f"{source}.rgl_grid: goes with parametrization = \"rgl\"")
        for key in ("incident_deg", "resolution"):
            if key in table:
                raise SettingsError(f"{source}.{key}: the RGL grid sets it (its theta_i, phi_i and n); "
                                    f"use rgl_grid = [N_THETA_I, N_PHI_I, N]")
        if stack is None:
            raise SettingsError(f"{source}.parametrization: rgl needs the stack (the warp follows its top interface)")
        spec = table.get("rgl_grid", [None, None, None])
        if not isinstance(spec, list) or len(spec) != 3 or not all(x is None or _is_int(x) for x in spec):
            raise SettingsError(f"{source}.rgl_grid: must be [N_THETA_I, N_PHI_I, N] (integers, e.g. [8, 1, 32])")
        rest = {k: v for k, v in table.items() if k not in ("parametrization", "rgl_grid")}
        plain = cls.from_mapping(rest, source)
        try:
            grid = grid_for(stack, *spec)
        except RGLGridError as e:
            raise SettingsError(f"{source}.rgl_grid: {str(e).split(': ', 1)[-1]}") from None
        fields = {k: getattr(plain, k) for k in ("rays", "seed", "masking", "max_order", "threads", "first_order",
                                                 "spectral", "wavelength_bins", "polarized")}
        try:
            return cls.on_rgl_grid(grid, **fields)
        except SettingsError as e:
            raise SettingsError(f"{source}.{e}") from None


def _is_int(x: Any) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def _is_num(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _int_in(value: Any, name: str, lo: int, hi: int) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise SettingsError(f"{name}: {value!r} is not an integer in [{lo}, {hi}]")
    if not lo <= value <= hi:
        raise SettingsError(f"{name}: {value} is outside [{lo}, {hi}]")


#: default rays of a tabulation (``gonio tabulate``): about 180 paths per cell of non-zero measure of the
#: MERL grid on average for a diffuse material (``docs/tabulated-format.md``)
TABULATE_RAYS = 200_000_000


@dataclass(frozen=True)
class TabulationSettings(_Channels):
    """What to tabulate (``docs/tabulated-format.md``): ``rays`` paths in all, each with its own
    incident direction. ``seed`` and ``chunk_rays`` (rays per random stream) make the determinism
    contract: the same pair gives the same bits whatever ``threads``. Fields mean what they mean
    in :class:`SimulationSettings`, whose validation they share."""

    rays: int = TABULATE_RAYS
    seed: int = 1
    masking: str = "separable"
    threads: int | None = None
    chunk_rays: int = 1 << 16
    event_cap: int = EVENT_CAP
    #: a spectral tabulation (``docs/spectral.md`` section 1): ``rays`` paths per wavelength bin
    spectral: bool = False
    wavelength_bins: int = 30
    device: str = "cpu"
    #: a polarized tabulation (``docs/polarization.md`` section 5): each cell holds its Mueller
    #: matrix beside its intensity, in the "plane" frames
    polarized: bool = False

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        SimulationSettings(incident_deg=(0.0,), rays=self.rays, seed=self.seed, masking=self.masking,
                           threads=self.threads, chunk_rays=self.chunk_rays, event_cap=self.event_cap,
                           spectral=self.spectral, wavelength_bins=self.wavelength_bins, device=self.device,
                           polarized=self.polarized)

    def with_overrides(self, **kw: Any) -> "TabulationSettings":
        """A copy with the given non-None fields replaced."""
        return replace(self, **{k: v for k, v in kw.items() if v is not None})
