"""goniometer: a Monte Carlo virtual goniometer for layered materials (the simulator floor).

Stacks in, HDF5 BRDF/BTDF slices out. The public face, for notebooks and scripts::

    import goniometer as g
    stack = g.stack_from_dict({...})            # or g.load_stack("material.toml")
    result = g.simulate(stack, g.SimulationSettings(incident_deg=(30,), rays=300_000))
    g.write("material.h5", result); g.read("material.h5")
    ds = g.open_dataset("material.h5", side="brdf")   # xarray (extra "xarray"), masked cells NaN

Whole isotropic BRDFs on the MERL grid: ``g.tabulate(stack, g.TabulationSettings(...))``,
``g.read_tabulated(path).eval(l, v)`` (``docs/tabulated-format.md``). Into Mitsuba 3 and pbrt-v4:
``g.SimulationSettings.on_rgl_grid(grid)``, ``g.export_rgl(result, "m.bsdf")``, ``g.read_tensor(path)``
(``docs/rgl-format.md``).

Contracts: ``docs/material-format.md``, ``docs/slices-format.md``, ``docs/database-format.md``,
``docs/xarray.md``, ``docs/architecture.md``. Names are loaded on first use, so ``import goniometer`` stays light.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

from goniometer import cache as _cache

__version__ = "0.1.0"

#: where numba caches the simulator's compiled kernels (keyed by its sources: goniometer.cache)
NUMBA_CACHE_DIR = _cache.configure()

_EXPORTS = {
    # stacks
    "Stack": "goniometer.stack", "Interface": "goniometer.stack", "Medium": "goniometer.stack",
    "Lambertian": "goniometer.stack", "StackError": "goniometer.stack", "stack_from_dict": "goniometer.stack",
    "load_stack": "goniometer.stack",
    # running
    "SimulationSettings": "goniometer.settings", "SettingsError": "goniometer.settings",
    "simulate": "goniometer.run", "run_incidents": "goniometer.run",
    "Checkpoints": "goniometer.checkpoint",
    # results and files
    "SimulationResult": "goniometer.results", "SliceData": "goniometer.results", "SliceGrid": "goniometer.slices",
    "light_direction": "goniometer.slices",
    "read": "goniometer.store", "write": "goniometer.store", "describe": "goniometer.store",
    "StoreError": "goniometer.store",
    # tabulated BRDFs (the MERL grid)
    "TabulationSettings": "goniometer.settings", "tabulate": "goniometer.tabulation",
    "TabulatedBRDF": "goniometer.tabulated", "read_tabulated": "goniometer.tabulated",
    "write_tabulated": "goniometer.tabulated", "write_merl": "goniometer.merl",
    # the RGL tensor format (Mitsuba 3's and pbrt-v4's measured materials; docs/rgl-format.md)
    "read_tensor": "goniometer.rgl.tensor", "write_tensor": "goniometer.rgl.tensor",
    "TensorError": "goniometer.rgl.tensor", "RGLGrid": "goniometer.rgl.grid", "export_rgl": "goniometer.rgl.export",
    # xarray views (optional extra "xarray")
    "open_dataset": "goniometer.dataset", "open_datatree": "goniometer.dataset",
    # databases
    "load_database": "goniometer.database", "simulate_database": "goniometer.database",
    "DatabaseError": "goniometer.database",
}

__all__ = sorted(_EXPORTS) + ["__version__", "NUMBA_CACHE_DIR"]


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'goniometer' has no attribute {name!r}")
    value = getattr(import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
