"""Drake's equations of motion compiled to vectorized numpy (the fast analytic route, SPEC §4).

- :mod:`plants.codegen.graph`: a hash-consed DAG of scalar operations, simplification and
  forward-mode derivatives;
- :mod:`plants.codegen.emit`: straight-line Python source from the DAG, compiled for floats
  and ``(T,)`` arrays;
- :mod:`plants.codegen.drake_reader`: Drake's symbolic inverse dynamics and mass matrix read
  into the DAG, and the cyclic (vertical-axis) joints;
- :mod:`plants.codegen.derive`: derivation per plant with a build-time self-check against
  Drake, cached per plant name.

The model built on it is :class:`plants.fast_analytic.FastAnalyticDynamics`. This package
imports nothing from the rest of ``plants``.
"""
