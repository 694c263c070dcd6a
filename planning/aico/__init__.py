"""AICO and R-AICO: approximate inference control with Gaussian messages, one implementation
(R-AICO is AICO with ``alpha > 0``, thesis §3.5, Algorithm 1).

- :mod:`planning.aico.options`: :class:`AICOOptions` and the plan-stage flags that set them;
- :mod:`planning.aico.sweeps`: the messages and per-step updates of one run (:class:`Sweeps`,
  the numpy reference of the compiled kernel ``planning/csweep.c``);
- :mod:`planning.aico.bounds`: hard bounds as an augmented Lagrangian, the cost's curvature;
- :mod:`planning.aico.steps`: the step rules (fixed, adaptive and robust schedules);
- :mod:`planning.aico.solve`: the entry point :func:`aico`.
"""

from planning.aico.options import SCHEDULES, AICOOptions
from planning.aico.solve import aico

__all__ = ["SCHEDULES", "AICOOptions", "aico"]
