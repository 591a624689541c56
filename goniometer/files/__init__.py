"""The file formats: what the simulator writes and reads (``docs/outputs.md``).

* :mod:`~goniometer.files.slices` -- HDF5 slices files (``docs/slices-format.md``);
* :mod:`~goniometer.files.tabulated` -- tabulated BRDFs on the MERL grid (``docs/tabulated-format.md``),
  :mod:`~goniometer.files.merl` -- their MERL ``.binary`` export;
* :mod:`~goniometer.files.rgl_tensor`, :mod:`~goniometer.files.rgl_export` -- the RGL tensor format
  and the export Mitsuba 3 and pbrt-v4 read (``docs/rgl-format.md``);
* :mod:`~goniometer.files.measured` -- measured BRDFs as references (``docs/measured.md``);
* :mod:`~goniometer.files.dataset` -- xarray views of the HDF5 files (``docs/xarray.md``);
* :mod:`~goniometer.files.outputs` -- the overwrite policy of every command that writes.
"""

from goniometer._lazy import lazy_face

_EXPORTS = {
    "read": "goniometer.files.slices", "write": "goniometer.files.slices", "describe": "goniometer.files.slices",
    "StoreError": "goniometer.files.slices",
    "read_tabulated": "goniometer.files.tabulated", "write_tabulated": "goniometer.files.tabulated",
    "TabulatedError": "goniometer.files.tabulated", "write_merl": "goniometer.files.merl",
    "read_tensor": "goniometer.files.rgl_tensor", "write_tensor": "goniometer.files.rgl_tensor",
    "TensorError": "goniometer.files.rgl_tensor", "TensorFile": "goniometer.files.rgl_tensor",
    "export_rgl": "goniometer.files.rgl_export", "ExportError": "goniometer.files.rgl_export",
    "read_measured": "goniometer.files.measured", "MeasuredBRDF": "goniometer.files.measured",
    "MeasuredError": "goniometer.files.measured",
    "open_dataset": "goniometer.files.dataset", "open_datatree": "goniometer.files.dataset",
    "OutputError": "goniometer.files.outputs", "check_output": "goniometer.files.outputs",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_face(__name__, _EXPORTS)
