"""What the project's tests check the simulator against, for plugin authors' tests too.

* :mod:`~goniometer.testing.smooth` -- closed forms for perfectly smooth stacks (the adding
  equations), the simulator's exact oracles.
"""

from goniometer._lazy import lazy_face

_EXPORTS = {
    "adding_energies": "goniometer.testing.smooth", "coated_lambertian_brdf": "goniometer.testing.smooth",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_face(__name__, _EXPORTS)
