"""The robots: models, dynamics, task maps."""

from plants import threads  # noqa: F401  (one BLAS thread: set before numpy loads)
