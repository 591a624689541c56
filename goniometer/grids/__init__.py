"""Where light is recorded: the cells of a run's slices and of tabulations.

* :mod:`~goniometer.grids.slice_grid` -- classic and half slices (:class:`SliceGrid`): a direction
  to its cell, a cell to its sub-cell directions and solid angles (``docs/slices-format.md``);
* :mod:`~goniometer.grids.halfdiff` -- the MERL half/difference grid of tabulations
  (``docs/tabulated-format.md``);
* :mod:`~goniometer.grids.rgl` and :mod:`~goniometer.grids.warp` -- the RGL format's sample space
  and its warp (``docs/rgl-format.md``);
* :mod:`~goniometer.grids.stokes` -- the Stokes frames of polarized slices and their conversion to
  Mitsuba 3's (``docs/polarization.md``).
"""

from goniometer._lazy import lazy_face

_EXPORTS = {
    "SliceGrid": "goniometer.grids.slice_grid", "light_direction": "goniometer.grids.slice_grid",
    "RGLGrid": "goniometer.grids.rgl", "RGLGridError": "goniometer.grids.rgl", "grid_for": "goniometer.grids.rgl",
    "Warp2D": "goniometer.grids.warp",
    "convert_mueller": "goniometer.grids.stokes",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_face(__name__, _EXPORTS)
