"""Small dense linear algebra dominates here: one BLAS thread per process is faster than
several (parallelism comes from worker processes). Set before numpy loads; users may override."""

import os as _os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_var, "1")
