"""The RGL tensor format (Dupuy & Jakob 2018), the measured BRDFs Mitsuba 3's and pbrt-v4's
``measured`` materials read: the container (:mod:`~goniometer.rgl.tensor`), the sample-space warp
(:mod:`~goniometer.rgl.warp`), the grid a run records on (:mod:`~goniometer.rgl.grid`) and the export
of such a run to the files both readers take (:mod:`~goniometer.rgl.export`). ``docs/rgl-format.md``.

Names are loaded on first use: the tracer imports the warp alone.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

_EXPORTS = {
    "TensorError": "goniometer.rgl.tensor", "TensorFile": "goniometer.rgl.tensor",
    "read_tensor": "goniometer.rgl.tensor", "write_tensor": "goniometer.rgl.tensor",
    "Warp2D": "goniometer.rgl.warp",
    "RGLGrid": "goniometer.rgl.grid", "RGLGridError": "goniometer.rgl.grid", "grid_for": "goniometer.rgl.grid",
    "ExportError": "goniometer.rgl.export", "export_rgl": "goniometer.rgl.export",
    "bsdf_fields": "goniometer.rgl.export", "check_readers": "goniometer.rgl.export",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'goniometer.rgl' has no attribute {name!r}")
    value = getattr(import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
