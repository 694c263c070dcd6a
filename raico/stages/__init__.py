"""Pure stage functions."""

import raico.plants.threads  # noqa: F401  (one BLAS thread: set before numpy loads)
