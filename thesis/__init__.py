"""The thesis's reproduction on top of the tool: its figures' definitions (:mod:`thesis.figures`, read from
its experiment files in ``thesis/experiments/``), its claims (:mod:`thesis.claims`), the report
(:mod:`thesis.report`), ``raico reproduce`` (:mod:`thesis.reproduce`, the command registered by
:mod:`thesis.cli`) and its Python function (:mod:`thesis.api`).

The tool's layers (``pipeline``, ``stages``, ``planning``, ``plants``) import nothing from here.
"""

import plants.threads  # noqa: F401  (one BLAS thread: set before numpy loads)
