"""crocoddyl's FDDP / BoxFDDP as a baseline on raico's own problems, one adapter package.

- :mod:`planning.crocoddyl.model`: the optional import of crocoddyl and Pinocchio (``AVAILABLE``),
  ``NotExpressible``, a robot's Pinocchio model and the coordinates between raico and Pinocchio;
- :mod:`planning.crocoddyl.costs`: each raico cost term as crocoddyl residuals and activations;
- :mod:`planning.crocoddyl.solve`: the ``ShootingProblem`` of a raico problem (:func:`build`) and
  FDDP on it (:func:`fddp`, registered as solvers ``fddp*`` in :mod:`planning.solvers`).
"""

from planning.crocoddyl.model import (
    AVAILABLE,
    CONTINUOUS,
    UNAVAILABLE_REASON,
    NotExpressible,
    StateMap,
    frame_id,
    model_from_drake,
    pinocchio_robot,
)
from planning.crocoddyl.solve import (
    CrocoddylProblem,
    FDDPOptions,
    build,
    fddp,
    result,
)

__all__ = ["AVAILABLE", "CONTINUOUS", "UNAVAILABLE_REASON", "CrocoddylProblem",
           "FDDPOptions", "NotExpressible", "StateMap", "build", "fddp", "frame_id", "model_from_drake",
           "pinocchio_robot", "result"]
