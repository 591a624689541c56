"""What the project's tests check the simulator against, for plugin authors' tests too
(``docs/testing.md``).

* :mod:`~goniometer.testing.statistics` -- the statistical checks of Monte Carlo results: the
  false-alarm conventions (``P_FALSE_ALARM``, ``Z_TOL``, ``chi2_limit``), the per-cell chi-square
  against a model (cells judged where about 20 exits are expected, sparse regions in aggregate,
  sigma under the model), two simulations against each other, values and energies within their
  standard errors.
* :mod:`~goniometer.testing.smooth` -- closed forms for perfectly smooth stacks (the adding
  equations), the simulator's exact oracles.
"""

from goniometer._lazy import lazy_face

_STATISTICS = (
    "P_FALSE_ALARM", "Z_TOL", "MIN_EXPECTED", "MIN_CELLS", "chi2_limit", "chi2_interval", "noise_floor_ratio_limit",
    "expected_exits", "model_sigma", "cell_chi2", "assert_cells_match", "flux", "sparse_flux",
    "assert_sparse_flux_matches", "mean_stderr", "effective_exits", "two_sample_chi2", "assert_samples_match",
    "assert_z_close", "energy_total", "assert_energy_conserved", "assert_energy_matches",
)
_EXPORTS = {
    "adding_energies": "goniometer.testing.smooth", "coated_lambertian_brdf": "goniometer.testing.smooth",
    **{name: "goniometer.testing.statistics" for name in _STATISTICS},
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_face(__name__, _EXPORTS)
