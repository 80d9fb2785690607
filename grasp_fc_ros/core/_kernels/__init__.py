"""Compiled (numba) building blocks shared by the core's interior-point stages.

The exact stage (:mod:`..exact.interior_point`), the s* stage (:mod:`..forces.force_interior_point`)
and, through the exact stage's signed mode, the mu* stage (:mod:`..quality.minimum_friction`)
are written from these pieces. Every function here is compiled with :func:`.jit.jit`
and works on one grasp in unit size: arrays are float64, C-contiguous, and outputs go
into arrays the caller owns (the stages reuse their scratch from grasp to grasp).

* :mod:`.jit` -- the JIT decorator and the array form every kernel takes;
* :mod:`.frames` -- per-contact frames, wrench rows and the work of a wrench at a contact;
* :mod:`.grasp_map` -- the grasp map G: G G^T, G f, per-contact congruences, and a
  certified rank-6 test;
* :mod:`.linear_algebra` -- the 6 x 6 Cholesky factor, its solves and inverse norm;
* :mod:`.cones` -- the second-order cone Q^3: Nesterov-Todd scaling, Jordan product and
  division, the longest step inside the cone.
"""
