"""The robots: models, dynamics, task maps."""

from raico.plants import threads  # noqa: F401  (one BLAS thread: set before numpy loads)
