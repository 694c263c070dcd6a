"""crocoddyl's FDDP / BoxFDDP as a baseline on raico's own problems, one adapter package.

- :mod:`raico.planning.crocoddyl.model`: the optional import of crocoddyl and Pinocchio (``AVAILABLE``),
  ``NotExpressible``, a robot's Pinocchio model and the coordinates between raico and Pinocchio;
- :mod:`raico.planning.crocoddyl.costs`: each raico cost term as crocoddyl residuals and activations;
- :mod:`raico.planning.crocoddyl.solve`: the ``ShootingProblem`` of a raico problem (:func:`build`) and
  FDDP on it (:func:`fddp`, registered as solvers ``fddp*`` in :mod:`raico.planning.solvers`).
"""

from raico.planning.crocoddyl.model import (
    AVAILABLE,
    CONTINUOUS,
    UNAVAILABLE_REASON,
    NotExpressible,
    StateMap,
    frame_id,
    model_from_drake,
    pinocchio_robot,
)
from raico.planning.crocoddyl.solve import (
    CrocoddylProblem,
    FDDPOptions,
    build,
    fddp,
    result,
)

__all__ = ["AVAILABLE", "CONTINUOUS", "UNAVAILABLE_REASON", "CrocoddylProblem",
           "FDDPOptions", "NotExpressible", "StateMap", "build", "fddp", "frame_id", "model_from_drake",
           "pinocchio_robot", "result"]
