"""One BLAS thread per process (the one place this is set).

Small dense linear algebra dominates here: one BLAS thread per process is faster than several
(parallelism comes from worker processes). Must run before numpy loads, so the ``__init__`` of
every package (``plants``, ``stages``, ``pipeline``, ``bench``) and ``tests/conftest.py``
import this module first; users may override by setting the variables themselves.
"""

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
