"""AICO and R-AICO: approximate inference control with Gaussian messages, one implementation
(R-AICO is AICO with ``alpha > 0``, thesis §3.5, Algorithm 1).

- :mod:`raico.planning.aico.options`: :class:`AICOOptions` and the plan-stage flags that set them;
- :mod:`raico.planning.aico.sweeps`: the messages and per-step updates of one run (:class:`Sweeps`,
  the numpy reference of the compiled kernel ``raico/planning/csweep.c``);
- :mod:`raico.planning.aico.bounds`: hard bounds as an augmented Lagrangian, the cost's curvature;
- :mod:`raico.planning.aico.steps`: the step rules (fixed, adaptive and robust schedules);
- :mod:`raico.planning.aico.solve`: the entry point :func:`aico`.
"""

from raico.planning.aico.options import SCHEDULES, AICOOptions
from raico.planning.aico.solve import aico

__all__ = ["SCHEDULES", "AICOOptions", "aico"]
