"""Solver registry: ``solve(problem, "aico" | "raico" | "ilqg", options_dict)``; with
crocoddyl installed also ``"fddp"`` and ``"fddp-rollout"`` (the baseline the report compares with).

``SOLVERS[name]`` is a ``SolverSpec`` (crocoddyl's made on first use by ``get_solver``): the solver function, its options class and the
defaults the name implies ("raico" is AICO with ``alpha = 1`` unless given, and requires
``alpha > 0``; "aico" requires ``alpha = 0``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from planning.aico import AICOOptions, aico
from planning.ilqg import ILQGOptions, ilqg
from planning.problem import IterateHistory, OptionsBase, Problem, Result, iterate_steps


@dataclass(frozen=True)
class SolverSpec:
    """A registered solver: ``run(problem, options, **init) -> Result``."""

    name: str
    run: Callable[..., Result]
    options_cls: type[OptionsBase]
    defaults: dict[str, Any] = field(default_factory=dict)
    check: Callable[[Any], None] | None = None

    def options(self, d: dict[str, Any] | OptionsBase | None = None) -> OptionsBase:
        """Validated options from a dict (unknown keys rejected) or an options object."""
        if isinstance(d, OptionsBase):
            if not isinstance(d, self.options_cls):
                raise TypeError(f"solver {self.name!r} takes {self.options_cls.__name__}, "
                                 f"got {type(d).__name__}")
            opts = d
        else:
            opts = self.options_cls.from_dict(d, **self.defaults)
        if self.check is not None:
            self.check(opts)
        return opts


def _check_aico(o: AICOOptions) -> None:
    if o.alpha != 0:
        raise ValueError(f"solver 'aico' is plain AICO (alpha = 0), got alpha={o.alpha}; "
                         "use solver 'raico' for alpha > 0")


def _check_raico(o: AICOOptions) -> None:
    if not o.alpha > 0:
        raise ValueError(f"solver 'raico' needs alpha > 0, got alpha={o.alpha}; "
                         "use solver 'aico' for alpha = 0")


SOLVERS: dict[str, SolverSpec | None] = {   # None: made on first use (crocoddyl's)
    "aico": SolverSpec("aico", aico, AICOOptions, {"alpha": 0.0}, _check_aico),
    "raico": SolverSpec("raico", aico, AICOOptions, {"alpha": 1.0}, _check_raico),
    "ilqg": SolverSpec("ilqg", ilqg, ILQGOptions),
}


CROCODDYL_SOLVERS = ("fddp", "fddp-rollout", "fddp-rollout-accept-any", "fddp-rollout-ilqg-schedule", "boxfddp")


def _register_crocoddyl() -> None:
    """The crocoddyl baseline's names, where crocoddyl and pinocchio are installed: their specs are made
    (and crocoddyl imported) when one is first asked for (:func:`get_solver`), so that listing or
    checking a solver name loads neither."""
    from importlib.util import find_spec

    if find_spec("crocoddyl") is not None and find_spec("pinocchio") is not None:
        SOLVERS.update(dict.fromkeys(CROCODDYL_SOLVERS))


def _crocoddyl_specs() -> dict[str, SolverSpec]:
    """The crocoddyl baseline (``planning.crocoddyl``): ``fddp`` starts from ``x0`` held at every
    node (R-AICO's start), ``fddp-rollout`` from the zero-torque rollout; ``fddp-rollout-accept-any``
    and ``fddp-rollout-ilqg-schedule`` are the ablations with iLQG's acceptance rule and its
    regularization schedule."""
    from planning import crocoddyl as cm

    if not cm.AVAILABLE:
        raise ValueError(f"crocoddyl's solvers cannot run here: {cm.UNAVAILABLE_REASON}")
    specs: dict[str, SolverSpec] = {}

    def check(start: str):
        def _check(o) -> None:
            if o.start != start:
                raise ValueError(f"solver starts from '{start}', got start={o.start!r}")
        return _check

    specs["fddp"] = SolverSpec("fddp", cm.fddp, cm.FDDPOptions, {"start": "held"}, check("held"))
    specs["fddp-rollout"] = SolverSpec("fddp-rollout", cm.fddp, cm.FDDPOptions, {"start": "rollout"},
                                       check("rollout"))
    # ablation (why iLQG stalls): FDDP accepting any step that lowers the cost, iLQG's rule
    specs["fddp-rollout-accept-any"] = SolverSpec(
        "fddp-rollout-accept-any", cm.fddp, cm.FDDPOptions,
        {"start": "rollout", "th_accept": cm.ACCEPT_ANY}, check("rollout"))
    # ablation: FDDP with iLQG's regularization schedule (lower it after every accepted step)
    specs["fddp-rollout-ilqg-schedule"] = SolverSpec(
        "fddp-rollout-ilqg-schedule", cm.fddp, cm.FDDPOptions, {"start": "rollout", **cm.ILQG_SCHEDULE},
        check("rollout"))
    # BoxFDDP from x0 held: the control limits (the problem's hard effort bounds, its control-limit terms) as
    # BoxDDP's box on the control QP; "fddp" takes it too where limits exist (box "auto"), this name insists
    specs["boxfddp"] = SolverSpec("boxfddp", cm.fddp, cm.FDDPOptions, {"start": "held", "box": "yes"}, check("held"))
    assert tuple(specs) == CROCODDYL_SOLVERS
    return specs


_register_crocoddyl()


def make_options(solver_name: str, options: dict[str, Any] | OptionsBase | None = None):
    """The validated options object of ``solver_name`` built from ``options``."""
    return get_solver(solver_name).options(options)


def get_solver(solver_name: str) -> SolverSpec:
    """The registered solver called ``solver_name`` (``ValueError`` naming the valid ones)."""
    if solver_name not in SOLVERS:
        raise ValueError(f"unknown solver {solver_name!r}; valid solvers: {sorted(SOLVERS)}")
    if SOLVERS[solver_name] is None:    # a crocoddyl solver's first use: import it
        SOLVERS.update(_crocoddyl_specs())
    return SOLVERS[solver_name]


def solve(problem: Problem, solver_name: str,
          options: dict[str, Any] | OptionsBase | None = None, **init: Any) -> Result:
    """Run ``solver_name`` on ``problem`` with options from a dict (or an options object).

    ``init`` is passed to the solver (``U_init``, ``X_init`` for AICO, ``callback``).

    The result's ``X_iterations (iterations + 1, K, n_x)`` (float32) holds every iteration's
    trajectory at the steps ``t_iterations = iterate_steps(problem)``, collected through the
    solver's callback (``IterateHistory``, called before the caller's ``callback``): row 0 the
    initial guess rolled out (``X_initial``, whose cost is ``initial_cost``), row ``i`` the iterate
    of iteration ``i``; iterations that diverged report nothing and stay NaN. The last row of a
    run whose last iteration did not diverge is the result's ``X`` itself (FDDP: its controller
    rolled out on the planning model, as the plan stores it, rather than crocoddyl's iterate).
    """
    spec = get_solver(solver_name)
    history = IterateHistory(iterate_steps(problem))
    user = init.get("callback")

    def callback(record, X, U) -> None:  # noqa: ANN001
        history(record, X, U)
        if user is not None:
            user(record, X, U)

    result = spec.run(problem, spec.options(options), **{**init, "callback": callback})
    result.solver = solver_name
    if result.X_initial is not None:
        history.set(0, result.X_initial)
    if result.history and result.history[-1].iteration in history.rows:
        history.set(result.history[-1].iteration, result.X)
    result.X_iterations = history.array(result.iterations, problem.n_x)
    result.t_iterations = history.steps
    return result
