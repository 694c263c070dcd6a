"""The tool around the stages: engine (cache, runner), recordings, experiments, interface (CLI, API)."""

import plants.threads  # noqa: F401  (one BLAS thread: set before numpy loads)
