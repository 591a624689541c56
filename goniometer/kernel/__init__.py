"""The parts of the tracer's lane kernel (``docs/kernel.md``); :mod:`goniometer.kernel.tracer` drives them.

* :mod:`~goniometer.kernel.layout` -- the lane state (one flat array, a row per field) and the
  stack's table read by the vectorised event;
* :mod:`~goniometer.kernel.event` -- the event every active lane takes in one step, written
  branch-free so that LLVM vectorises it across lanes;
* :mod:`~goniometer.kernel.steps` -- what a lane does alone: free flights in scattering media and
  random walks on multiple-scattering interfaces;
* :mod:`~goniometer.kernel.deposit` -- exits to histogram cells, in exit order;
* :mod:`~goniometer.kernel.codegen` -- the few LLVM-level helpers (bit casts, a stack table,
  prefetch, the vector-width hint).
"""

#: no public names: the kernel's parts are the tracer's internals (``goniometer.kernel.tracer`` is the face)
__all__: list[str] = []
