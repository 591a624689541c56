"""How paths are traced (``docs/kernel.md``, ``docs/gpu.md``): one physics, two drivers.

The face:

* :mod:`~goniometer.kernel.tracer` -- the launch face: a run's kernel call prepared once
  (``prepare``, a ``Launch``: the stack's facts, the variant, the chunk arithmetic) and launched per
  batch of chunks (``launch``) on the lane kernel, the per-path kernel or the CUDA kernel; the
  output layouts (``E_*``, ``N_*``, ``C_*``);
* :mod:`~goniometer.kernel.packing` -- the packed stack the kernels read (``PackedStack``, ``pack``,
  the base and film codes ``BASE_*``, ``FL_*``);
* :mod:`~goniometer.kernel.variants` -- what a stack is, as the kernels need to know it, worked out
  once (``StackFacts``), the variant (``Variant``) and the kernels' stack argument (``Derived``,
  ``KernelStack``);
* :mod:`~goniometer.kernel.rng` -- random numbers: per-path keys, counter-based draws, xoshiro256**.

The per-path transport and its drivers:

* :mod:`~goniometer.kernel.onepath` -- the per-path transport, ``trace_path``: one path from start
  to end, the transport rules in one place;
* :mod:`~goniometer.kernel.paths` -- the per-path kernel, its CPU driver (the tests' second
  implementation, ``KERNEL_PATHS``);
* :mod:`~goniometer.kernel.cuda` -- the CUDA kernel, its GPU driver (numba-cuda; imported only for a
  ``"cuda"`` run);
* :mod:`~goniometer.kernel.cuda_build` -- the CUDA kernel compiled for sm_80 and sm_90 without a
  GPU: PTX, ``ptxas -v``'s registers and spills, occupancy.

The lane kernel (the CPU's, for every stack), its own vectorised event loop over the same optics:

* :mod:`~goniometer.kernel.layout` -- the lane state (one flat array, a row per field) and the
  stack's table read by the vectorised event;
* :mod:`~goniometer.kernel.event` -- the event every active lane takes in one step, written
  branch-free so that LLVM vectorises it across lanes;
* :mod:`~goniometer.kernel.steps` -- what a path does alone, in both kinds of kernel: free flights
  in scattering media, random walks on multiple-scattering interfaces, the thin films' events, and
  the lane kernel's continuation of a walk;
* :mod:`~goniometer.kernel.deposit` -- exits to histogram cells, in exit order;
* :mod:`~goniometer.kernel.codegen` -- the few LLVM-level helpers (bit casts, a stack table,
  prefetch, the vector-width hint).
"""

#: no public names at the package level: ``goniometer.kernel.tracer`` is the face
__all__: list[str] = []
