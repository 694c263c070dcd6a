"""The tool around the stages: engine (cache, runner), recordings, experiments, interface (CLI, API);
``errors`` (the error types) and ``lifecycle`` (signals, child processes) beneath them all."""

import raico.plants.threads  # noqa: F401  (one BLAS thread: set before numpy loads)
