"""A run: what to simulate, how its work is split and summed, and what it produces.

* :mod:`~goniometer.run.settings` -- :class:`SimulationSettings`, :class:`TabulationSettings`;
* :mod:`~goniometer.run.loop` -- the one loop over incident directions (:func:`simulate`,
  :func:`run_incidents`);
* :mod:`~goniometer.run.tasks` -- chunks and tasks traced by the kernel, summed in fixed order;
  :mod:`~goniometer.run.distributed` -- the same tasks on a Dask cluster;
* :mod:`~goniometer.run.launches` -- a spectral run's launches of three wavelengths, and
  :mod:`~goniometer.run.rgb` -- a spectral result reduced to linear sRGB (``docs/spectral.md``);
* :mod:`~goniometer.run.first_order` -- bounce order 1 integrated over the cells
  (``docs/first-order.md``);
* :mod:`~goniometer.run.results` -- result types and run identity; :mod:`~goniometer.run.checkpoints`
  -- the finished parts of an interrupted run;
* :mod:`~goniometer.run.tabulation` -- a tabulation's run (``docs/tabulated-format.md``).
"""

from goniometer._lazy import lazy_face

_EXPORTS = {
    "SimulationSettings": "goniometer.run.settings", "TabulationSettings": "goniometer.run.settings",
    "SettingsError": "goniometer.run.settings",
    "simulate": "goniometer.run.loop", "run_incidents": "goniometer.run.loop",
    "Checkpoints": "goniometer.run.checkpoints", "CheckpointMismatch": "goniometer.run.checkpoints",
    "SimulationResult": "goniometer.run.results", "SliceData": "goniometer.run.results",
    "tabulate": "goniometer.run.tabulation",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_face(__name__, _EXPORTS)
