"""The thesis's reproduction on top of the tool: its figures' definitions (:mod:`raico.thesis.figures`, read from
its experiment files in ``raico/thesis/experiments/``), its claims (:mod:`raico.thesis.claims`), the report
(:mod:`raico.thesis.report`), ``raico reproduce`` (:mod:`raico.thesis.reproduce`, the command registered by
:mod:`raico.thesis.cli`) and its Python function (:mod:`raico.thesis.api`).

The tool's layers (``pipeline``, ``stages``, ``planning``, ``plants``) import nothing from here.
"""

import raico.plants.threads  # noqa: F401  (one BLAS thread: set before numpy loads)
