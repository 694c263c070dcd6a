"""Pure stage functions."""

import plants._threads  # noqa: F401  (one BLAS thread: set before numpy loads)
