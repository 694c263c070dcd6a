"""Drake's equations of motion compiled to vectorized numpy (the fast analytic route).

- :mod:`raico.plants.codegen.graph`: a hash-consed DAG of scalar operations, simplification and
  forward-mode derivatives;
- :mod:`raico.plants.codegen.emit`: straight-line Python source from the DAG, compiled for floats
  and ``(T,)`` arrays;
- :mod:`raico.plants.codegen.drake_reader`: Drake's symbolic inverse dynamics and mass matrix read
  into the DAG, and the cyclic (vertical-axis) joints;
- :mod:`raico.plants.codegen.derive`: derivation per plant with a build-time self-check against
  Drake, cached per plant name;
- :mod:`raico.plants.codegen.c_backend`: the same code as C (gcc, a disk cache keyed by the source,
  ``ctypes``) and scipy's BLAS/LAPACK addresses for compiled kernels;
- :mod:`raico.plants.codegen.rbd`: the kinematic tree read from Drake, compiled: forward kinematics,
  Jacobians, mass matrix, Newton-Euler inverse dynamics and its derivatives (forward mode and
  analytical), task messages
  (for plants too large for the symbolic route, and for the task maps).

The models built on it are :class:`raico.plants.fast_analytic.FastAnalyticDynamics` and
:class:`raico.plants.fast_analytic.TreeAnalyticDynamics`. This package imports nothing from the rest
of ``plants``.
"""
