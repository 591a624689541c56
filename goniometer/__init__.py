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

from goniometer import cache as _cache
from goniometer._lazy import lazy_face

__version__ = "0.1.0"

#: where numba caches the simulator's compiled kernels (keyed by its sources: goniometer.cache)
NUMBA_CACHE_DIR = _cache.configure()

_EXPORTS = {
    # stacks
    "Stack": "goniometer.stack", "Interface": "goniometer.stack", "Medium": "goniometer.stack",
    "Lambertian": "goniometer.stack", "StackError": "goniometer.stack", "stack_from_dict": "goniometer.stack",
    "load_stack": "goniometer.stack",
    # running
    "SimulationSettings": "goniometer.run.settings", "SettingsError": "goniometer.run.settings",
    "simulate": "goniometer.run.loop", "run_incidents": "goniometer.run.loop",
    "Checkpoints": "goniometer.run.checkpoints",
    # results and files
    "SimulationResult": "goniometer.run.results", "SliceData": "goniometer.run.results",
    "SliceGrid": "goniometer.grids.slice_grid", "light_direction": "goniometer.grids.slice_grid",
    "read": "goniometer.files.slices", "write": "goniometer.files.slices", "describe": "goniometer.files.slices",
    "StoreError": "goniometer.files.slices",
    # tabulated BRDFs (the MERL grid)
    "TabulationSettings": "goniometer.run.settings", "tabulate": "goniometer.run.tabulation",
    "TabulatedBRDF": "goniometer.run.results", "read_tabulated": "goniometer.files.tabulated",
    "write_tabulated": "goniometer.files.tabulated", "write_merl": "goniometer.files.merl",
    # the RGL tensor format (Mitsuba 3's and pbrt-v4's measured materials; docs/rgl-format.md)
    "read_tensor": "goniometer.files.rgl_tensor", "write_tensor": "goniometer.files.rgl_tensor",
    "TensorError": "goniometer.files.rgl_tensor", "RGLGrid": "goniometer.grids.rgl",
    "export_rgl": "goniometer.files.rgl_export",
    # xarray views (optional extra "xarray")
    "open_dataset": "goniometer.files.dataset", "open_datatree": "goniometer.files.dataset",
    # databases
    "load_database": "goniometer.database", "simulate_database": "goniometer.database",
    "DatabaseError": "goniometer.database",
}

__all__ = sorted(_EXPORTS) + ["__version__", "NUMBA_CACHE_DIR"]


__getattr__, __dir__ = lazy_face(__name__, _EXPORTS)
